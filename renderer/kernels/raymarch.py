"""The per-ray sphere-tracing march, written once for numba, and the kernels built from it.

The march of one ray is renderer/reference.py's, step for step, in the grid's dtype: box
entry/exit by the slab test, the sign at the start point, sphere tracing with the hit threshold,
the closest approach of misses, the search for the deepest point behind hits, and the
start-inside cases. It is written as a small state machine: ``ray_begin`` (box test),
``ray_advance`` (takes one SDF sample, returns the ray's new state and where the next sample is
due) and ``ray_extreme``. Both kernels drive those same routines: ``march_ray`` runs one ray to
the end (the CUDA kernel, ``cuda_march_body``: one ray per thread, its state in registers), and
the CPU kernel ``march_rays_cpu`` runs LANES rays interleaved per thread (``march_block``: a lone
ray's samples are a chain of dependent cache misses, the lanes' are independent). Everything is
scalar code on arrays, so the same ``@njit`` functions compile for both targets
(``make_cuda_kernel`` compiles the CUDA body lazily, so this module imports on machines without a
GPU).

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

import numpy as np
from numba import njit, prange, types, uintp
from numba.extending import overload

# Options of the per-ray code: no reference counting (nothing is allocated), and numpy's float
# division (no zero-divisor check and exception path: divisors here are never zero). The small
# helpers are inlined into the march at numba's IR level; inlined into a function compiled *with*
# reference counting they would incref and decref their array arguments at every call (atomic
# operations, several times slower: docs/measurements.md), so only ``_RAY_OPTIONS`` functions call them.
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
def cell_corner(b, px, py, pz, params, iparams):
    """Flat index of the first corner (c000) of the cell of grid ``b`` holding the world point
    (px, py, pz), the strides to its other corners along z, y, x, and the fractions in the cell.

    The flat indices are unsigned, so the loads carry no negative-index wraparound.
    """
    i, wx = _cell(px, 0, params)
    j, wy = _cell(py, 1, params)
    k, wz = _cell(pz, 2, params)
    ny, nz = iparams[NY], iparams[NZ]
    c000 = uintp(((b * iparams[NX] + i) * ny + j) * nz + k)
    return c000, uintp(1), uintp(nz), uintp(ny * nz), wx, wy, wz


@ray_helper
def trilinear(c000, c001, c010, c011, c100, c101, c110, c111, wx, wy, wz):
    """Trilinear interpolation of a cell's corner values (bits x, y, z), halved along z, y, x."""
    c00 = c000 + (c001 - c000) * wz
    c01 = c010 + (c011 - c010) * wz
    c10 = c100 + (c101 - c100) * wz
    c11 = c110 + (c111 - c110) * wz
    c0 = c00 + (c01 - c00) * wy
    c1 = c10 + (c11 - c10) * wy
    return c0 + (c1 - c0) * wx


@ray_helper
def sample_sdf(values, b, px, py, pz, params, iparams):
    """Trilinear SDF of grid ``b`` at the world point (px, py, pz), as SDFGrid._sample_flat.

    values: the (B, Nx, Ny, Nz) grids flattened (C order).
    """
    c, dz, dy, dx, wx, wy, wz = cell_corner(b, px, py, pz, params, iparams)
    return trilinear(values[c], values[c + dz], values[c + dy], values[c + dy + dz],
                     values[c + dx], values[c + dx + dz], values[c + dx + dy], values[c + dx + dy + dz],
                     wx, wy, wz)


@ray_helper
def hit_threshold(t, pixel_angle, params, iparams):
    """The hit threshold at distance t: fixed, or the pixel footprint, never below the floor."""
    if iparams[USE_FIXED] != 0:
        return params[FIXED]
    thr = params[SCALE] * t * pixel_angle
    return thr if thr > params[FLOOR] else params[FLOOR]


# Phases of a ray's march (the state machine below).
START, MARCH, INNER, DONE, OUTSIDE = 0, 1, 2, 3, 4


