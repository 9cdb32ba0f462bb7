"""Analytic shapes and exact ray intersections used by the renderer tests."""
from __future__ import annotations

import torch

TORUS_R, TORUS_r = 0.5, 0.2


def sphere_sdf(radius: float = 0.5, centre=(0.0, 0.0, 0.0)):
    c = torch.tensor(centre, dtype=torch.float64)
    return lambda p: (p - c.to(p.dtype)).norm(dim=-1) - radius


def torus_sdf(p: torch.Tensor, big: float = TORUS_R, small: float = TORUS_r) -> torch.Tensor:
    """Torus around the y axis."""
    q = torch.stack([torch.linalg.norm(p[..., [0, 2]], dim=-1) - big, p[..., 1]], dim=-1)
    return torch.linalg.norm(q, dim=-1) - small


def ray_sphere(o, d, radius=0.5):
    """Exact first hit of rays (..., 3) with a centred sphere: (hit, t, normal)."""
    b = (o * d).sum(-1)
    c = (o * o).sum(-1) - radius**2
    disc = b * b - c
    hit = (disc > 0) & (-b + disc.clamp(min=0).sqrt() > 0)
    t = -b - disc.clamp(min=0).sqrt()
    p = o + t[..., None] * d
    return hit, t, p / p.norm(dim=-1, keepdim=True)


def ray_analytic(sdf, o, d, t_max=10.0, eps=1e-10, steps=4000):
    """First hit of rays with an exact SDF (float64 sphere tracing to eps): (hit, t, normal)."""
    o, d = o.double(), d.double()
    t = torch.zeros(o.shape[:-1], dtype=torch.float64)
    hit = torch.zeros_like(t, dtype=torch.bool)
    for _ in range(steps):
        f = sdf(o + t[..., None] * d)
        hit = hit | (f < eps)
        t = torch.where(hit | (t > t_max), t, t + f)
    p = (o + t[..., None] * d).requires_grad_(True)
    (g,) = torch.autograd.grad(sdf(p).sum(), p)
    return hit & (t <= t_max), t, g / g.norm(dim=-1, keepdim=True)


def edge_pixels(mask: torch.Tensor) -> torch.Tensor:
    """(..., H, W) bool: pixels whose 8-neighbourhood holds both values (silhouette edges)."""
    m = mask.float().reshape(-1, 1, *mask.shape[-2:])
    mx = torch.nn.functional.max_pool2d(m, 3, 1, 1)
    mn = -torch.nn.functional.max_pool2d(-m, 3, 1, 1)
    return (mx != mn).reshape(mask.shape)
