"""The per-ray sphere-tracing march, written once for numba, and the kernels built from it.

``march_ray`` is renderer/reference.py's march for one ray, step for step, in the grid's dtype:
box entry/exit by the slab test, the sign at the start point, sphere tracing with the hit
threshold, the closest approach of misses, the search for the deepest point behind hits, and the
start-inside cases. Everything is scalar code on arrays, so the same ``@njit`` functions compile
for the CPU (``march_rays_cpu``: ``prange`` over rays) and, called from ``cuda_march_body``, for
numba's CUDA target (``make_cuda_kernel`` compiles that body lazily, so this module imports on
machines without a GPU).

Every function the kernels call lives in this one file on purpose: numba's on-disk cache checks
only the source file of the function it caches, so a helper in another file could change without
invalidating the cached kernels.

Arithmetic stays in the grid's dtype: float constants come from the ``params`` array (a Python
float literal would promote float32 arithmetic to float64 and drift from the reference).

``params`` (grid dtype) holds, at the indices below: bbox_min (3), bbox_max (3), voxel size (3),
box centre (3), ``res - 1`` (3) and ``res - 2`` (3) as floats, then 0, 1, the tiny direction
component, the threshold floor, the threshold scale, the fixed threshold and ``-inner_depth``.
``iparams`` (int64): Nx, Ny, Nz, max_steps, inner_steps, whether the threshold is fixed.
"""
from __future__ import annotations

from numba import njit, prange, types, uintp
from numba.extending import overload

# Options of the per-ray code: no reference counting (nothing is allocated), and numpy's float
# division (no zero-divisor check and exception path: divisors here are never zero). The small
# helpers are inlined into the march at numba's IR level.
_RAY_OPTIONS = dict(cache=True, _nrt=False, error_model="numpy")
ray_function = njit(**_RAY_OPTIONS)
ray_helper = njit(inline="always", **_RAY_OPTIONS)

# numba.cuda, imported by make_cuda_kernel() on first use only (it resolves when the body compiles).
cuda = None

# float parameters
LO, HI, VOX, CENTRE, TOP, CELL_MAX = 0, 3, 6, 9, 12, 15
ZERO, ONE, TINY, FLOOR, SCALE, FIXED, NEG_DEPTH = 18, 19, 20, 21, 22, 23, 24
N_PARAMS = 25
# int parameters
NX, NY, NZ, MAX_STEPS, INNER_STEPS, USE_FIXED = 0, 1, 2, 3, 4, 5
N_IPARAMS = 6


def float_like(i, like):
    """The integer i as a float of ``like``'s type (float(i) would be float64 for float32 code)."""
    return type(like)(i)


@overload(float_like, target="generic")
def _float_like_impl(i, like):
    if isinstance(i, types.Integer) and isinstance(like, types.Float):
        cast = like

        def impl(i, like):
            return cast(i)

        return impl
    return None


# min/max of two floats (the builtins fail to type on numba's built-in CUDA target).
@ray_helper
def _min(a, b):
    return b if b < a else a


@ray_helper
def _max(a, b):
    return b if b > a else a


@ray_helper
def _safe_inverse(d, params):
    """1 / d with components below the tiny value replaced by it (keeping the sign), as reference."""
    tiny = params[TINY]
    if abs(d) < tiny:
        d = -tiny if d < params[ZERO] else tiny
    return params[ONE] / d


@ray_helper
def box_interval(ox, oy, oz, dx, dy, dz, params):
    """Slab test for one ray: (t_near, t_far) of the grid's box."""
    inv = _safe_inverse(dx, params)
    t1 = (params[LO] - ox) * inv
    t2 = (params[HI] - ox) * inv
    near = _min(t1, t2)
    far = _max(t1, t2)
    inv = _safe_inverse(dy, params)
    t1 = (params[LO + 1] - oy) * inv
    t2 = (params[HI + 1] - oy) * inv
    near = _max(near, _min(t1, t2))
    far = _min(far, _max(t1, t2))
    inv = _safe_inverse(dz, params)
    t1 = (params[LO + 2] - oz) * inv
    t2 = (params[HI + 2] - oz) * inv
    near = _max(near, _min(t1, t2))
    far = _min(far, _max(t1, t2))
    return near, far


