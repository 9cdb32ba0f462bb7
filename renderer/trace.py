"""Stage 1, the op: ``sphere_trace`` marches one ray per pixel without gradients, with the
backend renderer/backends.py chooses: the plain-PyTorch ``march_reference`` (renderer/reference.py,
the specification) or the fused kernel (``march_fused``, renderer/fused.py), and returns a
MarchResult, what stage 2 (renderer/stage2.py) reads.
"""
from __future__ import annotations

import torch

from .backends import resolve_backend
from .cameras import Cameras
from .fused import march_fused
from .grid import SDFGrid, require_finite
from .records import MarchResult
from .reference import march_reference
from .settings import TraceSettings


def camera_grid_index(grid: SDFGrid, cameras: Cameras) -> torch.Tensor:
    """(B_cameras,) the grid each camera renders: camera c renders grid ``c // (B_cameras / B_grids)``.

    So one grid can be seen by many cameras, one camera can see each grid, or each of G grids by V
    consecutive cameras (B_cameras = G * V), all without copying the grid.
    """
    bg, bc = grid.batch_size, cameras.batch_size
    if bc % bg != 0:
        raise ValueError(
            f"cameras batch ({bc}) must be a multiple of the grid batch ({bg}): each grid is seen by "
            f"the same number of consecutive cameras"
        )
    return torch.arange(bc, device=grid.device) // (bc // bg)


def sphere_trace(
    grid: SDFGrid,
    cameras: Cameras,
    settings: TraceSettings = TraceSettings(),
    backend: str = "auto",
    grazing: bool = False,
) -> MarchResult:
    """Marches one ray per pixel of every camera through its grid, without gradients.

    Args:
        grid: B_g grids; cameras: B_c cameras with B_c a multiple of B_g (see camera_grid_index).
        settings: march settings.
        backend: "auto" (fused kernel for the device, else reference), "reference", "cpu", "cuda".
        grazing: also find each ray's grazing point (``Scene(gradient="visibility")`` needs them).
    Returns:
        MarchResult with (B_c, H, W) maps.
    """
    if not isinstance(grid, SDFGrid):
        raise TypeError(f"grid must be an SDFGrid, got {type(grid).__name__}")
    if not isinstance(cameras, Cameras):
        raise TypeError(f"cameras must be a Cameras, got {type(cameras).__name__}")
    # SDFGrid checks its values when built but keeps the tensor without a copy: an in-place change
    # (an optimiser step, a caller's edit) since then would march and shade NaN silently.
    if not grid.unchanged_since_checked():
        require_finite(grid.values, "grid.values")
    gidx = camera_grid_index(grid, cameras)
    cams = cameras.detach().to(device=grid.device, dtype=grid.dtype)  # the march has no gradient
    origins, directions = cams.rays()
    b, h, w, _ = directions.shape
    n = h * w
    chosen = resolve_backend(backend, grid.device)
    ray_grid = gidx.repeat_interleave(n)
    ray_pix = cams.pixel_angle.repeat_interleave(n)
    o = origins.reshape(-1, 3)
    d = directions.reshape(-1, 3)
    if chosen == "reference":
        out = march_reference(grid, o, d, ray_grid, ray_pix, settings, grazing)
    else:
        out = march_fused(chosen, grid, o, d, ray_grid, ray_pix, settings, check_indices=False, grazing=grazing)
    t = out.t.reshape(b, h, w)
    return MarchResult(
        hit=out.hit.reshape(b, h, w),
        t=t,
        points=(origins + t[..., None] * directions).detach(),
        extreme_points=out.extreme.reshape(b, h, w, 3),
        t_extreme=out.t_extreme.reshape(b, h, w),
        steps=out.steps.reshape(b, h, w),
        origins=origins,
        directions=directions,
        grid_index=gidx,
        backend=chosen,
        graze_t=None if out.graze_t is None else out.graze_t.reshape(b, h, w),
        graze_gap=None if out.graze_gap is None else out.graze_gap.reshape(b, h, w),
    )
