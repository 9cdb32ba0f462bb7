"""The fused paths of both stages: ``march_fused`` (stage 1, one kernel over the rays) and
``shade_fused`` (stage 2 as one kernel forward and one backward, an autograd Function), each the
counterpart of a plain-PyTorch specification it is tested against (``march_reference`` in
renderer/reference.py; ``shade_reference`` in renderer/shading.py). This module checks the inputs
and packs the grid, the march settings and the scene into the small parameter arrays whose
layouts renderer/kernels/raymarch.py defines; renderer/kernels launches. Which backend runs, and
whether it can, is renderer/backends.py's business: nothing here falls back.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.autograd.function import once_differentiable

from . import kernels
from .grid import SDFGrid
from .records import MarchedRays, Shading, ShadingRays
from .reference import TINY_DIRECTION, min_threshold
from .scene import PointLight, Scene
from .settings import TraceSettings

FUSED_BACKENDS = kernels.FUSED_BACKENDS


def march_params(grid: SDFGrid, settings: TraceSettings, grazing: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """The grid and the march settings packed for the kernels: ``params`` (grid dtype) and
    ``iparams`` (int64), made on the host from the grid's host box and kept on its device;
    ``grazing``: whether the march finds grazing points."""
    m = kernels.load()
    dt = grid.dtype
    lo, hi = grid.host_box()
    res = torch.tensor(grid.resolution, dtype=dt)
    floor = min_threshold(grid)
    fixed = settings.threshold is not None
    consts = torch.tensor(
        [0.0, 1.0, TINY_DIRECTION, floor, settings.threshold_scale,
         max(float(settings.threshold), floor) if fixed else 0.0, -settings.inner_depth, float("inf")], dtype=dt)
    # The same tensor expressions as the reference, so the kernels see bit-identical constants.
    params = torch.cat([lo, hi, grid.host_voxel_size(), (lo + hi) / 2, res - 1, res - 2, consts]).contiguous()
    iparams = torch.tensor([*grid.resolution, settings.max_steps, settings.inner_steps, int(fixed), int(grazing)],
                           dtype=torch.int64)
    if params.numel() != m.N_PARAMS or iparams.numel() != m.N_IPARAMS:
        raise RuntimeError("renderer/fused.py: the parameter layout and renderer/kernels/raymarch.py disagree")
    return kernels.on_device(params, grid.device), kernels.on_device(iparams, grid.device)


def scene_params(grid: SDFGrid, scene: Scene, pixels: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The scene packed for the stage-2 kernels: ``sparams`` (grid dtype) and ``lights`` (L, 6) on
    the grid's device, ``sflags`` (int64; the gradient flags left 0) on the CPU."""
    m = kernels.load()
    dt = grid.dtype
    info = torch.finfo(dt)
    channels = scene.channels
    background = scene.background
    background = [float(background)] * channels if isinstance(background, (int, float)) else list(background)
    if len(background) == 1:
        background = background * channels
    camera_light = scene.camera_light
    vox = grid.host_voxel_size()
    inv_span = torch.cat([1 / vox, 1 / (2 * vox)])  # as SDFGrid.sample_gradient forms them
    sparams = torch.cat([torch.tensor([scene.ambient, scene.silhouette_sigma, info.eps, info.tiny,
                                       0.0 if camera_light is None else camera_light], dtype=dt),
                         inv_span, torch.tensor([*scene.albedo, *background], dtype=dt)])
    sflags = torch.zeros(m.N_SFLAGS, dtype=torch.int64)
    for flag, on in ((m.SF_DEPTH, scene.wants("depth")), (m.SF_NORMAL, scene.wants("normal")),
                     (m.SF_SHADING, scene.wants("shading")), (m.SF_SILHOUETTE, scene.wants("silhouette")),
                     (m.SF_CAM_LIGHT, camera_light is not None), (m.SF_CAM_FALLOFF, scene.camera_light_falloff)):
        sflags[flag] = int(bool(on))
    sflags[m.SF_PIXELS] = pixels
    sflags[m.SF_CHANNELS] = channels
    rows = []
    for light in scene.lights:
        if isinstance(light, PointLight):
            rows.append(torch.tensor([float(m.LIGHT_POINT), *light.position, light.intensity, float(light.falloff)],
                                     dtype=dt))
        else:  # normalised in the grid's dtype, as shade_lambert does
            d = torch.tensor(light.direction, dtype=dt)
            d = d / d.norm()
            rows.append(torch.cat([torch.zeros(1, dtype=dt), d, torch.tensor([light.intensity, 0.0], dtype=dt)]))
    lights = torch.stack(rows) if rows else torch.zeros(0, 6, dtype=dt)
    return kernels.on_device(sparams, grid.device), sflags, kernels.on_device(lights, grid.device)


