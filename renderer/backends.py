"""Which backend runs each stage, and whether the fused ones work here: the probes of numba and of
the GPU (a one-ray march and a one-ray fused stage 2 on the GPU, so a numba-cuda that cannot build
the kernels is found here, where ``backend="auto"`` can still fall back, rather than in a render)
and the choice the op modules make with them (``resolve_backend`` for the march,
``resolve_stage2`` for stage 2), with the one warning a fallback gives per process. Above
renderer/fused.py and renderer/kernels/, below the op modules (renderer/trace.py, renderer/stage2.py).
"""
from __future__ import annotations

import functools
import logging
import warnings

import torch

from . import kernels
from .cameras import Cameras
from .fused import FUSED_BACKENDS, march_fused, shade_fused
from .grid import SDFGrid
from .records import ShadingRays
from .scene import Scene
from .settings import TraceSettings

BACKENDS = ("auto", "reference", "cpu", "cuda")
STAGE2 = ("auto", "reference", "fused")

_warned: set[str] = set()


def warn_once(key: str, message: str) -> None:
    """A RuntimeWarning and a logged warning (so it reaches the log files of the training and
    reconstruction commands too), once per process and ``key``."""
    if key not in _warned:
        _warned.add(key)
        warnings.warn(message, RuntimeWarning, stacklevel=3)
        logging.getLogger("renderer").warning(message)


@functools.lru_cache(maxsize=None)
def march_available(backend: str) -> tuple[bool, str]:
    """(True, "") if the fused march ``backend`` ("cpu" or "cuda") can run here, else (False, why)."""
    if backend not in FUSED_BACKENDS:
        raise ValueError(f"backend must be one of {FUSED_BACKENDS}, got {backend!r}")
    try:
        kernels.load()
    except Exception as exc:  # numba missing or broken: the reference march still works
        return False, f"numba is unusable ({type(exc).__name__}: {exc})"
    if backend == "cpu":
        return True, ""
    if not torch.cuda.is_available():
        return False, "torch sees no CUDA GPU"
    try:
        from numba import cuda  # optional: imports only where numba-cuda is installed
    except Exception as exc:
        return False, f"numba's CUDA target does not import ({type(exc).__name__}: {exc})"
    try:
        if not cuda.is_available():
            return False, "numba's CUDA target finds no usable GPU or driver"
    except Exception as exc:
        return False, f"numba's CUDA target failed ({type(exc).__name__}: {exc})"
    try:
        _march_one_ray_on_gpu()
    except Exception as exc:  # e.g. a numba-cuda release that does not build against this numpy
        return False, f"numba's CUDA target cannot build or run the march ({type(exc).__name__}: {exc})"
    return True, ""


@functools.lru_cache(maxsize=None)
def stage2_available(backend: str) -> tuple[bool, str]:
    """(True, "") if the fused stage 2 can run on ``backend`` ("cpu" or "cuda"), else (False, why).

    Needs the march's kernels; on CUDA the stage-2 kernels (their atomic adds go through a
    CUDA-target overload) are also built and run once on a one-ray render, so a numba-cuda that
    cannot build them leaves ``render`` on the PyTorch stage 2 instead of failing in a render.
    """
    ok, why = march_available(backend)
    if not ok or backend == "cpu":
        return ok, why
    try:
        _shade_one_ray_on_gpu()
    except Exception as exc:
        return False, f"the fused stage 2 cannot build or run on the GPU ({type(exc).__name__}: {exc})"
    return True, ""


def backend_available(backend: str) -> tuple[bool, str]:
    """Whether ``sphere_trace(..., backend=backend)`` can march here.

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
    return march_available(backend)


def resolve_backend(backend: str, device: torch.device) -> str:
    """The backend that will march on ``device``: the fused kernel where available, else the
    reference (with one warning per process where "auto" falls back)."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "reference":
        return backend
    if backend == "auto":
        want = "cuda" if device.type == "cuda" else "cpu"
        ok, why = march_available(want)
        if ok:
            return want
        hint = (" (30-95x slower on a GPU; `make install` on a GPU machine installs numba-cuda through the "
                "project's cuda12/cuda13 extra)") if want == "cuda" else ""
        warn_once(want, f"the fused {want} kernels are unavailable ({why}); rendering with the PyTorch "
                        f"reference instead{hint}")
        return "reference"
    ok, why = march_available(backend)
    if not ok:
        raise RuntimeError(f"backend={backend!r} is not available: {why}")
    if (backend == "cuda") != (device.type == "cuda"):
        raise ValueError(f"backend={backend!r} cannot march tensors on device {device}")
    return backend


