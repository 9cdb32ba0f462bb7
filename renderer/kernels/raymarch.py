"""The renderer's per-ray code, written once for numba, and the kernels built from it: the
sphere-tracing march (stage 1) and, in the "stage 2" section at the end, the differentiable
shading (forward and backward). The march of one ray is renderer/reference.py's step for step:
box entry and exit by the slab test, the sign at the start point, sphere tracing with the hit
threshold, the closest approach of misses, the search for the deepest point behind hits and the
start-inside cases, written as a small state machine (``ray_begin`` the box test, ``ray_advance``
one SDF sample in and the ray's new state and next sample position out, ``ray_extreme``), and
where asked the grazing points (``ray_graze``, fed each sample beside ``ray_advance``). Both
kernels drive those routines: ``march_ray`` runs one ray to the end (the CUDA kernel,
``cuda_march_body``, one ray per thread with its state in registers), and the CPU kernel
``march_rays_cpu`` runs LANES rays interleaved per thread (``march_block``), because a lone ray's
samples are a chain of dependent cache misses while the lanes' are independent. Everything is
scalar code on arrays, so the same ``@njit`` functions compile for both targets, and
``make_cuda_kernel`` compiles the CUDA body lazily so that the module imports on machines without
a GPU. Every function the kernels call, of both stages, lives in this one file on purpose: numba's
on-disk cache checks only the source file of the function it caches, so a helper in another file
could change without invalidating the cached kernels. Arithmetic stays in the grid's dtype, with
float constants taken from the ``params`` array (laid out beside its index constants below),
since a Python float literal would promote float32 arithmetic to float64 and drift from the
reference.
"""
from __future__ import annotations

import math
import threading

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

# ``params`` (grid dtype) holds, from the indices below: bbox_min (3), bbox_max (3), the voxel
# size (3), the box centre (3), ``res - 1`` (3) and ``res - 2`` (3) as floats, then 0, 1, the tiny
# direction component, the threshold floor, the threshold scale, the fixed threshold,
# ``-inner_depth`` and +inf. ``iparams`` (int64): Nx, Ny, Nz, max_steps, inner_steps, whether the
# threshold is fixed, whether to find grazing points.
# float parameters
LO, HI, VOX, CENTRE, TOP, CELL_MAX = 0, 3, 6, 9, 12, 15
ZERO, ONE, TINY, FLOOR, SCALE, FIXED, NEG_DEPTH, INF = 18, 19, 20, 21, 22, 23, 24, 25
N_PARAMS = 26
# int parameters
NX, NY, NZ, MAX_STEPS, INNER_STEPS, USE_FIXED, GRAZING = 0, 1, 2, 3, 4, 5, 6
N_IPARAMS = 7


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


@ray_helper
def ray_graze(phase, f, ts, sign, last_f, last_t, falling, graze_gap, graze_t, pixel_angle, params, iparams):
    """Feeds the SDF sample f, taken at ``ts`` in ``phase`` (the phase before ``ray_advance`` moved
    the ray on; ``sign`` the one it decided), into the search for the ray's grazing point
    (renderer/reference.py, step 3): a march sample at most the previous one and below the next
    one is a local minimum, and the one with the smallest gap in pixel footprints is kept. Rays
    that began inside the shape (sign -1) have none.

    Returns the new (last_f, last_t, falling, graze_gap, graze_t) (unchanged by other samples).
    """
    if iparams[GRAZING] == 0 or (phase != START and phase != MARCH) or sign < params[ZERO]:
        return last_f, last_t, falling, graze_gap, graze_t
    if phase == MARCH:  # the first march sample (phase START) has no previous one
        foot = last_t * pixel_angle
        if not foot > params[FLOOR]:
            foot = params[FLOOR]
        gap = (last_f - hit_threshold(last_t, pixel_angle, params, iparams)) / foot
        if falling != 0 and f > last_f and gap < graze_gap:
            graze_gap = gap
            graze_t = last_t
    falling = 1 if phase == MARCH and f <= last_f else 0
    return f, ts, falling, graze_gap, graze_t


@ray_function
def march_ray(values, params, iparams, ox, oy, oz, dx, dy, dz, b, pixel_angle):
    """Marches one ray to the end (renderer/reference.py, steps 1-4): the state machine driven
    sample by sample.

    Returns:
        (t, hit, extreme x, y, z, t_extreme, steps, graze_gap, graze_t): the traced distance (0
        outside the box), whether it hit, the closest-approach or deepest point (world) and its
        distance, the number of SDF samples of the march, and the grazing point's gap and distance
        (+inf and 0 where there is none or none was asked for).
    """
    phase, ts, t, best_f, best_t, sign, t0, t_far, steps, count, hit = ray_begin(ox, oy, oz, dx, dy, dz, params)
    last_f, last_t, falling, graze_gap, graze_t = params[ZERO], params[ZERO], 0, params[INF], params[ZERO]
    while phase < DONE:
        f = sample_sdf(values, b, ox + ts * dx, oy + ts * dy, oz + ts * dz, params, iparams)
        sampled_phase, sampled_ts = phase, ts
        phase, ts, t, best_f, best_t, sign, steps, count, hit = ray_advance(
            f, phase, ts, t, best_f, best_t, sign, t0, t_far, steps, count, hit, pixel_angle, params, iparams)
        last_f, last_t, falling, graze_gap, graze_t = ray_graze(
            sampled_phase, f, sampled_ts, sign, last_f, last_t, falling, graze_gap, graze_t, pixel_angle, params,
            iparams)
    ex, ey, ez = ray_extreme(phase, best_t, ox, oy, oz, dx, dy, dz, params)
    return t, hit != 0, ex, ey, ez, best_t, steps, graze_gap, graze_t