@ray_helper
def _cell(p, axis, params):
    """Cell index and fraction along one axis, clamped into the box (as SDFGrid._cells)."""
    u = (p - params[LO + axis]) / params[VOX + axis]
    if u < params[ZERO]:
        u = params[ZERO]
    if u > params[TOP + axis]:
        u = params[TOP + axis]
    # floor(u) is the truncation here (u >= 0): one conversion instruction, no floorf call.
    i = int(u)
    corner = float_like(i, u)
    if corner > params[CELL_MAX + axis]:
        corner = params[CELL_MAX + axis]
        i = int(corner)
    return i, u - corner


@ray_helper
def sample_sdf(values, b, px, py, pz, params, iparams):
    """Trilinear SDF of grid ``b`` at the world point (px, py, pz), as SDFGrid._sample_flat.

    values: the (B, Nx, Ny, Nz) grids flattened (C order). The flat indices are unsigned, so the
    loads carry no negative-index wraparound.
    """
    i, wx = _cell(px, 0, params)
    j, wy = _cell(py, 1, params)
    k, wz = _cell(pz, 2, params)
    ny, nz = iparams[NY], iparams[NZ]
    c000 = uintp(((b * iparams[NX] + i) * ny + j) * nz + k)
    dz, dy, dx = uintp(1), uintp(nz), uintp(ny * nz)
    c00 = values[c000] + (values[c000 + dz] - values[c000]) * wz
    c01 = values[c000 + dy] + (values[c000 + dy + dz] - values[c000 + dy]) * wz
    c10 = values[c000 + dx] + (values[c000 + dx + dz] - values[c000 + dx]) * wz
    c11 = values[c000 + dx + dy] + (values[c000 + dx + dy + dz] - values[c000 + dx + dy]) * wz
    c0 = c00 + (c01 - c00) * wy
    c1 = c10 + (c11 - c10) * wy
    return c0 + (c1 - c0) * wx


@ray_helper
def hit_threshold(t, pixel_angle, params, iparams):
    """The hit threshold at distance t: fixed, or the pixel footprint, never below the floor."""
    if iparams[USE_FIXED] != 0:
        return params[FIXED]
    thr = params[SCALE] * t * pixel_angle
    return thr if thr > params[FLOOR] else params[FLOOR]


