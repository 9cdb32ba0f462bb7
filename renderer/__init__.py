"""A differentiable renderer for signed distance fields sampled on grids (SDFDiff, CVPR 2020), and
its public API (``__all__``): sphere tracing finds where rays meet the surface without gradients,
and only the local shading at the hits (and the soft silhouettes) is differentiable, as in the
paper, unless ``Scene(gradient="visibility")`` also gives the image the motion of its edges
(renderer/shading.py, ``edge_gradient``). Both stages
run as fused numba kernels (CPU or CUDA, ``renderer.fused`` over ``renderer.kernels``) where
available; their plain-PyTorch versions (``renderer.reference``, ``renderer.shading``) are the
specification, used by ``backend="reference"`` and as the fallback, and ``renderer.backends``
chooses. Importing the package sets ``THP_MEM_ALLOC_ENABLE=1`` unless the variable is already set
(``0`` turns it off), so that PyTorch backs large CPU tensors with transparent huge pages: a
render's gradient is a fresh grid-sized buffer every backward pass, and zeroing it is several
times faster with huge pages than with 4 KiB pages (docs/measurements.md). Examples and the
details: README.md and docs/renderer.md.
"""
import os as _os

_os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")

from .backends import backend_available, stage2_available  # noqa: E402
from .cameras import NMR_DISTANCE, NMR_ELEVATION_DEG, NMR_FOV_DEG, NMR_NUM_VIEWS, Cameras, rotation_matrices  # noqa: E402
from .examples import torus_and_sphere  # noqa: E402
from .grid import SDFGrid  # noqa: E402
from .kernels import start_cpu_thread_pool  # noqa: E402
from .records import MarchResult, RenderOutput  # noqa: E402
from .render import render  # noqa: E402
from .scene import EFFECTS, DirectionalLight, PointLight, Scene  # noqa: E402
from .settings import TraceSettings  # noqa: E402
from .shading import shade_lambert  # noqa: E402
from .stage2 import shade_trace  # noqa: E402
from .trace import sphere_trace  # noqa: E402

__all__ = [
    "SDFGrid",
    "Cameras",
    "rotation_matrices",
    "NMR_DISTANCE",
    "NMR_ELEVATION_DEG",
    "NMR_FOV_DEG",
    "NMR_NUM_VIEWS",
    "Scene",
    "DirectionalLight",
    "PointLight",
    "EFFECTS",
    "TraceSettings",
    "MarchResult",
    "RenderOutput",
    "sphere_trace",
    "render",
    "shade_trace",
    "shade_lambert",
    "backend_available",
    "stage2_available",
    "start_cpu_thread_pool",
    "torus_and_sphere",
]