@ray_function
def march_into(r, values, params, iparams, origins, directions, grid_index, pixel_angle,
               t_out, hit_out, extreme_out, t_extreme_out, steps_out, graze_out):
    """Marches ray r and writes its results: the CUDA kernel's body per thread."""
    t, hit, ex, ey, ez, te, steps, graze_gap, graze_t = march_ray(
        values, params, iparams,
        origins[r, 0], origins[r, 1], origins[r, 2],
        directions[r, 0], directions[r, 1], directions[r, 2],
        grid_index[r], pixel_angle[r])
    _write(r, t, 1 if hit else 0, ex, ey, ez, te, steps, t_out, hit_out, extreme_out, t_extreme_out, steps_out)
    _write_graze(r, graze_gap, graze_t, iparams, graze_out)


@ray_helper
def _write(r, t, hit, ex, ey, ez, te, steps, t_out, hit_out, extreme_out, t_extreme_out, steps_out):
    t_out[r] = t
    hit_out[r] = hit
    extreme_out[r, 0] = ex
    extreme_out[r, 1] = ey
    extreme_out[r, 2] = ez
    t_extreme_out[r] = te
    steps_out[r] = steps


@ray_helper
def _write_graze(r, graze_gap, graze_t, iparams, graze_out):
    """Writes ray r's grazing point (gap, distance) into graze_out (R, 2), where asked for."""
    if iparams[GRAZING] != 0:
        graze_out[r, 0] = graze_gap
        graze_out[r, 1] = graze_t


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
F_LAST_F, F_LAST_T, F_GRAZE_GAP, F_GRAZE_T = range(10, 14)  # the grazing search (``ray_graze``)
N_FSTATE = 14
I_RAY, I_PHASE, I_STEPS, I_COUNT, I_HIT, I_FALLING = range(6)
N_ISTATE = 6


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
def _start_lane(k, fs, ist, next_ray, end, params, iparams, origins, directions,
                t_out, hit_out, extreme_out, t_extreme_out, steps_out, graze_out):
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
            _write_graze(r, params[INF], params[ZERO], iparams, graze_out)
            continue
        fs[F_T0, k] = t0
        fs[F_T_FAR, k] = t_far
        fs[F_LAST_F, k] = params[ZERO]
        fs[F_LAST_T, k] = params[ZERO]
        fs[F_GRAZE_GAP, k] = params[INF]
        fs[F_GRAZE_T, k] = params[ZERO]
        ist[I_FALLING, k] = 0
        ist[I_RAY, k] = r
        _store_lane(k, fs, ist, phase, ts, t, best_f, best_t, sign, steps, count, hit)
        return next_ray, True
    ist[I_RAY, k] = -1
    return next_ray, False


@ray_function
def march_block(start, end, fs, ist, corners, values, params, iparams, origins, directions, grid_index,
                pixel_angle, t_out, hit_out, extreme_out, t_extreme_out, steps_out, graze_out):
    """Marches rays start..end-1 on LANES lanes, with the same per-ray routines as ``march_ray``.

    fs (N_FSTATE, LANES), ist (N_ISTATE, LANES), corners (8, LANES): scratch for the lanes' state.
    """
    next_ray = start
    active = 0
    for k in range(LANES):
        next_ray, got = _start_lane(k, fs, ist, next_ray, end, params, iparams, origins, directions,
                                    t_out, hit_out, extreme_out, t_extreme_out, steps_out, graze_out)
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
            sampled_phase, sampled_ts = ist[I_PHASE, k], fs[F_TS, k]
            phase, ts, t, best_f, best_t, sign, steps, count, hit = ray_advance(
                f, sampled_phase, sampled_ts, fs[F_T, k], fs[F_BEST_F, k], fs[F_BEST_T, k], fs[F_SIGN, k],
                fs[F_T0, k], fs[F_T_FAR, k], ist[I_STEPS, k], ist[I_COUNT, k], ist[I_HIT, k],
                pixel_angle[r], params, iparams)
            if iparams[GRAZING] != 0:  # (the lanes' stores cost the plain march a few per cent)
                last_f, last_t, falling, graze_gap, graze_t = ray_graze(
                    sampled_phase, f, sampled_ts, sign, fs[F_LAST_F, k], fs[F_LAST_T, k], ist[I_FALLING, k],
                    fs[F_GRAZE_GAP, k], fs[F_GRAZE_T, k], pixel_angle[r], params, iparams)
                fs[F_LAST_F, k] = last_f
                fs[F_LAST_T, k] = last_t
                ist[I_FALLING, k] = falling
                fs[F_GRAZE_GAP, k] = graze_gap
                fs[F_GRAZE_T, k] = graze_t
            if phase >= DONE:
                ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
                dx, dy, dz = directions[r, 0], directions[r, 1], directions[r, 2]
                ex, ey, ez = ray_extreme(phase, best_t, ox, oy, oz, dx, dy, dz, params)
                _write(r, t, hit, ex, ey, ez, best_t, steps, t_out, hit_out, extreme_out, t_extreme_out, steps_out)
                _write_graze(r, fs[F_GRAZE_GAP, k], fs[F_GRAZE_T, k], iparams, graze_out)
                next_ray, got = _start_lane(k, fs, ist, next_ray, end, params, iparams, origins, directions,
                                            t_out, hit_out, extreme_out, t_extreme_out, steps_out, graze_out)
                if not got:
                    active -= 1
                continue
            _store_lane(k, fs, ist, phase, ts, t, best_f, best_t, sign, steps, count, hit)


@njit(parallel=True, cache=True, error_model="numpy")
def march_rays_cpu(values, params, iparams, origins, directions, grid_index, pixel_angle,
                   t_out, hit_out, extreme_out, t_extreme_out, steps_out, graze_out):
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
                    directions, grid_index, pixel_angle, t_out, hit_out, extreme_out, t_extreme_out, steps_out,
                    graze_out)