@ray_helper
def ray_begin(ox, oy, oz, dx, dy, dz, params):
    """A ray's march state before its first sample (renderer/reference.py, step 1).

    Returns (phase, ts, t, best_f, best_t, sign, t0, t_far, steps, count, hit): ``ts`` is where the
    next SDF sample is due. A ray that misses the box is finished at once (phase OUTSIDE, with its
    closest approach to the box centre in best_t).
    """
    zero = params[ZERO]
    t_near, t_far = box_interval(ox, oy, oz, dx, dy, dz, params)
    t0 = t_near if t_near > zero else zero
    if not t_far >= t0:
        tc = ((params[CENTRE] - ox) * dx + (params[CENTRE + 1] - oy) * dy) + (params[CENTRE + 2] - oz) * dz
        if tc < zero:
            tc = zero
        return OUTSIDE, zero, zero, zero, tc, params[ONE], t0, t_far, 0, 0, 0
    return START, t0, t0, zero, t0, params[ONE], t0, t_far, 0, 0, 0


@ray_helper
def ray_advance(f, phase, ts, t, best_f, best_t, sign, t0, t_far, steps, count, hit, pixel_angle,
                params, iparams):
    """Takes the SDF sample f at ``ts`` and moves the ray's march on (reference steps 2-4).

    Returns the new (phase, ts, t, best_f, best_t, sign, steps, count, hit). Behind a hit from
    outside (phase INNER) best_f and best_t hold the deepest sample and its distance.
    """
    zero = params[ZERO]
    if phase == START:
        # The start sample decides the sign and is also the march's first sample (same point).
        sign = -params[ONE] if f < zero else params[ONE]
        f = sign * f
        best_f = f
        best_t = t
        phase = MARCH
    elif phase == MARCH:
        f = sign * f
    if phase == MARCH:
        steps += 1
        if f < best_f:
            best_f = f
            best_t = t
        if f < hit_threshold(t, pixel_angle, params, iparams):
            hit = 1
            if sign < zero or iparams[INNER_STEPS] <= 0:
                # Began inside (its start point carries the silhouette), or no search behind hits.
                return DONE, ts, t, best_f, (t0 if sign < zero else t), sign, steps, count, hit
            # Hit from outside: look for the smallest SDF along the rest of the ray.
            step = abs(best_f)
            thr = hit_threshold(t, pixel_angle, params, iparams)
            if thr > step:
                step = thr
            return INNER, t + step, t, best_f, t, sign, steps, count, hit
        t = t + f
        if not t <= t_far or steps >= iparams[MAX_STEPS]:
            return DONE, ts, t, best_f, (t0 if sign < zero else best_t), sign, steps, count, hit
        return MARCH, t, t, best_f, best_t, sign, steps, count, hit
    # phase INNER: f was sampled at ts = the previous sample + max(|its f|, its threshold)
    count += 1
    inside_box = ts <= t_far
    if inside_box and f < best_f:
        best_f = f
        best_t = ts
    thr = hit_threshold(ts, pixel_angle, params, iparams)
    if not (inside_box and best_f > params[NEG_DEPTH] * thr) or count >= iparams[INNER_STEPS]:
        return DONE, ts, t, best_f, best_t, sign, steps, count, hit
    step = abs(f)
    if thr > step:
        step = thr
    return INNER, ts + step, t, best_f, best_t, sign, steps, count, hit


@ray_helper
def ray_extreme(phase, te, ox, oy, oz, dx, dy, dz, params):
    """The closest-approach or deepest point of a finished ray, at distance te."""
    if phase == OUTSIDE:  # missed the box: clamped into it
        return (_min(_max(ox + te * dx, params[LO]), params[HI]),
                _min(_max(oy + te * dy, params[LO + 1]), params[HI + 1]),
                _min(_max(oz + te * dz, params[LO + 2]), params[HI + 2]))
    return ox + te * dx, oy + te * dy, oz + te * dz