@ray_function
def march_ray(values, params, iparams, ox, oy, oz, dx, dy, dz, b, pixel_angle):
    """Marches one ray (renderer/reference.py, steps 1-4).

    Returns:
        (t, hit, extreme x, y, z, t_extreme, steps): the traced distance (0 outside the box),
        whether it hit, the closest-approach or deepest point (world) and its distance, and the
        number of SDF samples of the march.
    """
    zero = params[ZERO]
    t_near, t_far = box_interval(ox, oy, oz, dx, dy, dz, params)
    t0 = t_near if t_near > zero else zero
    if not t_far >= t0:
        # Missed the box: the point nearest the box centre, clamped into the box.
        tc = ((params[CENTRE] - ox) * dx + (params[CENTRE + 1] - oy) * dy) + (params[CENTRE + 2] - oz) * dz
        if tc < zero:
            tc = zero
        ex = _min(_max(ox + tc * dx, params[LO]), params[HI])
        ey = _min(_max(oy + tc * dy, params[LO + 1]), params[HI + 1])
        ez = _min(_max(oz + tc * dz, params[LO + 2]), params[HI + 2])
        return zero, False, ex, ey, ez, tc, 0

    # The start sample decides the sign and is also the march's first sample (same point).
    f = sample_sdf(values, b, ox + t0 * dx, oy + t0 * dy, oz + t0 * dz, params, iparams)
    sign = -params[ONE] if f < zero else params[ONE]
    f = sign * f
    t = t0
    best_f = f
    best_t = t0
    hit = False
    steps = 0
    max_steps = iparams[MAX_STEPS]
    while True:
        steps += 1
        if f < best_f:
            best_f = f
            best_t = t
        if f < hit_threshold(t, pixel_angle, params, iparams):
            hit = True
            break
        t = t + f
        if not t <= t_far or steps >= max_steps:
            break
        f = sign * sample_sdf(values, b, ox + t * dx, oy + t * dy, oz + t * dz, params, iparams)

    if sign < zero:
        # Began inside the shape (hit or not): the start point carries the silhouette.
        return t, hit, ox + t0 * dx, oy + t0 * dy, oz + t0 * dz, t0, steps
    if not hit:
        return t, hit, ox + best_t * dx, oy + best_t * dy, oz + best_t * dz, best_t, steps

    # Hit from outside: the smallest SDF along the rest of the ray.
    t_cur = t
    f_cur = best_f
    best_in = best_f
    best_ti = t
    thr = hit_threshold(t_cur, pixel_angle, params, iparams)
    for _ in range(iparams[INNER_STEPS]):
        step = abs(f_cur)
        if thr > step:
            step = thr
        t_new = t_cur + step
        f_new = sample_sdf(values, b, ox + t_new * dx, oy + t_new * dy, oz + t_new * dz, params, iparams)
        inside_box = t_new <= t_far
        if inside_box and f_new < best_in:
            best_in = f_new
            best_ti = t_new
        t_cur = t_new
        f_cur = f_new
        thr = hit_threshold(t_new, pixel_angle, params, iparams)
        if not (inside_box and best_in > params[NEG_DEPTH] * thr):
            break
    return t, hit, ox + best_ti * dx, oy + best_ti * dy, oz + best_ti * dz, best_ti, steps


@ray_function
def march_into(r, values, params, iparams, origins, directions, grid_index, pixel_angle,
               t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    """Marches ray r and writes its results: the body both kernels run per ray."""
    t, hit, ex, ey, ez, te, steps = march_ray(
        values, params, iparams,
        origins[r, 0], origins[r, 1], origins[r, 2],
        directions[r, 0], directions[r, 1], directions[r, 2],
        grid_index[r], pixel_angle[r])
    t_out[r] = t
    hit_out[r] = 1 if hit else 0
    extreme_out[r, 0] = ex
    extreme_out[r, 1] = ey
    extreme_out[r, 2] = ez
    t_extreme_out[r] = te
    steps_out[r] = steps


@njit(parallel=True, cache=True, error_model="numpy")
def march_rays_cpu(values, params, iparams, origins, directions, grid_index, pixel_angle,
                   t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    """CPU kernel: one ray per ``prange`` iteration. Shapes as in ``cuda_march_body``."""
    for r in prange(origins.shape[0]):
        march_into(r, values, params, iparams, origins, directions, grid_index, pixel_angle,
                   t_out, hit_out, extreme_out, t_extreme_out, steps_out)


def cuda_march_body(values, params, iparams, origins, directions, grid_index, pixel_angle,
                    t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    """CUDA kernel body (compiled by ``make_cuda_kernel``): one ray per thread.

    values (B * Nx * Ny * Nz,) the grids flattened; params (N_PARAMS,) and the float arrays in the grid dtype; iparams
    (N_IPARAMS,) int64; origins, directions (R, 3); grid_index (R,) int64; pixel_angle (R,);
    outputs t (R,), hit (R,) uint8, extreme (R, 3), t_extreme (R,), steps (R,) int32.
    """
    r = cuda.grid(1)
    if r < origins.shape[0]:
        march_into(r, values, params, iparams, origins, directions, grid_index, pixel_angle,
                   t_out, hit_out, extreme_out, t_extreme_out, steps_out)


_cuda_kernel = None


def make_cuda_kernel():
    """The CUDA kernel compiled from ``cuda_march_body`` (lazily, once; cached on disk by numba)."""
    global cuda, _cuda_kernel
    if _cuda_kernel is None:
        from numba import cuda as numba_cuda

        cuda = numba_cuda
        _cuda_kernel = numba_cuda.jit(cache=True)(cuda_march_body)
    return _cuda_kernel