def cuda_march_body(values, params, iparams, origins, directions, grid_index, pixel_angle,
                    t_out, hit_out, extreme_out, t_extreme_out, steps_out, graze_out):
    """CUDA kernel body (compiled by ``make_cuda_kernel``): one ray per thread.

    values (B * Nx * Ny * Nz,) the grids flattened; params (N_PARAMS,) and the float arrays in the grid dtype; iparams
    (N_IPARAMS,) int64; origins, directions (R, 3); grid_index (R,) int64; pixel_angle (R,);
    outputs t (R,), hit (R,) uint8, extreme (R, 3), t_extreme (R,), steps (R,) int32, and graze
    (R, 2) (gap, distance) where iparams asks for grazing points (else it is not written).
    """
    r = cuda.grid(1)
    if r < origins.shape[0]:
        march_into(r, values, params, iparams, origins, directions, grid_index, pixel_angle,
                   t_out, hit_out, extreme_out, t_extreme_out, steps_out, graze_out)


_cuda_kernel = None


def make_cuda_kernel():
    """The CUDA kernel compiled from ``cuda_march_body`` (lazily, once; cached on disk by numba)."""
    global cuda, _cuda_kernel
    if _cuda_kernel is None:
        from numba import cuda as numba_cuda

        cuda = numba_cuda
        _cuda_kernel = numba_cuda.jit(cache=True)(cuda_march_body)
    return _cuda_kernel


# ============================================================================ stage 2
# The differentiable stage, per ray: renderer/shading.py's ``shade_reference`` with the
# conservative hit point (p = s + f(s) v), its normals (central differences at the cell's
# corners, trilinearly interpolated at p, normalised), Lambert shading and the soft silhouette,
# forward (``shade_ray``) and backward (``shade_ray_backward``: the gradients of one ray's outputs
# with respect to the SDF samples it read, then ``scatter_ray``: those gradients added into the
# grid's gradient). The PyTorch code stays the specification (tests/renderer/test_stage2.py).
#
# ``sparams`` (grid dtype): ambient, silhouette sigma, the normalisation epsilon, the smallest
# normal float, the camera light's intensity, 1 / (1 voxel) and 1 / (2 voxels) along x, y, z (the
# spacings of one-sided and central differences), then the albedo (C) and the background (C).
SP_AMBIENT, SP_SIGMA, SP_EPS, SP_TINY, SP_CAM_LIGHT, SP_INV_SPAN, SP_ALBEDO = 0, 1, 2, 3, 4, 5, 11
# ``sflags`` (int64): which outputs to make, rays per camera, channels, the camera light and its
# falloff, and (backward) which outputs brought a gradient.
SF_DEPTH, SF_NORMAL, SF_SHADING, SF_SILHOUETTE, SF_PIXELS, SF_CHANNELS, SF_CAM_LIGHT, SF_CAM_FALLOFF = range(8)
SF_GRAD_DEPTH, SF_GRAD_NORMAL, SF_GRAD_IMAGE, SF_GRAD_SILHOUETTE = 8, 9, 10, 11
N_SFLAGS = 12
# ``lights`` (L, 6) rows (grid dtype): kind (0 directional, 1 point), x, y, z (the unit direction
# towards the light, or the position), intensity, falloff (point lights: 1 for 1/distance^2).
LIGHT_POINT = 1


def scatter_add(grad, index, value):
    """``grad[index] += value``: a plain add in the CPU kernels (each thread owns the grids it
    writes), an atomic one in the CUDA kernel (see ``make_cuda_shade_kernels``). This Python body runs
    only where numba's JIT is off (the CUDA simulator in the tests), under a lock."""
    with _PY_SCATTER_LOCK:
        grad[index] += value


_PY_SCATTER_LOCK = threading.Lock()


@overload(scatter_add, target="cpu")
def _scatter_add_cpu(grad, index, value):
    def impl(grad, index, value):
        grad[index] += value

    return impl


@ray_helper
def _inside(p, axis, params):
    """Whether p lies in the box along ``axis`` (``_cell`` clamps it otherwise: then the sample does
    not move with p, as torch.clamp's gradient, which is 0 outside the bounds)."""
    u = (p - params[LO + axis]) / params[VOX + axis]
    return u >= params[ZERO] and u <= params[TOP + axis]


@ray_helper
def _vertex(b, i, j, k, iparams):
    return uintp(((b * iparams[NX] + i) * iparams[NY] + j) * iparams[NZ] + k)


@ray_helper
def _neighbours(c, n):
    """The samples a central difference at index c reads along an axis of n samples (one-sided at the ends)."""
    return (c - 1 if c > 0 else c), (c + 1 if c < n - 1 else c)


@ray_helper
def _corner_weight(c, wx, wy, wz, one):
    """Trilinear weight of corner c (bits x, y, z) and its derivatives along x, y, z."""
    x = wx if (c >> 2) & 1 else one - wx
    y = wy if (c >> 1) & 1 else one - wy
    z = wz if c & 1 else one - wz
    sx = one if (c >> 2) & 1 else -one
    sy = one if (c >> 1) & 1 else -one
    sz = one if c & 1 else -one
    return (x * y) * z, sx * (y * z), sy * (x * z), sz * (x * y)


@ray_helper
def _difference_ends(b, i, j, k, axis, params, iparams, sparams):
    """The samples a central difference at vertex (i, j, k) of grid b along ``axis`` reads (one-sided
    on the box faces): (index of the lower, index of the upper, 1 / their spacing)."""
    if axis == 0:
        lo, hi = _neighbours(i, iparams[NX])
        a, z = _vertex(b, lo, j, k, iparams), _vertex(b, hi, j, k, iparams)
    elif axis == 1:
        lo, hi = _neighbours(j, iparams[NY])
        a, z = _vertex(b, i, lo, k, iparams), _vertex(b, i, hi, k, iparams)
    else:
        lo, hi = _neighbours(k, iparams[NZ])
        a, z = _vertex(b, i, j, lo, iparams), _vertex(b, i, j, hi, iparams)
    return a, z, sparams[SP_INV_SPAN + axis + (3 if hi - lo == 2 else 0)]