def resolve_stage2(stage2: str, march_backend: str, scene: Scene, device: torch.device) -> str | None:
    """The fused stage-2 backend ("cpu" or "cuda") that will shade on ``device``, or None for the
    PyTorch stage 2.

    Args:
        stage2: "reference"; "fused" (raises where it cannot run); "auto": fused after a fused
            march (the reference march means the whole reference pipeline) with the conservative
            intersection, where the kernels work (else one warning per process).
        march_backend: the backend that marched (``MarchResult.backend``).
    """
    if stage2 not in STAGE2:
        raise ValueError(f"stage2 must be one of {STAGE2}, got {stage2!r}")
    if stage2 == "reference" or (stage2 == "auto" and (march_backend == "reference"
                                                       or scene.intersection != "conservative")):
        return None
    backend = "cuda" if device.type == "cuda" else "cpu"
    ok, why = stage2_available(backend)
    if ok:
        return backend
    if stage2 == "fused":
        raise RuntimeError(f"stage2='fused' is not available here: {why}")
    warn_once(f"stage2-{device.type}", f"the fused stage 2 is unavailable ({why}); using the PyTorch stage 2")
    return None


def _sphere_grid_on_gpu() -> SDFGrid:
    """An 8^3 grid of a sphere of radius 0.5 over [-1, 1]^3 (float32) on the current GPU, for the
    one-ray probes."""
    dev = torch.device("cuda", torch.cuda.current_device())
    axis = torch.linspace(-1.0, 1.0, 8, device=dev)
    x, y, z = torch.meshgrid(axis, axis, axis, indexing="ij")
    return SDFGrid(((x * x + y * y + z * z).sqrt() - 0.5)[None])


def _march_one_ray_on_gpu() -> None:
    """Marches one ray into the probe's sphere grid on the current GPU: the kernel is compiled (or
    loaded from the disk cache) and run. The ray from z = 3 down the axis must hit near t = 2.5."""
    grid = _sphere_grid_on_gpu()
    dev = grid.device
    out = march_fused("cuda", grid, torch.tensor([[0.0, 0.0, 3.0]], device=dev),
                      torch.tensor([[0.0, 0.0, -1.0]], device=dev), torch.zeros(1, dtype=torch.int64, device=dev),
                      torch.full((1,), 1e-3, device=dev), TraceSettings(), check_indices=False)
    hit, t = bool(out.hit[0]), float(out.t[0])
    if not hit or abs(t - 2.5) > 0.1:
        raise RuntimeError(f"a ray into a sphere grid came back wrong (hit={hit}, t={t:.4f}, expected t~2.5)")


def _shade_one_ray_on_gpu() -> None:
    """Marches and shades one ray into the probe's sphere grid on the GPU with the fused kernels,
    forward and backward: the depth must be near 2.5 and the gradient finite and non-zero."""
    grid = _sphere_grid_on_gpu()
    values = grid.values.requires_grad_(True)
    cams = Cameras.look_at([[0.0, 0.0, 3.0]], fov_deg=1.0, image_size=1, device=grid.device)
    origins, directions = cams.rays()
    o, d = origins.reshape(-1, 3), directions.reshape(-1, 3)
    marched = march_fused("cuda", grid, o, d, torch.zeros(1, dtype=torch.int64, device=grid.device),
                          cams.pixel_angle, TraceSettings(), check_indices=False)
    rays = ShadingRays(hit=marched.hit, t=marched.t, points=(o + marched.t[:, None] * d).contiguous(),
                       directions=d.contiguous(), extreme=marched.extreme, t_extreme=marched.t_extreme,
                       steps=marched.steps, camera_grid=torch.zeros(1, dtype=torch.int64, device=grid.device),
                       pixel_angle=cams.pixel_angle.contiguous(), eyes=cams.eye.contiguous(), pixels=1)
    out = shade_fused("cuda", grid, rays, Scene())
    (out.depth.sum() + out.silhouette.sum() + out.image.sum()).backward()
    depth, g = float(out.depth.detach()[0]), values.grad
    if abs(depth - 2.5) > 0.1 or not bool(torch.isfinite(g).all()) or float(g.abs().sum()) == 0.0:
        raise RuntimeError(f"a one-ray render came back wrong (depth {depth:.4f}, expected ~2.5)")
