"""The exact intersection, ``hit_points_exact``: the root of the trilinear SDF along the ray near
the traced point, found robustly (bracket, bisection, implicit differentiation; its docstring gives
the rule), where the paper's conservative point ``p = s + f(s) v`` stops short of the surface by up
to the hit threshold times ``1/cos(theta) - 1``.
"""
from __future__ import annotations

import torch

from .grid import SDFGrid

BRACKET_STEPS = 8
GRAZING_COS = 0.05


def hit_points_exact(grid: SDFGrid, s: torch.Tensor, v: torch.Tensor, b: torch.Tensor, p_cons: torch.Tensor,
                     dt_cons: torch.Tensor):
    """Exact hit points on the trilinear surface near traced points: the root of
    ``g(t) = trilinear(s + t v)``.

    1. Bracket: sample g at ``t = +-k delta`` (k = 1..BRACKET_STEPS, ``delta = max(|g(0)|, h/20)``),
       nearest first, and take the first sign change around ``t = 0``.
    2. Bisection inside the bracket (no gradient), to float precision.
    3. Implicit differentiation: with ``t*`` the root, ``dt*/dvalues = -(dg/dvalues) / (dg/dt)``;
       implemented as ``t = t* - g(t*) / g'(t*)`` with ``t*`` and ``g'`` detached (its value is t*).
    4. Fallback to the conservative point where no sign change is found (the ray passed within the
       threshold without crossing) or where the ray grazes the surface (``|g'| < GRAZING_COS * |grad|``),
       where the root's derivative blows up.

    Args:
        s: (K, 3) traced points (world; detached unless the cameras carry a gradient); v: (K, 3) unit
            directions; b: (K,) grid index.
        p_cons, dt_cons: (K, 3), (K,) the conservative hit points and offsets
            (``renderer.shading.hit_points_conservative``), the fallback.
    Returns:
        p: (K, 3) hit points; dt: (K,) offset along the ray (``depth = t + dt``); differentiable
        w.r.t. the grid values through the implicit function theorem, and w.r.t. ``s`` and ``v``
        where they carry a gradient (cameras being optimised).
    """
    k = s.shape[0]
    if k == 0:
        return p_cons, dt_cons
    with torch.no_grad():
        g = grid.detach()
        f0 = g.sample(s, b)
        h = float(grid.voxel_size.min())
        delta = torch.clamp(f0.abs(), min=h / 20)
        ks = torch.arange(1, BRACKET_STEPS + 1, dtype=s.dtype, device=s.device)
        offsets = torch.stack([ks, -ks], dim=1).reshape(-1)  # +1, -1, +2, -2, ...
        ts = offsets[None, :] * delta[:, None]  # (K, 2S)
        pts = s[:, None, :] + ts[..., None] * v[:, None, :]
        fs = g.sample(pts.reshape(-1, 3), b.repeat_interleave(ts.shape[1])).reshape(k, -1)
        change = torch.signbit(fs) != torch.signbit(f0)[:, None]
        found = change.any(dim=1)
        first = torch.argmax(change.to(torch.int8), dim=1)
        t_far = ts.gather(1, first[:, None]).squeeze(1)
        # The other end of the bracket: the previous sample on the same side of 0 (or 0 itself).
        prev = first - 2
        t_near = torch.where(prev >= 0, ts.gather(1, prev.clamp(min=0)[:, None]).squeeze(1), torch.zeros_like(t_far))
        lo, hi = t_near, t_far
        f_lo = torch.where(prev >= 0, fs.gather(1, prev.clamp(min=0)[:, None]).squeeze(1), f0)
        iters = 60 if s.dtype == torch.float64 else 30
        for _ in range(iters):
            mid = (lo + hi) / 2
            f_mid = g.sample(s + mid[:, None] * v, b)
            same = torch.signbit(f_mid) == torch.signbit(f_lo)
            lo = torch.where(same, mid, lo)
            f_lo = torch.where(same, f_mid, f_lo)
            hi = torch.where(same, hi, mid)
        t_star = (lo + hi) / 2
        root = s + t_star[:, None] * v
    # Slope of g along the ray at the root (exact trilinear derivative, detached).
    with torch.enable_grad():
        q = root.detach().requires_grad_(True)
        (grad_q,) = torch.autograd.grad(g.sample(q, b).sum(), q)
    slope = (grad_q * v).sum(-1)
    steep = slope.abs() > GRAZING_COS * grad_q.norm(dim=-1).clamp(min=torch.finfo(s.dtype).tiny)
    ok = found & steep
    safe_slope = torch.where(ok, slope, torch.ones_like(slope))
    # ~0 in value; carries d g / d values, and the ray's motion (a camera with a gradient: s and v
    # then carry it) through the root's own point, so dt gets the implicit derivative of both.
    moving = root.detach() + (s - s.detach()) + t_star[:, None] * (v - v.detach())
    g_root = grid.sample(moving, b)
    t_exact = t_star - g_root / safe_slope
    dt = torch.where(ok, t_exact, dt_cons)
    p = s + dt[:, None] * v
    return p, dt