@ray_function
def march_ray(values, params, iparams, ox, oy, oz, dx, dy, dz, b, pixel_angle):
    """Marches one ray to the end (renderer/reference.py, steps 1-4): the state machine driven
    sample by sample.

    Returns:
        (t, hit, extreme x, y, z, t_extreme, steps): the traced distance (0 outside the box),
        whether it hit, the closest-approach or deepest point (world) and its distance, and the
        number of SDF samples of the march.
    """
    phase, ts, t, best_f, best_t, sign, t0, t_far, steps, count, hit = ray_begin(ox, oy, oz, dx, dy, dz, params)
    while phase < DONE:
        f = sample_sdf(values, b, ox + ts * dx, oy + ts * dy, oz + ts * dz, params, iparams)
        phase, ts, t, best_f, best_t, sign, steps, count, hit = ray_advance(
            f, phase, ts, t, best_f, best_t, sign, t0, t_far, steps, count, hit, pixel_angle, params, iparams)
    ex, ey, ez = ray_extreme(phase, best_t, ox, oy, oz, dx, dy, dz, params)
    return t, hit != 0, ex, ey, ez, best_t, steps


@ray_function
def march_into(r, values, params, iparams, origins, directions, grid_index, pixel_angle,
               t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    """Marches ray r and writes its results: the CUDA kernel's body per thread."""
    t, hit, ex, ey, ez, te, steps = march_ray(
        values, params, iparams,
        origins[r, 0], origins[r, 1], origins[r, 2],
        directions[r, 0], directions[r, 1], directions[r, 2],
        grid_index[r], pixel_angle[r])
    _write(r, t, 1 if hit else 0, ex, ey, ez, te, steps, t_out, hit_out, extreme_out, t_extreme_out, steps_out)


@ray_helper
def _write(r, t, hit, ex, ey, ez, te, steps, t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    t_out[r] = t
    hit_out[r] = hit
    extreme_out[r, 0] = ex
    extreme_out[r, 1] = ey
    extreme_out[r, 2] = ez
    t_extreme_out[r] = te
    steps_out[r] = steps


# ---------------------------------------------------------------------------- CPU: interleaved rays
# A CPU thread marches LANES rays at once, one sample of each in turn, taking the next ray of its
# block into a lane as soon as the lane's ray finishes. A lone ray's samples form a chain of
# dependent cache misses (each position needs the previous sample); the lanes' samples are
# independent, so their loads are issued together and their misses overlap, which is faster than
# one ray per thread (docs/measurements.md).
LANES = 8
BLOCK = 64  # rays per prange iteration (per block the lanes work through)
# rows of the per-lane state: float (grid dtype) and int64
F_TS, F_T, F_BEST_F, F_BEST_T, F_SIGN, F_T0, F_T_FAR, F_WX, F_WY, F_WZ = range(10)
N_FSTATE = 10
I_RAY, I_PHASE, I_STEPS, I_COUNT, I_HIT = range(5)
N_ISTATE = 5


@ray_helper
def _store_lane(k, fs, ist, phase, ts, t, best_f, best_t, sign, steps, count, hit):
    """Writes the state ``ray_advance`` moves on into lane k."""
    fs[F_TS, k] = ts
    fs[F_T, k] = t
    fs[F_BEST_F, k] = best_f
    fs[F_BEST_T, k] = best_t
    fs[F_SIGN, k] = sign
    ist[I_PHASE, k] = phase
    ist[I_STEPS, k] = steps
    ist[I_COUNT, k] = count
    ist[I_HIT, k] = hit


@ray_function
def _start_lane(k, fs, ist, next_ray, end, params, origins, directions,
                t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    """Puts the next ray of the block that needs samples into lane k (rays that miss the box are
    finished on the way). Returns the new next ray and whether the lane got one."""
    while next_ray < end:
        r = next_ray
        next_ray += 1
        ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
        dx, dy, dz = directions[r, 0], directions[r, 1], directions[r, 2]
        phase, ts, t, best_f, best_t, sign, t0, t_far, steps, count, hit = ray_begin(ox, oy, oz, dx, dy, dz, params)
        if phase >= DONE:
            ex, ey, ez = ray_extreme(phase, best_t, ox, oy, oz, dx, dy, dz, params)
            _write(r, t, hit, ex, ey, ez, best_t, steps, t_out, hit_out, extreme_out, t_extreme_out, steps_out)
            continue
        fs[F_T0, k] = t0
        fs[F_T_FAR, k] = t_far
        ist[I_RAY, k] = r
        _store_lane(k, fs, ist, phase, ts, t, best_f, best_t, sign, steps, count, hit)
        return next_ray, True
    ist[I_RAY, k] = -1
    return next_ray, False


@ray_function
def march_block(start, end, fs, ist, corners, values, params, iparams, origins, directions, grid_index,
                pixel_angle, t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    """Marches rays start..end-1 on LANES lanes, with the same per-ray routines as ``march_ray``.

    fs (N_FSTATE, LANES), ist (N_ISTATE, LANES), corners (8, LANES): scratch for the lanes' state.
    """
    next_ray = start
    active = 0
    for k in range(LANES):
        next_ray, got = _start_lane(k, fs, ist, next_ray, end, params, origins, directions,
                                    t_out, hit_out, extreme_out, t_extreme_out, steps_out)
        if got:
            active += 1
    while active > 0:
        # Pass 1: each lane's sample position and its 8 corner loads, independent across lanes.
        for k in range(LANES):
            r = ist[I_RAY, k]
            if r < 0:
                continue
            ts = fs[F_TS, k]
            c, dz, dy, dx, wx, wy, wz = cell_corner(
                grid_index[r], origins[r, 0] + ts * directions[r, 0], origins[r, 1] + ts * directions[r, 1],
                origins[r, 2] + ts * directions[r, 2], params, iparams)
            corners[0, k] = values[c]
            corners[1, k] = values[c + dz]
            corners[2, k] = values[c + dy]
            corners[3, k] = values[c + dy + dz]
            corners[4, k] = values[c + dx]
            corners[5, k] = values[c + dx + dz]
            corners[6, k] = values[c + dx + dy]
            corners[7, k] = values[c + dx + dy + dz]
            fs[F_WX, k] = wx
            fs[F_WY, k] = wy
            fs[F_WZ, k] = wz
        # Pass 2: interpolate, move each march on, refill the lanes whose ray finished.
        for k in range(LANES):
            r = ist[I_RAY, k]
            if r < 0:
                continue
            f = trilinear(corners[0, k], corners[1, k], corners[2, k], corners[3, k], corners[4, k],
                          corners[5, k], corners[6, k], corners[7, k], fs[F_WX, k], fs[F_WY, k], fs[F_WZ, k])
            phase, ts, t, best_f, best_t, sign, steps, count, hit = ray_advance(
                f, ist[I_PHASE, k], fs[F_TS, k], fs[F_T, k], fs[F_BEST_F, k], fs[F_BEST_T, k], fs[F_SIGN, k],
                fs[F_T0, k], fs[F_T_FAR, k], ist[I_STEPS, k], ist[I_COUNT, k], ist[I_HIT, k],
                pixel_angle[r], params, iparams)
            if phase >= DONE:
                ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
                dx, dy, dz = directions[r, 0], directions[r, 1], directions[r, 2]
                ex, ey, ez = ray_extreme(phase, best_t, ox, oy, oz, dx, dy, dz, params)
                _write(r, t, hit, ex, ey, ez, best_t, steps, t_out, hit_out, extreme_out, t_extreme_out, steps_out)
                next_ray, got = _start_lane(k, fs, ist, next_ray, end, params, origins, directions,
                                            t_out, hit_out, extreme_out, t_extreme_out, steps_out)
                if not got:
                    active -= 1
                continue
            _store_lane(k, fs, ist, phase, ts, t, best_f, best_t, sign, steps, count, hit)


@njit(parallel=True, cache=True, error_model="numpy")
def march_rays_cpu(values, params, iparams, origins, directions, grid_index, pixel_angle,
                   t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    """CPU kernel: blocks of BLOCK rays over ``prange``, LANES rays interleaved per thread
    (``march_block``). Shapes as in ``cuda_march_body``."""
    n = origins.shape[0]
    for blk in prange((n + BLOCK - 1) // BLOCK):
        # Lane scratch per block (the per-ray code is compiled without numba's allocator).
        fs = np.empty((N_FSTATE, LANES), dtype=values.dtype)
        ist = np.empty((N_ISTATE, LANES), dtype=np.int64)
        corners = np.empty((8, LANES), dtype=values.dtype)
        start = blk * BLOCK
        march_block(start, min(n, start + BLOCK), fs, ist, corners, values, params, iparams, origins,
                    directions, grid_index, pixel_angle, t_out, hit_out, extreme_out, t_extreme_out, steps_out)


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
