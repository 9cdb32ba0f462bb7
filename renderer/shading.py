"""Stage 2 in plain PyTorch, ``shade_reference``: the specification the fused stage 2
(renderer/fused.py) is tested against, and its fallback; with its parts (hit points, normals,
Lambert shading, soft silhouettes), each on flat lists of rays (K hit rays or R rays) and
differentiable w.r.t. the grid values by autograd. The traced points come in detached: gradients
reach the grid only through the SDF samples read here (the paper's local-shading approximation),
and, with the visibility gradient, through the SDF at each edge pixel's grazing point
(``edge_gradient``).
"""
from __future__ import annotations

import torch

from .exact import hit_points_exact
from .grid import SDFGrid
from .records import Shading, ShadingRays
from .reference import min_threshold
from .scene import DirectionalLight, PointLight, Scene


def shade_reference(grid: SDFGrid, rays: ShadingRays, scene: Scene) -> Shading:
    """The passes ``scene.effects`` need, for R rays marched through ``grid``, in plain autograd
    (given a plain SDFGrid; renderer/stage2.py passes ``with_shared_gradient(grid)``, whose
    samplings give the same values and gradients faster).

    Hit rays get the hit point (conservative or exact, ``scene.intersection``), then the depth, the
    normal and the shading the scene asks for (with ``scene.gradient="visibility"`` the image adds
    ``edge_gradient``: zero in value, the edges' motion in gradient); every ray that entered the
    grid's box gets the soft silhouette at its extreme point (0 for the others: the SDF is
    undefined outside the box).

    Returns:
        Shading of the R rays (the grid's dtype and device), differentiable w.r.t. ``grid.values``.
    """
    total = rays.count
    depth = normal = image = silhouette = None
    if scene.needs_hit_points():
        idx = rays.hit.nonzero().squeeze(1)
        cam = idx // rays.pixels
        gi = rays.camera_grid[cam]
        s, v = rays.points[idx], rays.directions[idx]
        p, dt_off = hit_points_conservative(grid, s, v, gi)
        if scene.intersection == "exact":
            p, dt_off = hit_points_exact(grid, s, v, gi, p, dt_off)
        if scene.wants("depth"):
            depth = _scatter(rays.t[idx] + dt_off, idx, total, 0.0)
        if scene.needs_normals():
            n = surface_normals(grid, p, gi, v)
            if scene.wants("normal"):
                normal = _scatter(n, idx, total, 0.0)
            if scene.wants("shading"):
                image = _scatter(shade_lambert(n, p, rays.eyes[cam], scene), idx, total, scene.background)
                if scene.needs_grazing():
                    image = image + edge_gradient(grid, rays, image.detach(), scene)
    if scene.wants("silhouette"):
        ray_cam = rays.camera()
        foot = torch.clamp(rays.t_extreme * rays.pixel_angle[ray_cam], min=min_threshold(grid))
        sil = soft_silhouette(grid, rays.extreme, rays.camera_grid[ray_cam], foot, scene.silhouette_sigma)
        # Rays that never enter the grid's box see nothing (the SDF is undefined outside it): they
        # are the rays the march took no sample on (every march samples a ray that enters).
        silhouette = torch.where(rays.steps > 0, sil, torch.zeros_like(sil))
    return Shading(depth=depth, normal=normal, silhouette=silhouette, image=image)


def _scatter(values: torch.Tensor, index: torch.Tensor, total: int, fill) -> torch.Tensor:
    """(total, ...) filled with ``fill``, ``values`` (K, ...) at rows ``index`` (K,); differentiable."""
    out = torch.empty((total, *values.shape[1:]), dtype=values.dtype, device=values.device)
    out[...] = torch.as_tensor(fill, dtype=values.dtype, device=values.device)
    return out.index_put((index,), values)


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


def edge_gradient(grid: SDFGrid, rays: ShadingRays, image: torch.Tensor, scene: Scene) -> torch.Tensor:
    """The derivative of the anti-aliased image where an edge moves, as a term that is zero in value.

    A ray that passes a surface at its grazing point g (the march's ``graze_t``) sees what lies
    behind (``L_far``: its own colour, a farther surface or the background); the rays beside it
    on the other side of the edge meet the surface there (``L_near``: the colour a hit at g would
    get). A pixel's box-filtered value then moves, where the edge crosses it, by
    ``(L_far - L_near) * delta(f(g) - thr) * d f(g)`` (the grazing point sits at a minimum of the SDF
    along the ray, so only the SDF's change at g counts, not g's motion). The band method (Wang et
    al. 2024, "A Simple Approach to Differentiable Rendering of SDFs") replaces the delta by a box
    over a band of ``scene.visibility_band`` pixel footprints on the passing side: the rays whose
    gap ``x = f(g) - thr`` lies in it, ``0 <= x < width``, get ``(L_far - L_near) / width * d f(g)``,
    so the band's pixels together carry the edge's gradient. Biased (the gradient sits on the
    passing side, half the band from the edge on average, and one sample per pixel gives a band of
    about one pixel all or nothing where an edge runs along the pixel grid) and without noise; it
    covers the outline against the background and self-occlusion edges (the rim of a concavity, a
    part in front of another) alike. A tent or a hat over the band instead of the box traded one
    scene's error against finite differences for another's (tests/renderer/test_visibility.py).

    Args:
        rays: R rays marched with grazing points. image: (R, C) the rendered colours, detached.
    Returns:
        (R, C), zero in value; its gradient reaches the 8 samples around each band ray's grazing point.
    """
    band = rays.graze_gap < scene.visibility_band  # +inf where a ray has no grazing point
    idx = band.nonzero().squeeze(1)
    cam = idx // rays.pixels
    gi = rays.camera_grid[cam]
    v, eye, t_g = rays.directions[idx], rays.eyes[cam], rays.graze_t[idx]
    f = grid.sample(eye + t_g[:, None] * v, gi)
    with torch.no_grad():
        q = eye + (t_g + f)[:, None] * v  # the hit a ray just across the edge gets (conservative)
        near = shade_lambert(surface_normals(grid, q, gi, v), q, eye, scene)
        width = scene.visibility_band * torch.clamp(t_g * rays.pixel_angle[cam], min=min_threshold(grid))
        weight = (image[idx] - near) / width[:, None]
    return _scatter(weight * (f - f.detach())[:, None], idx, rays.count, 0.0)


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
