"""The fused stage 2: renderer/render.py's differentiable stage as one kernel forward and one backward.

``shade_trace_fused`` computes what ``shade_trace`` computes with renderer/shading.py's PyTorch code
(the conservative hit point, normals, Lambert shading, soft silhouettes; only the effects the scene
asks for), from the same TraceResult, in one numba kernel over the rays (CPU or CUDA), and its
backward in another: per ray, the gradients of its outputs with respect to the SDF samples it read,
added into the grid's gradient (renderer/kernels/raymarch.py, "stage 2"). No per-ray tensors,
gathers or scatters are built in PyTorch and no host synchronisation happens on a GPU.

The PyTorch stage 2 stays the specification: tests/renderer/test_stage2.py compares values and
gradients, every effect and light, float32 and float64. The exact intersection
(``Scene(intersection="exact")``) has no fused version; ``render`` uses the PyTorch stage 2 for it.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.autograd.function import once_differentiable

from .cameras import Cameras
from .grid import SDFGrid
from .scene import Scene
from .settings import TraceSettings
from .trace import TraceResult

STAGE2 = ("auto", "reference", "fused")


def fused_backend(device: torch.device) -> tuple[str | None, str]:
    """(the fused stage-2 kernel for ``device``, "") or (None, why there is none)."""
    from . import kernels

    name = "cuda" if device.type == "cuda" else "cpu"
    ok, why = kernels.stage2_available(name)
    return (name, "") if ok else (None, why)


def can_fuse(trace: TraceResult, scene: Scene) -> bool:
    """Whether ``shade_trace(stage2="auto")`` runs the fused stage 2: after a fused march (the
    reference march means the whole reference pipeline) with the conservative hit point."""
    return trace.backend != "reference" and scene.intersection == "conservative"


@dataclass
class _Launch:
    """What the kernels need beside the grid values (on the grid's device unless noted)."""

    backend: str
    params: torch.Tensor
    iparams: torch.Tensor
    sparams: torch.Tensor
    lights: torch.Tensor
    sflags_host: torch.Tensor  # on the CPU (the backward sets its gradient flags in a copy)
    rays: dict
    grids: int
    channels: int
    want: dict  # output name -> whether the scene asks for it


class _FusedStage2(torch.autograd.Function):
    """values (B, Nx, Ny, Nz) -> (depth (R,), normal (R, 3), image (R, C), silhouette (R,)), each
    empty (0 rows) where the scene does not ask for it."""

    @staticmethod
    def forward(ctx, values: torch.Tensor, launch: _Launch):
        from . import kernels

        flat = values.detach().contiguous().reshape(-1)
        r = launch.rays["hit"].shape[0]
        want = launch.want
        dt, dev = values.dtype, values.device
        outputs = {
            "depth": torch.empty(r if want["depth"] else 0, dtype=dt, device=dev),
            "normal": torch.empty(r if want["normal"] else 0, 3, dtype=dt, device=dev),
            "image": torch.empty(r if want["image"] else 0, launch.channels, dtype=dt, device=dev),
            "silhouette": torch.empty(r if want["silhouette"] else 0, dtype=dt, device=dev),
        }
        kernels.shade_forward(launch.backend, flat, launch.params, launch.iparams, launch.sparams,
                              kernels._on_device(launch.sflags_host, dev),
                              launch.lights, launch.rays, outputs)
        ctx.save_for_backward(values, outputs["silhouette"])  # the backward reads the coverage back
        ctx.launch = launch
        ctx.set_materialize_grads(False)
        for name, out in outputs.items():
            if not want[name]:
                ctx.mark_non_differentiable(out)
        return outputs["depth"], outputs["normal"], outputs["image"], outputs["silhouette"]

    @staticmethod
    @once_differentiable
    def backward(ctx, g_depth, g_normal, g_image, g_silhouette):
        from . import kernels

        values, silhouette = ctx.saved_tensors
        launch = ctx.launch
        m = kernels._load_march()
        dt, dev = values.dtype, values.device
        sflags = launch.sflags_host.clone()
        grads = {}
        for name, grad, flag, width in (("depth", g_depth, m.SF_GRAD_DEPTH, None),
                                        ("normal", g_normal, m.SF_GRAD_NORMAL, 3),
                                        ("image", g_image, m.SF_GRAD_IMAGE, launch.channels),
                                        ("silhouette", g_silhouette, m.SF_GRAD_SILHOUETTE, None)):
            if grad is None or grad.numel() == 0:
                shape = (0,) if width is None else (0, width)
                grads[name] = torch.empty(shape, dtype=dt, device=dev)
            else:
                grads[name] = grad.to(dt).contiguous()
                sflags[flag] = 1
        flat = values.detach().contiguous().reshape(-1)
        sflags = kernels._on_device(sflags, dev)
        grad = kernels.shade_backward(launch.backend, flat, launch.params, launch.iparams, launch.sparams, sflags,
                                      launch.lights, launch.rays, grads, silhouette, launch.grids)
        return grad.view(values.shape), None


def shade_trace_fused(grid: SDFGrid, cameras: Cameras, trace: TraceResult, scene: Scene, backend: str):
    """The fused stage 2 (``backend`` "cpu" or "cuda", the grid's device).

    Returns:
        (depth (B, H, W), normal (B, H, W, 3), silhouette (B, H, W), image (B, H, W, C)), each None
        where the scene does not ask for it; differentiable w.r.t. ``grid.values``.
    """
    from . import kernels

    if scene.intersection != "conservative":
        raise ValueError("the fused stage 2 has only the conservative intersection; use stage2='reference' "
                         f"for intersection={scene.intersection!r}")
    b, h, w = trace.hit.shape
    dt, dev = grid.dtype, grid.device
    cams = cameras.to(device=dev, dtype=dt)
    # The march settings do not matter here; _params packs the grid's box and resolution with them.
    params, iparams = kernels._params(grid, TraceSettings())
    sparams, sflags_host, lights = kernels.stage2_params(grid, scene, h * w)
    rays = {
        "hit": trace.hit.reshape(-1).contiguous().view(torch.uint8),
        "t": trace.t.reshape(-1).contiguous(),
        "points": trace.points.reshape(-1, 3).contiguous(),
        "directions": trace.directions.reshape(-1, 3).contiguous(),
        "extreme": trace.extreme_points.reshape(-1, 3).contiguous(),
        "t_extreme": trace.t_extreme.reshape(-1).contiguous(),
        "steps": trace.steps.reshape(-1).contiguous(),
        "cam_grid": trace.grid_index.to(torch.int64).contiguous(),
        "pixel_angle": cams.pixel_angle.contiguous(),
        "eyes": cams.eye.contiguous(),
    }
    want = {"depth": scene.wants("depth"), "normal": scene.wants("normal"), "image": scene.wants("shading"),
            "silhouette": scene.wants("silhouette")}
    launch = _Launch(backend, params, iparams, sparams, lights, sflags_host, rays,
                     grid.batch_size, scene.channels, want)
    depth, normal, image, silhouette = _FusedStage2.apply(grid.values, launch)
    return (depth.view(b, h, w) if scene.wants("depth") else None,
            normal.view(b, h, w, 3) if scene.wants("normal") else None,
            silhouette.view(b, h, w) if scene.wants("silhouette") else None,
            image.view(b, h, w, scene.channels) if scene.wants("shading") else None)
