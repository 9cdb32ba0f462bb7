"""sphere_trace(): the no-gradient stage of the renderer, with a choice of backend."""
from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass

import torch

from .cameras import Cameras
from .grid import SDFGrid, require_finite
from .reference import march_reference
from .settings import TraceSettings

BACKENDS = ("auto", "reference", "cpu", "cuda")


@dataclass(frozen=True)
class TraceResult:
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
        backend: the backend that marched.
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


_warned: set[str] = set()


def _warn_once(key: str, message: str) -> None:
    """A RuntimeWarning and a logged warning (so it reaches the log files of the training and
    reconstruction commands too), once per process."""
    if key not in _warned:
        _warned.add(key)
        warnings.warn(message, RuntimeWarning, stacklevel=3)
        logging.getLogger("renderer").warning(message)


def backend_available(backend: str) -> tuple[bool, str]:
    """Whether ``sphere_trace(..., settings.backend=backend)`` can march here.

    Args:
        backend: one of ``BACKENDS``; "reference" (plain PyTorch) and "auto" (which falls back to
            it) always can, the fused "cpu" and "cuda" kernels need numba (and for "cuda" a GPU).
    Returns:
        (True, "") or (False, the reason in a few words).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend in ("auto", "reference"):
        return True, ""
    from . import kernels

    return kernels.available(backend)


def resolve_backend(backend: str, device: torch.device) -> str:
    """The backend that will march on ``device``: the fused kernel where available, else the reference."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "reference":
        return backend
    from . import kernels

    if backend == "auto":
        want = "cuda" if device.type == "cuda" else "cpu"
        ok, why = kernels.available(want)
        if ok:
            return want
        hint = (" (30-95x slower on a GPU; `make install` on a GPU machine installs numba-cuda through the "
                "project's cuda12/cuda13 extra)") if want == "cuda" else ""
        _warn_once(want, f"the fused {want} kernels are unavailable ({why}); rendering with the PyTorch "
                         f"reference instead{hint}")
        return "reference"
    ok, why = kernels.available(backend)
    if not ok:
        raise RuntimeError(f"backend={backend!r} is not available: {why}")
    if (backend == "cuda") != (device.type == "cuda"):
        raise ValueError(f"backend={backend!r} cannot march tensors on device {device}")
    return backend


def sphere_trace(
    grid: SDFGrid,
    cameras: Cameras,
    settings: TraceSettings = TraceSettings(),
    backend: str = "auto",
) -> TraceResult:
    """Marches one ray per pixel of every camera through its grid, without gradients.

    Args:
        grid: B_g grids; cameras: B_c cameras with B_c a multiple of B_g (see camera_grid_index).
        settings: march settings.
        backend: "auto" (fused kernel for the device, else reference), "reference", "cpu", "cuda".
    Returns:
        TraceResult with (B_c, H, W) maps.
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
    cams = cameras.to(device=grid.device, dtype=grid.dtype)
    origins, directions = cams.rays()
    b, h, w, _ = directions.shape
    n = h * w
    chosen = resolve_backend(backend, grid.device)
    ray_grid = gidx.repeat_interleave(n)
    ray_pix = cams.pixel_angle.repeat_interleave(n)
    o = origins.reshape(-1, 3)
    d = directions.reshape(-1, 3)
    if chosen == "reference":
        out = march_reference(grid, o, d, ray_grid, ray_pix, settings)
    else:
        from . import kernels

        out = kernels.march(chosen, grid, o, d, ray_grid, ray_pix, settings, check_indices=False)
    t = out["t"].reshape(b, h, w)
    return TraceResult(
        hit=out["hit"].reshape(b, h, w),
        t=t,
        points=(origins + t[..., None] * directions).detach(),
        extreme_points=out["extreme"].reshape(b, h, w, 3),
        t_extreme=out["t_extreme"].reshape(b, h, w),
        steps=out["steps"].reshape(b, h, w),
        origins=origins,
        directions=directions,
        grid_index=gidx,
        backend=chosen,
    )
