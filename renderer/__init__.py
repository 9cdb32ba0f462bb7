"""A differentiable renderer for signed distance fields sampled on grids (SDFDiff, CVPR 2020).

Sphere tracing finds where rays meet the surface without gradients; only the local shading at the
hits (and the soft silhouettes) is differentiable, in plain PyTorch.

    >>> import torch, renderer
    >>> grid = renderer.SDFGrid.from_function(lambda p: p.norm(dim=-1) - 0.5, 64)
    >>> cams = renderer.Cameras.look_at(eye=[[0.0, 0.0, 3.0]], fov_deg=40, image_size=128)
    >>> out = renderer.render(grid, cams, renderer.Scene(effects=("silhouette", "shading")))
    >>> out.image.shape, out.depth is None
    (torch.Size([1, 128, 128, 3]), True)
"""
from .cameras import Cameras
from .grid import SDFGrid
from .render import RenderOutput, render, shade_trace
from .scene import EFFECTS, DirectionalLight, PointLight, Scene
from .settings import TraceSettings
from .kernels import start_cpu_thread_pool
from .trace import TraceResult, sphere_trace

__all__ = [
    "SDFGrid",
    "Cameras",
    "Scene",
    "DirectionalLight",
    "PointLight",
    "EFFECTS",
    "TraceSettings",
    "TraceResult",
    "RenderOutput",
    "sphere_trace",
    "render",
    "shade_trace",
    "start_cpu_thread_pool",
]