@ray_helper
def _difference(values, b, i, j, k, axis, params, iparams, sparams):
    """The central difference at vertex (i, j, k) of grid b along ``axis`` (SDFGrid.sample_gradient's)."""
    a, z, inv = _difference_ends(b, i, j, k, axis, params, iparams, sparams)
    return (values[z] - values[a]) * inv


@ray_helper
def _interior(i, j, k, iparams):
    """Whether every central difference of cell (i, j, k) reads two samples inside the grid."""
    return (i >= 1 and j >= 1 and k >= 1 and i <= iparams[NX] - 3 and j <= iparams[NY] - 3
            and k <= iparams[NZ] - 3)


@ray_helper
def _corner_differences(values, b, i, j, k, c, interior, params, iparams, sparams):
    """The central differences along x, y, z at corner c (bits x, y, z) of cell (i, j, k) of grid b.
    In the grid's interior the samples are fixed offsets from the corner (most cells); on the box
    faces they are one-sided (``_difference``)."""
    ci, cj, ck = i + ((c >> 2) & 1), j + ((c >> 1) & 1), k + (c & 1)
    if interior:
        at = _vertex(b, ci, cj, ck, iparams)
        sz = uintp(1)
        sy = uintp(iparams[NZ])
        sx = uintp(iparams[NY] * iparams[NZ])
        return ((values[at + sx] - values[at - sx]) * sparams[SP_INV_SPAN + 3],
                (values[at + sy] - values[at - sy]) * sparams[SP_INV_SPAN + 4],
                (values[at + sz] - values[at - sz]) * sparams[SP_INV_SPAN + 5])
    return (_difference(values, b, ci, cj, ck, 0, params, iparams, sparams),
            _difference(values, b, ci, cj, ck, 1, params, iparams, sparams),
            _difference(values, b, ci, cj, ck, 2, params, iparams, sparams))


@ray_helper
def stencil_gradient(values, b, i, j, k, wx, wy, wz, params, iparams, sparams):
    """The SDF gradient at a point of cell (i, j, k) with fractions w: the central differences at
    the cell's 8 corners, trilinearly interpolated (SDFGrid.sample_gradient)."""
    one = params[ONE]
    interior = _interior(i, j, k, iparams)
    gx = gy = gz = params[ZERO]
    for c in range(8):
        w, _, _, _ = _corner_weight(c, wx, wy, wz, one)
        dx, dy, dz = _corner_differences(values, b, i, j, k, c, interior, params, iparams, sparams)
        gx += w * dx
        gy += w * dy
        gz += w * dz
    return gx, gy, gz


@ray_helper
def _point_cell(px, py, pz, params):
    i, wx = _cell(px, 0, params)
    j, wy = _cell(py, 1, params)
    k, wz = _cell(pz, 2, params)
    return i, j, k, wx, wy, wz


@ray_helper
def _light_term(kind, lx, ly, lz, intensity, falloff, nx, ny, nz, px, py, pz, params, sparams):
    """One light's diffuse term at a point with normal n (renderer/shading.py's shade_lambert)."""
    zero = params[ZERO]
    if kind != LIGHT_POINT:
        c = (nx * lx + ny * ly) + nz * lz
        return intensity * c if c > zero else zero
    tx, ty, tz = lx - px, ly - py, lz - pz
    d2 = (tx * tx + ty * ty) + tz * tz
    if d2 < sparams[SP_TINY]:
        d2 = sparams[SP_TINY]
    c = ((nx * tx + ny * ty) + nz * tz) / math.sqrt(d2)
    term = intensity * c if c > zero else zero
    return term / d2 if falloff > zero else term


@ray_helper
def _light_backward(kind, lx, ly, lz, intensity, falloff, nx, ny, nz, px, py, pz, g, params, sparams):
    """The gradient of ``g * _light_term`` with respect to the normal and the point (6 values).

    As torch.clamp's, the gradient of the clamped cosine passes where the cosine is >= 0; a
    distance clamped to the smallest float carries none.
    """
    zero = params[ZERO]
    if kind != LIGHT_POINT:
        c = (nx * lx + ny * ly) + nz * lz
        if c < zero:
            return zero, zero, zero, zero, zero, zero
        return g * intensity * lx, g * intensity * ly, g * intensity * lz, zero, zero, zero
    tx, ty, tz = lx - px, ly - py, lz - pz  # t = light - p
    d2 = (tx * tx + ty * ty) + tz * tz
    clamped = d2 < sparams[SP_TINY]
    if clamped:
        d2 = sparams[SP_TINY]
    root = math.sqrt(d2)
    c = ((nx * tx + ny * ty) + nz * tz) / root
    if c < zero:
        return zero, zero, zero, zero, zero, zero
    # term = I c (/ d2 with falloff), c = (n . t) / sqrt(d2), d2 = |t|^2
    g_c = g * intensity
    g_d2 = zero
    if falloff > zero:
        g_c = g_c / d2
        g_d2 = -(g * intensity * c) / (d2 * d2)
    if clamped:
        g_d2 = zero
    else:
        g_d2 = g_d2 - g_c * c / (d2 + d2)
    two = params[ONE] + params[ONE]
    gtx = g_c * nx / root + two * g_d2 * tx
    gty = g_c * ny / root + two * g_d2 * ty
    gtz = g_c * nz / root + two * g_d2 * tz
    return g_c * tx / root, g_c * ty / root, g_c * tz / root, -gtx, -gty, -gtz