def _check_march_inputs(grid, origins, directions, grid_index, pixel_angle, settings, check_indices: bool) -> None:
    if not isinstance(grid, SDFGrid):
        raise TypeError(f"grid must be an SDFGrid, got {type(grid).__name__}")
    if not isinstance(settings, TraceSettings):
        raise TypeError(f"settings must be a TraceSettings, got {type(settings).__name__}")
    for name, x in (("origins", origins), ("directions", directions), ("grid_index", grid_index),
                    ("pixel_angle", pixel_angle)):
        if not isinstance(x, torch.Tensor):
            raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
        if x.device != grid.device:
            raise ValueError(f"{name} is on {x.device} but the grid is on {grid.device}")
    if origins.ndim != 2 or origins.shape[1] != 3:
        raise ValueError(f"origins must have shape (R, 3), got {tuple(origins.shape)}")
    r = origins.shape[0]
    if directions.shape != (r, 3):
        raise ValueError(f"directions must have shape ({r}, 3) like origins, got {tuple(directions.shape)}")
    if grid_index.shape != (r,) or grid_index.dtype.is_floating_point or grid_index.dtype == torch.bool:
        raise ValueError(f"grid_index must be an integer tensor of shape ({r},), got "
                         f"{grid_index.dtype} {tuple(grid_index.shape)}")
    if pixel_angle.shape != (r,):
        raise ValueError(f"pixel_angle must have shape ({r},), got {tuple(pixel_angle.shape)}")
    if check_indices and r and (int(grid_index.min()) < 0 or int(grid_index.max()) >= grid.batch_size):
        raise ValueError(f"grid_index must lie in [0, {grid.batch_size}) (the grid batch)")


@torch.no_grad()
def march_fused(
    backend: str,
    grid: SDFGrid,
    origins: torch.Tensor,
    directions: torch.Tensor,
    grid_index: torch.Tensor,
    pixel_angle: torch.Tensor,
    settings: TraceSettings,
    check_indices: bool = True,
    grazing: bool = False,
) -> MarchedRays:
    """Sphere-traces R rays with the fused kernel: the same contract as ``march_reference``.

    Args:
        backend: "cpu" or "cuda"; the tensors must be on that device (whether the backend works
            here is renderer.backends.march_available's question).
        grid: B grids, float32 or float64 (the march runs in that dtype).
        origins, directions: (R, 3) world, unit directions.
        grid_index: (R,) integer, the grid each ray reads.
        pixel_angle: (R,) pixel footprint per unit distance.
        settings: the march settings.
        check_indices: whether to check that ``grid_index`` lies in the grid batch (a min/max that
            waits for the GPU; ``sphere_trace`` makes the indices itself and skips it).
        grazing: whether to find each ray's grazing point, as ``march_reference`` does.
    Returns:
        MarchedRays on the grid's device, detached.
    """
    if backend not in FUSED_BACKENDS:
        raise ValueError(f"backend must be one of {FUSED_BACKENDS}, got {backend!r}")
    if (backend == "cuda") != (grid.device.type == "cuda"):
        raise ValueError(f"backend={backend!r} cannot march a grid on device {grid.device}")
    _check_march_inputs(grid, origins, directions, grid_index, pixel_angle, settings, check_indices)
    dt = grid.dtype
    params, iparams = march_params(grid, settings, grazing)
    return kernels.march(backend, grid.values.detach().contiguous().reshape(-1), params, iparams,
                         origins.detach().to(dt).contiguous(), directions.detach().to(dt).contiguous(),
                         grid_index.to(torch.int64).contiguous(), pixel_angle.detach().to(dt).contiguous(), grazing)


@dataclass(frozen=True)
class _Launch:
    """What the stage-2 kernels need beside the grid values (on the grid's device unless noted)."""

    backend: str
    params: torch.Tensor
    iparams: torch.Tensor
    sparams: torch.Tensor
    lights: torch.Tensor
    sflags_host: torch.Tensor  # on the CPU (the backward sets its gradient flags in a copy)
    rays: ShadingRays
    grids: int
    channels: int
    wants: tuple[bool, bool, bool, bool]  # depth, normal, image, silhouette


