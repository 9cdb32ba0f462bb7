"""The differentiable stage: hit points, normals, lights, materials and soft silhouettes.

Everything here is plain PyTorch on flat lists of rays (K hit rays or R rays), differentiable with
respect to the grid values. The traced points come in detached: gradients reach the grid only
through the SDF samples read here (the paper's local-shading approximation).
"""
from __future__ import annotations

import torch

from .grid import SDFGrid
from .scene import DirectionalLight, PointLight, Scene


def hit_points_conservative(grid: SDFGrid, s: torch.Tensor, v: torch.Tensor, b: torch.Tensor):
    """The paper's hit point ``p = s + f(s) v``.

    Args:
        s: (K, 3) traced points (world, detached); v: (K, 3) unit ray directions; b: (K,) grid index.
    Returns:
        p: (K, 3) hit points; dt: (K,) offset along the ray (``depth = t + dt``), both differentiable.

    The gradient treats ``s`` as fixed: d p / d values = v * d f(s) / d values. For a locally planar
    SDF with the ray at angle theta to the normal the whole render's depth moves by 1/cos(theta)
    per unit change of the SDF, this approximation by 1: exact head-on, too small at grazing angles.
    """
    f = grid.sample(s, b)
    return s + f[:, None] * v, f


def surface_normals(grid: SDFGrid, p: torch.Tensor, b: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Unit normals at p: central differences at the vertices, trilinearly interpolated, normalised.

    Args:
        p: (K, 3) world points; b: (K,) grid index; v: (K, 3) ray directions (used where the
            gradient vanishes, e.g. a flat region: the normal then faces the camera, without gradient).
    Returns:
        (K, 3) unit normals (world), finite for any finite grid.
    """
    g = grid.sample_gradient(p, b)
    # Normalising g / s for a (detached) positive s gives the same value and the same gradient as
    # normalising g, and keeps |g / s| near 1 whatever the SDF's scale (1e-6 or 1e6).
    scale = g.detach().abs().amax(dim=-1, keepdim=True)
    flat = scale <= torch.finfo(g.dtype).tiny
    g = g / torch.where(flat, torch.ones_like(scale), scale)
    n = g / torch.sqrt((g * g).sum(-1, keepdim=True) + torch.finfo(g.dtype).eps)
    return torch.where(flat, -v.detach(), n)


def shade_lambert(normals: torch.Tensor, points: torch.Tensor, eyes: torch.Tensor, scene: Scene) -> torch.Tensor:
    """Lambert diffuse + ambient shading.

    Args:
        normals: (K, 3) unit normals; points: (K, 3) hit points; eyes: (K, 3) camera positions (world).
    Returns:
        (K, C) radiance, C = len(scene.albedo).
    """
    radiance = torch.full_like(normals[:, 0], float(scene.ambient))
    tiny = torch.finfo(points.dtype).tiny
    sources = list(scene.lights)
    for light in sources:
        if isinstance(light, DirectionalLight):
            ldir = torch.tensor(light.direction, dtype=normals.dtype, device=normals.device)
            ldir = ldir / ldir.norm()
            radiance = radiance + light.intensity * torch.clamp((normals * ldir).sum(-1), min=0.0)
        elif isinstance(light, PointLight):
            pos = torch.tensor(light.position, dtype=normals.dtype, device=normals.device)
            radiance = radiance + _point_light(normals, points, pos, light.intensity, light.falloff, tiny)
    if scene.camera_light is not None:
        radiance = radiance + _point_light(normals, points, eyes, scene.camera_light, scene.camera_light_falloff, tiny)
    albedo = torch.tensor(scene.albedo, dtype=normals.dtype, device=normals.device)
    return radiance[:, None] * albedo[None, :]


def _point_light(normals, points, pos, intensity, falloff, tiny):
    to_light = pos - points
    dist2 = torch.clamp((to_light * to_light).sum(-1), min=tiny)
    cos = (normals * to_light).sum(-1) / torch.sqrt(dist2)
    contrib = intensity * torch.clamp(cos, min=0.0)
    return contrib / dist2 if falloff else contrib


def soft_silhouette(grid: SDFGrid, x: torch.Tensor, b: torch.Tensor, footprint: torch.Tensor,
                    sigma: float) -> torch.Tensor:
    """Soft coverage ``sigmoid(-sdf(x) / (sigma * footprint))``.

    Args:
        x: (R, 3) per ray, the closest approach (misses) or the deepest point behind the hit (hits).
        b: (R,) grid index. footprint: (R,) pixel footprint at x (world units, > 0).
        sigma: width in pixels.
    Returns:
        (R,) silhouette in [0, 1]; the gradient reaches the 8 samples around each x.
    """
    f = grid.sample(x, b)
    return torch.sigmoid(-f / (sigma * footprint))
