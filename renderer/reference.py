"""The vectorised-PyTorch sphere-tracing march, ``march_reference``: stage 1's specification,
which the fused kernels (renderer/fused.py, renderer/kernels/) must match step for step; its
docstring gives the rule.
"""
from __future__ import annotations

import torch

from .grid import SDFGrid
from .records import MarchedRays
from .settings import TraceSettings

# Direction components smaller than this are treated as this (keeping their sign), so the slab
# test never divides by zero and never forms 0 * inf.
TINY_DIRECTION = 1e-30


def box_interval(origins: torch.Tensor, directions: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor):
    """Slab test. origins/directions (R, 3), lo/hi (3,) -> t_near (R,), t_far (R,)."""
    d = directions
    safe = torch.where(d.abs() < TINY_DIRECTION, torch.where(d < 0, -TINY_DIRECTION, TINY_DIRECTION), d)
    inv = 1.0 / safe
    t1 = (lo - origins) * inv
    t2 = (hi - origins) * inv
    t_near = torch.minimum(t1, t2).amax(dim=-1)
    t_far = torch.maximum(t1, t2).amin(dim=-1)
    return t_near, t_far


def min_threshold(grid: SDFGrid) -> float:
    """The floor of the hit threshold: a tiny fraction of the voxel, so marches always progress."""
    return 1e-4 * float(grid.host_voxel_size().min())