@ray_function
def radiance(nx, ny, nz, px, py, pz, ex, ey, ez, params, sparams, sflags, lights):
    """Ambient plus every light's diffuse term (the scene's lights in order, then the camera light)."""
    rad = sparams[SP_AMBIENT]
    for l in range(lights.shape[0]):
        rad += _light_term(int(lights[l, 0]), lights[l, 1], lights[l, 2], lights[l, 3], lights[l, 4],
                           lights[l, 5], nx, ny, nz, px, py, pz, params, sparams)
    if sflags[SF_CAM_LIGHT] != 0:
        falloff = params[ONE] if sflags[SF_CAM_FALLOFF] != 0 else params[ZERO]
        rad += _light_term(LIGHT_POINT, ex, ey, ez, sparams[SP_CAM_LIGHT], falloff, nx, ny, nz, px, py, pz,
                           params, sparams)
    return rad


@ray_function
def radiance_backward(nx, ny, nz, px, py, pz, ex, ey, ez, g, params, sparams, sflags, lights):
    """The gradient of ``g * radiance`` with respect to the normal and the point (6 values)."""
    zero = params[ZERO]
    gnx = gny = gnz = gpx = gpy = gpz = zero
    for l in range(lights.shape[0]):
        a, b, c, d, e, f = _light_backward(int(lights[l, 0]), lights[l, 1], lights[l, 2], lights[l, 3], lights[l, 4],
                                           lights[l, 5], nx, ny, nz, px, py, pz, g, params, sparams)
        gnx, gny, gnz, gpx, gpy, gpz = gnx + a, gny + b, gnz + c, gpx + d, gpy + e, gpz + f
    if sflags[SF_CAM_LIGHT] != 0:
        falloff = params[ONE] if sflags[SF_CAM_FALLOFF] != 0 else zero
        a, b, c, d, e, f = _light_backward(LIGHT_POINT, ex, ey, ez, sparams[SP_CAM_LIGHT], falloff, nx, ny, nz,
                                           px, py, pz, g, params, sparams)
        gnx, gny, gnz, gpx, gpy, gpz = gnx + a, gny + b, gnz + c, gpx + d, gpy + e, gpz + f
    return gnx, gny, gnz, gpx, gpy, gpz


@ray_helper
def _normalise(gx, gy, gz, params, sparams):
    """renderer/shading.py's surface_normals after the gradient: divided by its largest component
    (exact, keeps the norm near 1), then by sqrt(|g|^2 + eps). Returns (n, scale, flat)."""
    scale = _max(_max(abs(gx), abs(gy)), abs(gz))
    if scale <= sparams[SP_TINY]:
        return params[ZERO], params[ZERO], params[ZERO], scale, True
    gx, gy, gz = gx / scale, gy / scale, gz / scale
    root = math.sqrt((gx * gx + gy * gy) + gz * gz + sparams[SP_EPS])
    return gx / root, gy / root, gz / root, scale, False


@ray_helper
def _silhouette_slope(r, t_extreme, pixel_angle, params, sparams):
    """-1 / (sigma * footprint) of ray r: the soft silhouette is sigmoid(f(x) times this)."""
    foot = t_extreme[r] * pixel_angle
    if foot < params[FLOOR]:
        foot = params[FLOOR]
    return -params[ONE] / (sparams[SP_SIGMA] * foot), foot


@ray_helper
def _silhouette(r, values, b, params, iparams, sparams, extreme, t_extreme, pixel_angle):
    """The soft coverage of ray r: sigmoid(-f(x) / (sigma * footprint))."""
    _, foot = _silhouette_slope(r, t_extreme, pixel_angle, params, sparams)
    f = sample_sdf(values, b, extreme[r, 0], extreme[r, 1], extreme[r, 2], params, iparams)
    z = -f / (sparams[SP_SIGMA] * foot)
    return params[ONE] / (params[ONE] + math.exp(-z))


@ray_helper
def shade_ray(r, values, params, iparams, sparams, sflags, lights, hit, t, points, directions, extreme, t_extreme,
              steps, cam_grid, pixel_angle, eyes, depth_out, normal_out, image_out, silhouette_out):
    """Stage 2 of ray r: writes the outputs ``sflags`` asks for (depth 0, normal 0 and the
    background where the ray missed; silhouette 0 where it never entered the box)."""
    zero = params[ZERO]
    cam = r // sflags[SF_PIXELS]
    b = cam_grid[cam]
    if sflags[SF_SILHOUETTE] != 0:
        sil = zero
        if steps[r] > 0:
            sil = _silhouette(r, values, b, params, iparams, sparams, extreme, t_extreme, pixel_angle[cam])
        silhouette_out[r] = sil
    want_normal = sflags[SF_NORMAL] != 0
    want_image = sflags[SF_SHADING] != 0
    channels = sflags[SF_CHANNELS]
    if hit[r] == 0:
        if sflags[SF_DEPTH] != 0:
            depth_out[r] = zero
        if want_normal:
            normal_out[r, 0] = zero
            normal_out[r, 1] = zero
            normal_out[r, 2] = zero
        if want_image:
            for ch in range(channels):
                image_out[r, ch] = sparams[SP_ALBEDO + channels + ch]
        return
    if sflags[SF_DEPTH] == 0 and not want_normal and not want_image:
        return
    vx, vy, vz = directions[r, 0], directions[r, 1], directions[r, 2]
    fs = sample_sdf(values, b, points[r, 0], points[r, 1], points[r, 2], params, iparams)
    if sflags[SF_DEPTH] != 0:
        depth_out[r] = t[r] + fs
    if not (want_normal or want_image):
        return
    px, py, pz = points[r, 0] + fs * vx, points[r, 1] + fs * vy, points[r, 2] + fs * vz
    i, j, k, wx, wy, wz = _point_cell(px, py, pz, params)
    gx, gy, gz = stencil_gradient(values, b, i, j, k, wx, wy, wz, params, iparams, sparams)
    nx, ny, nz, _, flat = _normalise(gx, gy, gz, params, sparams)
    if flat:
        nx, ny, nz = -vx, -vy, -vz
    if want_normal:
        normal_out[r, 0] = nx
        normal_out[r, 1] = ny
        normal_out[r, 2] = nz
    if want_image:
        rad = radiance(nx, ny, nz, px, py, pz, eyes[cam, 0], eyes[cam, 1], eyes[cam, 2], params, sparams, sflags,
                       lights)
        for ch in range(channels):
            image_out[r, ch] = rad * sparams[SP_ALBEDO + ch]


