"""render(): trace -> the passes the scene asks for -> RenderOutput."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch

from .cameras import Cameras
from .grid import SDFGrid
from .reference import min_threshold
from .scene import Scene
from .settings import TraceSettings
from .shading import hit_points_conservative, shade_lambert, soft_silhouette, surface_normals
from .stage2 import STAGE2, can_fuse, fused_backend, shade_trace_fused
from .trace import TraceResult, _warn_once, sphere_trace


@dataclass(frozen=True)
class RenderOutput:
    """A render of B_c cameras (an effect the scene did not ask for is None).

    Attributes:
        hit: (B, H, W) bool, rays that met the surface.
        depth: (B, H, W) distance from the eye to the hit point along the ray; 0 where no hit.
        normal: (B, H, W, 3) unit world normals at the hit points; 0 where no hit.
        silhouette: (B, H, W) soft coverage in [0, 1].
        image: (B, H, W, C) shaded colour; the scene's background where no hit.
        trace: the TraceResult the render was made from.
    """

    hit: torch.Tensor
    depth: Optional[torch.Tensor]
    normal: Optional[torch.Tensor]
    silhouette: Optional[torch.Tensor]
    image: Optional[torch.Tensor]
    trace: TraceResult


def render(
    grid: SDFGrid,
    cameras: Cameras,
    scene: Scene = Scene(),
    trace_settings: TraceSettings = TraceSettings(),
    backend: str = "auto",
) -> RenderOutput:
    """Renders SDF grids: sphere tracing without gradients, then differentiable local shading.

    With a fused march (``backend`` "cpu", "cuda", or "auto" where the kernels are available) the
    differentiable stage is fused too (renderer/stage2.py), except for the exact intersection;
    ``backend="reference"`` runs the PyTorch specification of both stages.

    Args:
        grid: B_g grids. cameras: B_c cameras, a multiple of B_g; camera c sees grid
            ``c // (B_c / B_g)`` (one grid seen by many cameras, or G grids by V cameras each).
        scene: effects, lights, material, background.
        trace_settings: the march (steps, threshold).
        backend: "auto", "reference", "cpu" or "cuda" (see renderer.trace.sphere_trace).
    Returns:
        RenderOutput, differentiable w.r.t. ``grid.values``.
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a Scene, got {type(scene).__name__}")
    trace = sphere_trace(grid, cameras, trace_settings, backend)
    return shade_trace(grid, cameras, trace, scene)


def _scatter(values: torch.Tensor, index: torch.Tensor, total: int, fill) -> torch.Tensor:
    out = torch.empty((total, *values.shape[1:]), dtype=values.dtype, device=values.device)
    out[...] = torch.as_tensor(fill, dtype=values.dtype, device=values.device)
    return out.index_put((index,), values)


def shade_trace(grid: SDFGrid, cameras: Cameras, trace: TraceResult, scene: Scene,
                stage2: str = "auto") -> RenderOutput:
    """The differentiable stage: the passes ``scene.effects`` need, from a fixed TraceResult.

    Args:
        stage2: "reference", the PyTorch code below (renderer/shading.py); "fused", one kernel
            forward and one backward (renderer/stage2.py; the grid's device must have the fused
            kernels, and the intersection must be the conservative one); "auto", fused after a
            fused march with the conservative intersection, else the reference.
    """
    if stage2 not in STAGE2:
        raise ValueError(f"stage2 must be one of {STAGE2}, got {stage2!r}")
    if stage2 == "fused" or (stage2 == "auto" and can_fuse(trace, scene)):
        backend, why = fused_backend(grid.device)
        if backend is None:
            if stage2 == "fused":
                raise RuntimeError(f"stage2='fused' is not available here: {why}")
            _warn_once(f"stage2-{grid.device.type}", f"the fused stage 2 is unavailable ({why}); using the "
                                                      "PyTorch stage 2")
        else:
            depth, normal, silhouette, image = shade_trace_fused(grid, cameras, trace, scene, backend)
            return RenderOutput(hit=trace.hit, depth=depth, normal=normal, silhouette=silhouette, image=image,
                                trace=trace)
    b, h, w = trace.hit.shape
    total = b * h * w
    grid = grid._with_shared_gradient()  # every pass below samples it: one gradient buffer for all
    dt, dev = grid.dtype, grid.device
    cams = cameras.to(device=dev, dtype=dt)
    hit_flat = trace.hit.reshape(-1)
    depth = normal = image = silhouette = None

    if scene.needs_hit_points():
        idx = hit_flat.nonzero().squeeze(1)
        cam = idx // (h * w)
        gi = trace.grid_index[cam]
        s = trace.points.reshape(-1, 3)[idx]
        v = trace.directions.reshape(-1, 3)[idx]
        if scene.intersection == "exact":
            from .exact import hit_points_exact

            p, dt_off = hit_points_exact(grid, s, v, gi)
        else:
            p, dt_off = hit_points_conservative(grid, s, v, gi)
        if scene.wants("depth"):
            depth = _scatter(trace.t.reshape(-1)[idx] + dt_off, idx, total, 0.0).reshape(b, h, w)
        if scene.needs_normals():
            n = surface_normals(grid, p, gi, v)
            if scene.wants("normal"):
                normal = _scatter(n, idx, total, 0.0).reshape(b, h, w, 3)
            if scene.wants("shading"):
                rgb = shade_lambert(n, p, cams.eye[cam], scene)
                image = _scatter(rgb, idx, total, scene.background).reshape(b, h, w, scene.channels)

    if scene.wants("silhouette"):
        x = trace.extreme_points.reshape(-1, 3)
        ray_cam = torch.arange(b, device=dev).repeat_interleave(h * w)
        foot = trace.t_extreme.reshape(-1) * cams.pixel_angle[ray_cam]
        foot = torch.clamp(foot, min=min_threshold(grid))
        sil = soft_silhouette(grid, x, trace.grid_index[ray_cam], foot, scene.silhouette_sigma)
        # Rays that never enter the grid's box see nothing (the SDF is undefined outside it): they
        # are the rays the march took no sample on (every march samples a ray that enters).
        entered = trace.steps.reshape(-1) > 0
        silhouette = torch.where(entered, sil, torch.zeros_like(sil)).reshape(b, h, w)

    return RenderOutput(hit=trace.hit, depth=depth, normal=normal, silhouette=silhouette, image=image,
                        trace=trace)
