"""render(): stage 1 (``sphere_trace``, renderer/trace.py), then stage 2 (``shade_trace``,
renderer/stage2.py), into a RenderOutput."""
from __future__ import annotations

from .cameras import Cameras
from .grid import SDFGrid
from .records import RenderOutput
from .scene import Scene
from .settings import TraceSettings
from .stage2 import shade_trace
from .trace import sphere_trace


def render(
    grid: SDFGrid,
    cameras: Cameras,
    scene: Scene = Scene(),
    trace_settings: TraceSettings = TraceSettings(),
    backend: str = "auto",
) -> RenderOutput:
    """Renders SDF grids: sphere tracing without gradients, then differentiable local shading.

    With a fused march (``backend`` "cpu", "cuda", or "auto" where the kernels are available) the
    differentiable stage is fused too (renderer/fused.py), except for the exact intersection;
    ``backend="reference"`` runs the PyTorch specification of both stages. With
    ``scene.gradient="visibility"`` the march also finds grazing points, and the edge term of the
    gradient is PyTorch's on either path (renderer/stage2.py).

    Args:
        grid: B_g grids. cameras: B_c cameras, a multiple of B_g; camera c sees grid
            ``c // (B_c / B_g)`` (one grid seen by many cameras, or G grids by V cameras each).
        scene: effects, lights, material, background.
        trace_settings: the march (steps, threshold).
        backend: "auto", "reference", "cpu" or "cuda" (see renderer.trace.sphere_trace).
    Returns:
        RenderOutput with (B_c, H, W) maps, differentiable w.r.t. ``grid.values``, and w.r.t. the
        cameras' poses where they carry a gradient (``Cameras.moved``; stage 2 is then PyTorch's).
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a Scene, got {type(scene).__name__}")
    trace = sphere_trace(grid, cameras, trace_settings, backend, grazing=scene.needs_grazing())
    return shade_trace(grid, cameras, trace, scene)