@ray_helper
def shade_ray_backward(r, values, params, iparams, sparams, sflags, lights, hit, points, directions, extreme,
                       t_extreme, steps, cam_grid, pixel_angle, eyes, grad_depth, grad_normal, grad_image,
                       grad_silhouette, silhouette):
    """The gradient of ray r's stage 2 with respect to the SDF values it read, as the weights of
    three samplings: returns (p (3), dL/df(s), dL/dg (3), dL/df(x)): the hit point, and the
    gradients with respect to the SDF at the traced point s, the (unnormalised) gradient at p and
    the SDF at the silhouette point x (``scatter_ray`` spreads them onto the samples)."""
    zero = params[ZERO]
    cam = r // sflags[SF_PIXELS]
    b = cam_grid[cam]
    g_sil = zero
    if sflags[SF_SILHOUETTE] != 0 and sflags[SF_GRAD_SILHOUETTE] != 0 and steps[r] > 0:
        # the forward's coverage: no second read of the samples at x
        sil = silhouette[r]
        slope, _ = _silhouette_slope(r, t_extreme, pixel_angle[cam], params, sparams)
        g_sil = grad_silhouette[r] * (sil * (params[ONE] - sil)) * slope
    px = py = pz = g_s = ggx = ggy = ggz = zero
    want_normal = sflags[SF_NORMAL] != 0
    want_image = sflags[SF_SHADING] != 0
    if hit[r] == 0 or not (sflags[SF_DEPTH] != 0 or want_normal or want_image):
        return px, py, pz, g_s, ggx, ggy, ggz, g_sil
    if sflags[SF_DEPTH] != 0 and sflags[SF_GRAD_DEPTH] != 0:
        g_s = grad_depth[r]
    grads_normal = want_normal and sflags[SF_GRAD_NORMAL] != 0
    grads_image = want_image and sflags[SF_GRAD_IMAGE] != 0
    if not (grads_normal or grads_image):
        return px, py, pz, g_s, ggx, ggy, ggz, g_sil
    vx, vy, vz = directions[r, 0], directions[r, 1], directions[r, 2]
    fs = sample_sdf(values, b, points[r, 0], points[r, 1], points[r, 2], params, iparams)
    px, py, pz = points[r, 0] + fs * vx, points[r, 1] + fs * vy, points[r, 2] + fs * vz
    i, j, k, wx, wy, wz = _point_cell(px, py, pz, params)
    gx, gy, gz = stencil_gradient(values, b, i, j, k, wx, wy, wz, params, iparams, sparams)
    nx, ny, nz, scale, flat = _normalise(gx, gy, gz, params, sparams)
    if flat:  # the normal faces the camera, without gradient (point lights still see p move)
        nx, ny, nz = -vx, -vy, -vz
    gnx = gny = gnz = gpx = gpy = gpz = zero
    if grads_normal:
        gnx, gny, gnz = grad_normal[r, 0], grad_normal[r, 1], grad_normal[r, 2]
    if grads_image:
        channels = sflags[SF_CHANNELS]
        g_rad = zero
        for ch in range(channels):
            g_rad += grad_image[r, ch] * sparams[SP_ALBEDO + ch]
        a, bb, c, d, e, f = radiance_backward(nx, ny, nz, px, py, pz, eyes[cam, 0], eyes[cam, 1], eyes[cam, 2],
                                              g_rad, params, sparams, sflags, lights)
        gnx, gny, gnz, gpx, gpy, gpz = gnx + a, gny + bb, gnz + c, gpx + d, gpy + e, gpz + f
    if flat:
        g_s += (gpx * vx + gpy * vy) + gpz * vz
        return px, py, pz, g_s, ggx, ggy, ggz, g_sil
    # n = h / sqrt(|h|^2 + eps) with h = g / scale (scale held fixed)
    hx, hy, hz = gx / scale, gy / scale, gz / scale
    root = math.sqrt((hx * hx + hy * hy) + hz * hz + sparams[SP_EPS])
    proj = ((hx * gnx + hy * gny) + hz * gnz) / (root * root * root)
    ggx = (gnx / root - hx * proj) / scale
    ggy = (gny / root - hy * proj) / scale
    ggz = (gnz / root - hz * proj) / scale
    # the gradient's dependence on p, through the trilinear weights
    one = params[ONE]
    interior = _interior(i, j, k, iparams)
    gwx = gwy = gwz = zero
    for c in range(8):
        _, dwx, dwy, dwz = _corner_weight(c, wx, wy, wz, one)
        dx, dy, dz = _corner_differences(values, b, i, j, k, c, interior, params, iparams, sparams)
        e = (dx * ggx + dy * ggy) + dz * ggz
        gwx += dwx * e
        gwy += dwy * e
        gwz += dwz * e
    if _inside(px, 0, params):
        gpx += gwx / params[VOX]
    if _inside(py, 1, params):
        gpy += gwy / params[VOX + 1]
    if _inside(pz, 2, params):
        gpz += gwz / params[VOX + 2]
    g_s += (gpx * vx + gpy * vy) + gpz * vz  # p = s + f(s) v
    return px, py, pz, g_s, ggx, ggy, ggz, g_sil


