"""Stage 2, the op: ``shade_trace`` turns a MarchResult into the differentiable passes the scene
asks for (hit point, depth, normals, Lambert shading, soft silhouettes), with the implementation
renderer/backends.py chooses: the plain-PyTorch ``shade_reference`` (renderer/shading.py, the
specification) or the fused kernels (``shade_fused``, renderer/fused.py), both reading the same
ShadingRays and returning the same Shading; the exact intersection has only the PyTorch version,
and the visibility gradient's edge term (``edge_gradient``) too, which the fused path adds to its
image.
"""
from __future__ import annotations

from dataclasses import replace

import torch

from .backends import resolve_stage2
from .cameras import Cameras
from .fused import shade_fused
from .grid import SDFGrid
from .shared_gradient import with_shared_gradient
from .records import MarchResult, RenderOutput, ShadingRays
from .scene import Scene
from .shading import edge_gradient, shade_reference


def shading_rays(trace: MarchResult, cameras: Cameras, dtype: torch.dtype, device: torch.device) -> ShadingRays:
    """The rays of ``trace`` flattened for stage 2 (contiguous; the cameras in ``dtype`` on ``device``,
    the grid's): ray r = (b * H + i) * W + j of the (B, H, W) maps belongs to camera b.

    Where the cameras carry a gradient (``Cameras.requires_grad``), the directions, eyes, traced
    points and silhouette points carry it too: their values are the march's, and each point moves
    with its ray at its fixed distance along it (``eye + t * direction``). For the silhouette and
    grazing points, minima of the SDF along their rays, that is their SDF's exact derivative."""
    cams = cameras.to(device=device, dtype=dtype)
    b, h, w = trace.hit.shape
    points = trace.points.reshape(-1, 3).contiguous()
    directions = trace.directions.reshape(-1, 3).contiguous()
    extreme = trace.extreme_points.reshape(-1, 3).contiguous()
    if cams.requires_grad:
        moved_dir = cams.rays()[1].reshape(-1, 3)
        d_dir = moved_dir - moved_dir.detach()  # zero in value, the directions' gradient
        eye = cams.eye.repeat_interleave(h * w, dim=0)
        d_eye = eye - eye.detach()
        finite = lambda t: torch.nan_to_num(t.reshape(-1, 1), posinf=0.0, neginf=0.0)  # noqa: E731
        directions = directions + d_dir
        points = points + d_eye + finite(trace.t) * d_dir
        extreme = extreme + d_eye + finite(trace.t_extreme) * d_dir
    return ShadingRays(
        hit=trace.hit.reshape(-1).contiguous(),
        t=trace.t.reshape(-1).contiguous(),
        points=points,
        directions=directions,
        extreme=extreme,
        t_extreme=trace.t_extreme.reshape(-1).contiguous(),
        steps=trace.steps.reshape(-1).contiguous(),
        camera_grid=trace.grid_index.to(torch.int64).contiguous(),
        pixel_angle=cams.pixel_angle.contiguous(),
        eyes=cams.eye.contiguous(),
        pixels=h * w,
        graze_t=None if trace.graze_t is None else trace.graze_t.reshape(-1).contiguous(),
        graze_gap=None if trace.graze_gap is None else trace.graze_gap.reshape(-1).contiguous(),
    )


def shade_trace(grid: SDFGrid, cameras: Cameras, trace: MarchResult, scene: Scene,
                stage2: str = "auto") -> RenderOutput:
    """The differentiable stage: the passes ``scene.effects`` need, from a fixed MarchResult.

    Args:
        grid: the B_g grids ``trace`` was marched through; cameras: its B_c cameras.
        trace: ``sphere_trace(grid, cameras, ...)``, with ``grazing=True`` for the visibility gradient.
        scene: effects, lights, material, background, intersection, gradient.
        stage2: "reference", the PyTorch stage 2 (renderer/shading.py); "fused", one kernel forward
            and one backward (renderer/fused.py; the grid's device must have the fused kernels, and
            the intersection must be the conservative one), with the visibility gradient's edge
            term from PyTorch added to its image; "auto", fused after a fused march with the
            conservative intersection, else the reference.
    Returns:
        RenderOutput with (B_c, H, W) maps, differentiable w.r.t. ``grid.values``, and w.r.t. the
        cameras where they carry a gradient (``Cameras.moved``; the PyTorch stage 2 then runs).
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a Scene, got {type(scene).__name__}")
    if scene.needs_grazing() and trace.graze_gap is None:
        raise ValueError("trace has no grazing points, which gradient='visibility' needs: march it with "
                         "sphere_trace(..., grazing=True)")
    if cameras.requires_grad and stage2 == "fused":
        raise ValueError("stage2='fused' differentiates the grid only; cameras with a gradient need "
                         "stage2='reference' or 'auto'")
    # The fused kernels differentiate the grid only: cameras with a gradient take the PyTorch stage 2.
    backend = None if cameras.requires_grad else resolve_stage2(stage2, trace.backend, scene, grid.device)
    rays = shading_rays(trace, cameras, grid.dtype, grid.device)
    if backend is None:
        # The plain-autograd specification, its samplings' gradients added into one buffer (the
        # same values and gradients, faster on large grid batches: renderer/shared_gradient.py).
        out = shade_reference(with_shared_gradient(grid), rays, scene)
    elif scene.needs_grazing():
        # The edge term has no kernel yet: the kernels make the paper's passes, the PyTorch term
        # (a few rays beside the edges) adds the edges' motion to the image's gradient.
        out = shade_fused(backend, grid, rays, replace(scene, gradient="paper"))
        out = replace(out, image=out.image + edge_gradient(grid, rays, out.image.detach(), scene))
    else:
        out = shade_fused(backend, grid, rays, scene)
    b, h, w = trace.hit.shape
    return RenderOutput(
        hit=trace.hit,
        depth=None if out.depth is None else out.depth.view(b, h, w),
        normal=None if out.normal is None else out.normal.view(b, h, w, 3),
        silhouette=None if out.silhouette is None else out.silhouette.view(b, h, w),
        image=None if out.image is None else out.image.view(b, h, w, scene.channels),
        trace=trace,
    )