class _FusedStage2(torch.autograd.Function):
    """values (B, Nx, Ny, Nz) -> (depth (R,), normal (R, 3), image (R, C), silhouette (R,)), each
    empty (0 rows) where the scene does not ask for it."""

    @staticmethod
    def forward(ctx, values: torch.Tensor, launch: _Launch):
        flat = values.detach().contiguous().reshape(-1)
        r = launch.rays.count
        want_depth, want_normal, want_image, want_silhouette = launch.wants
        dt, dev = values.dtype, values.device
        depth = torch.empty(r if want_depth else 0, dtype=dt, device=dev)
        normal = torch.empty(r if want_normal else 0, 3, dtype=dt, device=dev)
        image = torch.empty(r if want_image else 0, launch.channels, dtype=dt, device=dev)
        silhouette = torch.empty(r if want_silhouette else 0, dtype=dt, device=dev)
        kernels.shade_forward(launch.backend, flat, launch.params, launch.iparams, launch.sparams,
                              kernels.on_device(launch.sflags_host, dev), launch.lights, launch.rays,
                              depth, normal, image, silhouette)
        ctx.save_for_backward(values, silhouette)  # the backward reads the coverage back
        ctx.launch = launch
        ctx.set_materialize_grads(False)
        outputs = (depth, normal, image, silhouette)
        for out, wanted in zip(outputs, launch.wants):
            if not wanted:
                ctx.mark_non_differentiable(out)
        return outputs

    @staticmethod
    @once_differentiable
    def backward(ctx, g_depth, g_normal, g_image, g_silhouette):
        values, silhouette = ctx.saved_tensors
        launch = ctx.launch
        m = kernels.load()
        dt, dev = values.dtype, values.device
        sflags = launch.sflags_host.clone()
        grads = []
        for grad, flag, width in ((g_depth, m.SF_GRAD_DEPTH, None), (g_normal, m.SF_GRAD_NORMAL, 3),
                                  (g_image, m.SF_GRAD_IMAGE, launch.channels),
                                  (g_silhouette, m.SF_GRAD_SILHOUETTE, None)):
            if grad is None or grad.numel() == 0:
                grads.append(torch.empty((0,) if width is None else (0, width), dtype=dt, device=dev))
            else:
                grads.append(grad.to(dt).contiguous())
                sflags[flag] = 1
        flat = values.detach().contiguous().reshape(-1)
        grad = kernels.shade_backward(launch.backend, flat, launch.params, launch.iparams, launch.sparams,
                                      kernels.on_device(sflags, dev), launch.lights, launch.rays, *grads,
                                      silhouette, launch.grids)
        return grad.view(values.shape), None


def shade_fused(backend: str, grid: SDFGrid, rays: ShadingRays, scene: Scene) -> Shading:
    """Stage 2 fused (``backend`` "cpu" or "cuda", the grid's device): what ``shade_reference``
    computes, with the conservative hit point and the paper's gradient only.

    Returns:
        Shading of the R rays, differentiable w.r.t. ``grid.values``.
    """
    if scene.intersection != "conservative":
        raise ValueError("the fused stage 2 has only the conservative intersection; use stage2='reference' "
                         f"for intersection={scene.intersection!r}")
    if scene.needs_grazing():
        raise ValueError("the fused stage 2 has only the paper's gradient (renderer/stage2.py adds the "
                         f"visibility gradient's edge term); got gradient={scene.gradient!r}")
    # The march settings do not matter here; march_params packs the grid's box and resolution with them.
    params, iparams = march_params(grid, TraceSettings())
    sparams, sflags_host, lights = scene_params(grid, scene, rays.pixels)
    wants = (scene.wants("depth"), scene.wants("normal"), scene.wants("shading"), scene.wants("silhouette"))
    launch = _Launch(backend, params, iparams, sparams, lights, sflags_host, rays, grid.batch_size, scene.channels,
                     wants)
    depth, normal, image, silhouette = _FusedStage2.apply(grid.values, launch)
    return Shading(depth=depth if wants[0] else None, normal=normal if wants[1] else None,
                   silhouette=silhouette if wants[3] else None, image=image if wants[2] else None)