@torch.no_grad()
def march_reference(
    grid: SDFGrid,
    origins: torch.Tensor,
    directions: torch.Tensor,
    grid_index: torch.Tensor,
    pixel_angle: torch.Tensor,
    settings: TraceSettings,
    grazing: bool = False,
) -> MarchedRays:
    """Sphere-traces R rays through ``grid``.

    Per ray (origin o, unit direction d, the grid it reads, its pixel angle), without gradients:

    1. Box entry/exit ``[t_near, t_far]`` by the slab test; the march starts at ``t0 = max(t_near, 0)``
       (the eye may be inside the box). A ray that misses the box is a miss whose closest approach is
       the point on the ray nearest the box centre, clamped into the box.
    2. ``sign`` = -1 if the SDF at the start is negative (the eye is inside the shape; the ray then
       looks for the surface from inside), else +1. All tests below use ``f = sign * sdf``.
    3. March: ``f = sign * sdf(o + t d)``; if ``f < thr(t)`` the ray hits at t; else ``t += f``; the
       ray misses when ``t > t_far`` or after ``max_steps`` samples. ``thr(t)`` is
       ``settings.threshold`` if given, else ``threshold_scale * t * pixel_angle`` (the pixel footprint),
       never below ``min_threshold`` (so every step makes progress). The sample with the smallest f
       is the closest approach (used for the silhouettes of misses).
       With ``grazing``, a sample whose f is at most the previous one's and below the next one's is
       a local minimum (the first sample never is): where the ray passes a surface without meeting
       it, the rim of an occluder or an outline. Of these, the one with the smallest gap
       ``(f - thr(t)) / footprint(t)`` (``footprint = max(t * pixel_angle, min_threshold)``) is the
       ray's grazing point; a hit's last sample never is one, so a hit's grazing point lies in front
       of what it hit. Rays with sign -1 have none.
    4. Hits with sign +1 then look for the smallest SDF along the rest of the ray (for the soft
       silhouette of hits): from the hit, step by ``max(|sdf|, thr)`` (a safe sphere-tracing step inside
       and outside the shape, so a ray that leaves a thin part goes on to what lies behind it), at most
       ``inner_steps`` samples, stopping once the smallest SDF is below ``-inner_depth * thr(t)`` (the
       silhouette is saturated) or past t_far.
       Rays with sign -1 use their start point.

    The outputs per ray: ``t`` (traced distance, 0 for rays that miss the box), ``hit``, ``extreme``
    (the closest-approach/deepest point, world), ``t_extreme`` and ``steps`` (SDF samples taken in 3).

    Args:
        origins, directions: (R, 3) world, directions of unit length, grid dtype.
        grid_index: (R,) long, which grid of the batch each ray reads.
        pixel_angle: (R,) pixel footprint per unit distance.
        grazing: whether to find each ray's grazing point (visibility gradients, renderer/shading.py).
    Returns:
        MarchedRays (detached, the grid's dtype and device).
    """
    dt = grid.dtype
    o = origins.to(dt)
    d = directions.to(dt)
    pix = pixel_angle.to(dt)
    gi = grid_index.long()
    r = o.shape[0]
    dev = o.device
    lo, hi = grid.bbox_min, grid.bbox_max
    floor = min_threshold(grid)
    g = grid.detach()  # no autograd bookkeeping in the march

    def sample(p, b):
        return g.sample(p, b)

    def thr(t, pa):
        if settings.threshold is not None:
            return torch.full_like(t, max(float(settings.threshold), floor))
        return torch.clamp(settings.threshold_scale * t * pa, min=floor)

    t_near, t_far = box_interval(o, d, lo, hi)
    t0 = torch.clamp(t_near, min=0.0)
    in_box = t_far >= t0

    t = torch.where(in_box, t0, torch.zeros_like(t0))
    hit = torch.zeros(r, dtype=torch.bool, device=dev)
    steps = torch.zeros(r, dtype=torch.int32, device=dev)
    sign = torch.ones(r, dtype=dt, device=dev)
    best_f = torch.full((r,), float("inf"), dtype=dt, device=dev)
    best_t = t.clone()
    # Grazing points: the previous sample (f = -inf before the first, so it is never a minimum) and
    # whether f fell to it.
    graze_gap = torch.full((r,), float("inf"), dtype=dt, device=dev)
    graze_t = torch.zeros(r, dtype=dt, device=dev)
    last_f = torch.full((r,), float("-inf"), dtype=dt, device=dev)
    last_t = t.clone()
    falling = torch.zeros(r, dtype=torch.bool, device=dev)

    # Rays that miss the box: closest approach to the box centre, clamped into the box.
    centre = (lo + hi) / 2
    t_c = torch.clamp(((centre - o) * d).sum(-1), min=0.0)
    extreme = torch.minimum(torch.maximum(o + t_c[:, None] * d, lo), hi)
    t_ext = t_c.clone()

    idx = in_box.nonzero().squeeze(1)
    if idx.numel():
        f_start = sample(o[idx] + t[idx, None] * d[idx], gi[idx])
        sign[idx] = torch.where(f_start < 0, -1.0, 1.0).to(dt)

    active = idx
    for _ in range(settings.max_steps):
        if active.numel() == 0:
            break
        ta = t[active]
        f = sign[active] * sample(o[active] + ta[:, None] * d[active], gi[active])
        steps[active] += 1
        better = f < best_f[active]
        best_f[active] = torch.where(better, f, best_f[active])
        best_t[active] = torch.where(better, ta, best_t[active])
        is_hit = f < thr(ta, pix[active])
        hit[active[is_hit]] = True
        if grazing:
            lf, lt = last_f[active], last_t[active]
            foot = torch.clamp(lt * pix[active], min=floor)
            gap = (lf - thr(lt, pix[active])) / foot
            closer = falling[active] & (f > lf) & (gap < graze_gap[active])
            graze_gap[active] = torch.where(closer, gap, graze_gap[active])
            graze_t[active] = torch.where(closer, lt, graze_t[active])
            falling[active] = f <= lf
            last_f[active] = f
            last_t[active] = ta
        t_next = ta + f
        t[active] = torch.where(is_hit, ta, t_next)
        going = (~is_hit) & (t_next <= t_far[active])
        active = active[going]

    marched = in_box & ~hit
    extreme[marched] = o[marched] + best_t[marched, None] * d[marched]
    t_ext[marched] = best_t[marched]

    # Deepest point behind the surface, for hits found from outside.
    inner = (hit & (sign > 0)).nonzero().squeeze(1)
    ti = t[inner].clone()
    best_in = best_f[inner].clone()  # f at the hit is the smallest f of the march
    best_ti = ti.clone()
    fi = best_in.clone()
    act = torch.arange(inner.numel(), device=dev)
    for _ in range(settings.inner_steps):
        if act.numel() == 0:
            break
        ray = inner[act]
        t_cur = ti[act]
        step = torch.maximum(fi[act].abs(), thr(t_cur, pix[ray]))
        t_new = t_cur + step
        f_new = sample(o[ray] + t_new[:, None] * d[ray], gi[ray])
        in_box_now = t_new <= t_far[ray]
        deeper = in_box_now & (f_new < best_in[act])
        ti[act] = t_new
        fi[act] = f_new
        best_in[act] = torch.where(deeper, f_new, best_in[act])
        best_ti[act] = torch.where(deeper, t_new, best_ti[act])
        keep = in_box_now & (best_in[act] > -settings.inner_depth * thr(t_new, pix[ray]))
        act = act[keep]
    extreme[inner] = o[inner] + best_ti[:, None] * d[inner]
    t_ext[inner] = best_ti

    start_inside = hit & (sign < 0)
    extreme[start_inside] = o[start_inside] + t0[start_inside, None] * d[start_inside]
    t_ext[start_inside] = t0[start_inside]
    # Rays that began inside the shape and never reached its surface are misses; their start point
    # (negative SDF) is still the right place for the silhouette.
    inside_miss = in_box & ~hit & (sign < 0)
    extreme[inside_miss] = o[inside_miss] + t0[inside_miss, None] * d[inside_miss]
    t_ext[inside_miss] = t0[inside_miss]

    if not grazing:
        return MarchedRays(t=t, hit=hit, extreme=extreme, t_extreme=t_ext, steps=steps)
    inside = sign < 0
    graze_gap[inside] = float("inf")
    graze_t[inside] = 0.0
    return MarchedRays(t=t, hit=hit, extreme=extreme, t_extreme=t_ext, steps=steps, graze_t=graze_t,
                       graze_gap=graze_gap)