@ray_helper
def _scatter_trilinear(grad, b, px, py, pz, g, params, iparams):
    """Adds g times the trilinear weights at p onto the 8 samples around it."""
    c, dz, dy, dx, wx, wy, wz = cell_corner(b, px, py, pz, params, iparams)
    one = params[ONE]
    for corner in range(8):
        w, _, _, _ = _corner_weight(corner, wx, wy, wz, one)
        index = c
        if (corner >> 2) & 1:
            index += dx
        if (corner >> 1) & 1:
            index += dy
        if corner & 1:
            index += dz
        scatter_add(grad, index, w * g)


@ray_helper
def scatter_ray(r, grad, params, iparams, sparams, sflags, hit, points, extreme, steps, cam_grid,
                px, py, pz, g_s, ggx, ggy, ggz, g_sil):
    """Adds ray r's gradients (from ``shade_ray_backward``) onto the grid samples it read."""
    zero = params[ZERO]
    b = cam_grid[r // sflags[SF_PIXELS]]
    if g_sil != zero:
        _scatter_trilinear(grad, b, extreme[r, 0], extreme[r, 1], extreme[r, 2], g_sil, params, iparams)
    if hit[r] == 0:
        return
    if g_s != zero:
        _scatter_trilinear(grad, b, points[r, 0], points[r, 1], points[r, 2], g_s, params, iparams)
    if ggx == zero and ggy == zero and ggz == zero:
        return
    i, j, k, wx, wy, wz = _point_cell(px, py, pz, params)
    one = params[ONE]
    interior = _interior(i, j, k, iparams)
    sz = uintp(1)
    sy = uintp(iparams[NZ])
    sx = uintp(iparams[NY] * iparams[NZ])
    for c in range(8):
        w, _, _, _ = _corner_weight(c, wx, wy, wz, one)
        ci, cj, ck = i + ((c >> 2) & 1), j + ((c >> 1) & 1), k + (c & 1)
        if interior:
            at = _vertex(b, ci, cj, ck, iparams)
            gx = w * ggx * sparams[SP_INV_SPAN + 3]
            gy = w * ggy * sparams[SP_INV_SPAN + 4]
            gz = w * ggz * sparams[SP_INV_SPAN + 5]
            scatter_add(grad, at + sx, gx)
            scatter_add(grad, at - sx, -gx)
            scatter_add(grad, at + sy, gy)
            scatter_add(grad, at - sy, -gy)
            scatter_add(grad, at + sz, gz)
            scatter_add(grad, at - sz, -gz)
            continue
        for axis in range(3):
            ga = ggx if axis == 0 else (ggy if axis == 1 else ggz)
            lo, hi, inv = _difference_ends(b, ci, cj, ck, axis, params, iparams, sparams)
            scatter_add(grad, hi, w * ga * inv)
            scatter_add(grad, lo, -(w * ga * inv))


@ray_function
def shade_block(start, end, values, params, iparams, sparams, sflags, lights, hit, t, points, directions, extreme,
                t_extreme, steps, cam_grid, pixel_angle, eyes, depth_out, normal_out, image_out, silhouette_out):
    """``shade_ray`` for rays start..end-1: one call per block of the CPU kernel (a call per ray would
    pass every array's descriptor each time)."""
    for r in range(start, end):
        shade_ray(r, values, params, iparams, sparams, sflags, lights, hit, t, points, directions, extreme,
                  t_extreme, steps, cam_grid, pixel_angle, eyes, depth_out, normal_out, image_out, silhouette_out)


@ray_function
def shade_backward_block(start, end, values, params, iparams, sparams, sflags, lights, hit, points, directions,
                         extreme, t_extreme, steps, cam_grid, pixel_angle, eyes, grad_depth, grad_normal,
                         grad_image, grad_silhouette, silhouette, scratch):
    """``shade_ray_backward`` for rays start..end-1, its 8 results per ray into ``scratch``."""
    for r in range(start, end):
        px, py, pz, g_s, ggx, ggy, ggz, g_sil = shade_ray_backward(
            r, values, params, iparams, sparams, sflags, lights, hit, points, directions, extreme, t_extreme,
            steps, cam_grid, pixel_angle, eyes, grad_depth, grad_normal, grad_image, grad_silhouette, silhouette)
        scratch[r, 0] = px
        scratch[r, 1] = py
        scratch[r, 2] = pz
        scratch[r, 3] = g_s
        scratch[r, 4] = ggx
        scratch[r, 5] = ggy
        scratch[r, 6] = ggz
        scratch[r, 7] = g_sil


@ray_function
def scatter_block(start, end, grad, params, iparams, sparams, sflags, hit, points, extreme, steps, cam_grid,
                  scratch):
    """``scatter_ray`` for rays start..end-1 from their ``scratch`` rows."""
    for r in range(start, end):
        scatter_ray(r, grad, params, iparams, sparams, sflags, hit, points, extreme, steps, cam_grid,
                    scratch[r, 0], scratch[r, 1], scratch[r, 2], scratch[r, 3], scratch[r, 4], scratch[r, 5],
                    scratch[r, 6], scratch[r, 7])


@njit(parallel=True, cache=True, error_model="numpy")
def shade_rays_cpu(values, params, iparams, sparams, sflags, lights, hit, t, points, directions, extreme,
                   t_extreme, steps, cam_grid, pixel_angle, eyes, depth_out, normal_out, image_out, silhouette_out):
    """CPU kernel of stage 2's forward: blocks of BLOCK rays over ``prange``."""
    n = hit.shape[0]
    for blk in prange((n + BLOCK - 1) // BLOCK):
        shade_block(blk * BLOCK, min(n, (blk + 1) * BLOCK), values, params, iparams, sparams, sflags, lights, hit,
                    t, points, directions, extreme, t_extreme, steps, cam_grid, pixel_angle, eyes, depth_out,
                    normal_out, image_out, silhouette_out)


@ray_function
def backward_scatter_block(start, end, grad, values, params, iparams, sparams, sflags, lights, hit, points, directions,
                           extreme, t_extreme, steps, cam_grid, pixel_angle, eyes, grad_depth, grad_normal,
                           grad_image, grad_silhouette, silhouette):
    """``shade_ray_backward`` then ``scatter_ray`` for rays start..end-1, each ray's samples added
    while they are still in the cache."""
    for r in range(start, end):
        px, py, pz, g_s, ggx, ggy, ggz, g_sil = shade_ray_backward(
            r, values, params, iparams, sparams, sflags, lights, hit, points, directions, extreme, t_extreme,
            steps, cam_grid, pixel_angle, eyes, grad_depth, grad_normal, grad_image, grad_silhouette, silhouette)
        scatter_ray(r, grad, params, iparams, sparams, sflags, hit, points, extreme, steps, cam_grid, px, py, pz,
                    g_s, ggx, ggy, ggz, g_sil)


@njit(parallel=True, cache=True, error_model="numpy")
def shade_rays_backward_cpu(values, params, iparams, sparams, sflags, lights, hit, points, directions, extreme,
                            t_extreme, steps, cam_grid, pixel_angle, eyes, grad_depth, grad_normal, grad_image,
                            grad_silhouette, silhouette, grids, scratch, grad):
    """CPU kernel of stage 2's backward into ``grad`` (the flat gradient of the values, zeroed here:
    its contents on entry do not matter). The rays of
    grid g are a contiguous range (consecutive cameras see the same grid), so threads that each take
    whole grids never write the same sample: with ``scratch`` empty (several grids per thread) one
    pass over the grids does each ray's gradient and its scatter together; otherwise every ray's
    gradient first goes into ``scratch`` (R, 8) (blocks of rays in parallel), then the scatter runs
    over the grids (serially when there is one)."""
    n = hit.shape[0]
    per_grid = n // grids
    size = grad.shape[0] // grids
    if scratch.shape[0] == 0:
        for g in prange(grids):
            grad[g * size:(g + 1) * size] = 0  # zeroed by the thread that adds into it: still cached then
            backward_scatter_block(g * per_grid, (g + 1) * per_grid, grad, values, params, iparams, sparams, sflags,
                                   lights, hit, points, directions, extreme, t_extreme, steps, cam_grid, pixel_angle,
                                   eyes, grad_depth, grad_normal, grad_image, grad_silhouette, silhouette)
        return
    for blk in prange((n + BLOCK - 1) // BLOCK):
        shade_backward_block(blk * BLOCK, min(n, (blk + 1) * BLOCK), values, params, iparams, sparams, sflags,
                             lights, hit, points, directions, extreme, t_extreme, steps, cam_grid, pixel_angle,
                             eyes, grad_depth, grad_normal, grad_image, grad_silhouette, silhouette, scratch)
    for g in prange(grids):
        grad[g * size:(g + 1) * size] = 0
        scatter_block(g * per_grid, (g + 1) * per_grid, grad, params, iparams, sparams, sflags, hit, points,
                      extreme, steps, cam_grid, scratch)


def cuda_shade_body(values, params, iparams, sparams, sflags, lights, hit, t, points, directions, extreme,
                    t_extreme, steps, cam_grid, pixel_angle, eyes, depth_out, normal_out, image_out, silhouette_out):
    """CUDA kernel body of stage 2's forward (compiled by ``make_cuda_shade_kernels``): one ray per thread."""
    r = cuda.grid(1)
    if r < hit.shape[0]:
        shade_ray(r, values, params, iparams, sparams, sflags, lights, hit, t, points, directions, extreme,
                  t_extreme, steps, cam_grid, pixel_angle, eyes, depth_out, normal_out, image_out, silhouette_out)


def cuda_shade_backward_body(values, params, iparams, sparams, sflags, lights, hit, points, directions, extreme,
                             t_extreme, steps, cam_grid, pixel_angle, eyes, grad_depth, grad_normal, grad_image,
                             grad_silhouette, silhouette, grad):
    """CUDA kernel body of stage 2's backward: one ray per thread, its gradients added atomically."""
    r = cuda.grid(1)
    if r < hit.shape[0]:
        px, py, pz, g_s, ggx, ggy, ggz, g_sil = shade_ray_backward(
            r, values, params, iparams, sparams, sflags, lights, hit, points, directions, extreme, t_extreme,
            steps, cam_grid, pixel_angle, eyes, grad_depth, grad_normal, grad_image, grad_silhouette, silhouette)
        scatter_ray(r, grad, params, iparams, sparams, sflags, hit, points, extreme, steps, cam_grid, px, py, pz, g_s,
                    ggx, ggy, ggz, g_sil)


_cuda_shade_kernels = None


def make_cuda_shade_kernels():
    """The CUDA kernels of stage 2 (forward, backward), compiled lazily once; ``scatter_add`` is an
    atomic add there."""
    global cuda, _cuda_shade_kernels
    if _cuda_shade_kernels is None:
        from numba import cuda as numba_cuda

        cuda = numba_cuda
        _register_cuda_scatter_add(numba_cuda)
        _cuda_shade_kernels = (numba_cuda.jit(cache=True)(cuda_shade_body),
                               numba_cuda.jit(cache=True)(cuda_shade_backward_body))
    return _cuda_shade_kernels


_cuda_scatter_registered = False


def _register_cuda_scatter_add(numba_cuda):
    global _cuda_scatter_registered
    if _cuda_scatter_registered:
        return

    @overload(scatter_add, target="cuda")
    def _scatter_add_cuda(grad, index, value):
        def impl(grad, index, value):
            numba_cuda.atomic.add(grad, index, value)

        return impl

    _cuda_scatter_registered = True
