"""The records the renderer's stages hand on, as frozen dataclasses of tensors (pytorch3d's
``RayBundle`` and ``Fragments`` are the model): ``MarchedRays``, what a march backend returns per
ray; ``MarchResult``, stage 1's result per pixel; ``ShadingRays``, the flat rays stage 2 reads;
``Shading``, stage 2's outputs; ``RenderOutput``, a render. Only torch is imported here, so every
stage and the kernels' launchers can share them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch


@dataclass(frozen=True)
class MarchedRays:
    """What a march backend returns for R rays (detached, the grid's dtype and device).

    Attributes:
        t: (R,) distance from the origin to the traced point (0 if the ray misses the box).
        hit: (R,) bool.
        extreme: (R, 3) world, the closest approach of a miss or the deepest point behind a hit.
        t_extreme: (R,) the distance of ``extreme`` along the ray.
        steps: (R,) int32 SDF samples taken by the march.
        graze_t, graze_gap: (R,) where the march was asked for grazing points (else None): the
            distance along the ray of its grazing point, the sampled local minimum of the SDF before
            the hit (or along the whole ray for a miss) with the smallest ``graze_gap``, the SDF there
            minus the hit threshold, in pixel footprints (>= 0: the ray passed the surface there);
            ``graze_gap`` is +inf where the ray has none (``graze_t`` is then 0).
    """

    t: torch.Tensor
    hit: torch.Tensor
    extreme: torch.Tensor
    t_extreme: torch.Tensor
    steps: torch.Tensor
    graze_t: Optional[torch.Tensor] = None
    graze_gap: Optional[torch.Tensor] = None


@dataclass(frozen=True)
class MarchResult:
    """Where each ray meets the surface (all tensors detached, world frame, the grid's dtype).

    Attributes:
        hit: (B, H, W) bool.
        t: (B, H, W) distance from the eye to the traced point along the ray (0 if the ray misses
            the box).
        points: (B, H, W, 3) traced points ``origin + t * direction`` (the paper's ``s``).
        extreme_points: (B, H, W, 3) for misses the closest approach (smallest SDF along the ray),
            for hits the deepest point found behind the surface: the soft silhouettes read the SDF
            there.
        t_extreme: (B, H, W) distance of ``extreme_points`` along the ray.
        steps: (B, H, W) int32 SDF samples taken by the march.
        origins, directions: (B, H, W, 3) the rays (unit directions).
        grid_index: (B,) long, the grid each camera renders.
        backend: the backend that marched ("reference", "cpu" or "cuda").
        graze_t, graze_gap: (B, H, W) the grazing points (see MarchedRays), None unless asked for.
    """

    hit: torch.Tensor
    t: torch.Tensor
    points: torch.Tensor
    extreme_points: torch.Tensor
    t_extreme: torch.Tensor
    steps: torch.Tensor
    origins: torch.Tensor
    directions: torch.Tensor
    grid_index: torch.Tensor
    backend: str
    graze_t: Optional[torch.Tensor] = None
    graze_gap: Optional[torch.Tensor] = None


@dataclass(frozen=True)
class ShadingRays:
    """The rays stage 2 reads: a MarchResult flattened over its R = B * H * W pixels (ray r belongs
    to camera ``r // pixels``), with what stage 2 needs of the cameras. Contiguous tensors on the
    grid's device, in its dtype (the integer ones excepted); world frame.

    Attributes:
        hit: (R,) bool.
        t: (R,) distance to the traced point.
        points: (R, 3) traced points (the paper's ``s``); directions: (R, 3) unit ray directions.
        extreme: (R, 3) the silhouette points; t_extreme: (R,) their distance along the ray.
        steps: (R,) int32 samples the march took (0: the ray never entered the grid's box).
        camera_grid: (B,) int64, the grid each camera renders.
        pixel_angle: (B,) pixel footprint per unit distance, per camera.
        eyes: (B, 3) camera positions.
        pixels: H * W, the rays per camera.
        graze_t, graze_gap: (R,) the grazing points (see MarchedRays), None unless marched for.
    """

    hit: torch.Tensor
    t: torch.Tensor
    points: torch.Tensor
    directions: torch.Tensor
    extreme: torch.Tensor
    t_extreme: torch.Tensor
    steps: torch.Tensor
    camera_grid: torch.Tensor
    pixel_angle: torch.Tensor
    eyes: torch.Tensor
    pixels: int
    graze_t: Optional[torch.Tensor] = None
    graze_gap: Optional[torch.Tensor] = None

    @property
    def count(self) -> int:
        """R, the number of rays."""
        return self.hit.shape[0]

    def camera(self) -> torch.Tensor:
        """(R,) long, the camera of each ray."""
        return torch.arange(self.camera_grid.shape[0], device=self.hit.device).repeat_interleave(self.pixels)


@dataclass(frozen=True)
class Shading:
    """Stage 2's outputs for R rays (flat), each None where the scene does not ask for it;
    differentiable w.r.t. the grid values.

    Attributes:
        depth: (R,) distance from the eye to the hit point; 0 where no hit.
        normal: (R, 3) unit world normals; 0 where no hit.
        silhouette: (R,) soft coverage in [0, 1].
        image: (R, C) shaded colour; the scene's background where no hit.
    """

    depth: Optional[torch.Tensor]
    normal: Optional[torch.Tensor]
    silhouette: Optional[torch.Tensor]
    image: Optional[torch.Tensor]


@dataclass(frozen=True)
class RenderOutput:
    """A render of B_c cameras (an effect the scene did not ask for is None).

    Attributes:
        hit: (B, H, W) bool, rays that met the surface.
        depth: (B, H, W) distance from the eye to the hit point along the ray; 0 where no hit.
        normal: (B, H, W, 3) unit world normals at the hit points; 0 where no hit.
        silhouette: (B, H, W) soft coverage in [0, 1].
        image: (B, H, W, C) shaded colour; the scene's background where no hit.
        trace: the MarchResult the render was made from.
    """

    hit: torch.Tensor
    depth: Optional[torch.Tensor]
    normal: Optional[torch.Tensor]
    silhouette: Optional[torch.Tensor]
    image: Optional[torch.Tensor]
    trace: MarchResult
