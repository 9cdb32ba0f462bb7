"""The renderer's fused kernels (numba CPU and CUDA): the sphere-tracing march and the
differentiable stage 2 (forward and backward), each sharing one per-ray routine between targets.

They implement exactly the march of renderer/reference.py and the stage 2 of renderer/shading.py
(renderer/render.py's ``shade_trace``), which stay the specification; the per-ray code is
renderer/kernels/raymarch.py. This module is the torch side: it checks the inputs, packs the grid,
the settings and the scene into small parameter arrays, hands the kernels zero-copy views of the
tensors (CPU: ``Tensor.numpy()``; CUDA: ``numba.cuda.as_cuda_array``, the CUDA array interface)
and returns torch tensors. The autograd Function around stage 2 is renderer/stage2.py.

The kernels compile on first use, once per dtype, and numba caches them on disk (next to this
package, else in numba's user cache directory, else in a temporary directory), so a new process
loads them instead of compiling again. ``NUMBA_CACHE_DIR`` overrides the location.

The CPU kernels run on numba's "omp" thread pool, the GNU OpenMP runtime torch uses, unless numba's
pool was already started or the user chose a layer (``NUMBA_THREADING_LAYER``): see
``_start_thread_pool`` for why.
"""
from __future__ import annotations

import contextlib
import functools
import os
import tempfile
import threading

import torch

from ..grid import SDFGrid
from ..reference import TINY_DIRECTION, min_threshold
from ..settings import TraceSettings

FUSED_BACKENDS = ("cpu", "cuda")
# Blocks of rays (raymarch.BLOCK each) per chunk handed to a CPU thread: rays differ a lot in cost
# (misses leave at once, grazing rays crawl), so threads take small chunks dynamically instead of
# one static half each.
CPU_CHUNK_BLOCKS = 2
CUDA_THREADS_PER_BLOCK = 128
_CPU_LAUNCH_LOCK = threading.Lock()


def _writable_dir(path: str) -> bool:
    try:
        os.makedirs(path, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
        return True
    except OSError:
        return False


def _configure_cache() -> None:
    """Makes sure numba has somewhere writable to cache the kernels (set before they are defined)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    import numba
    from numba.misc.appdirs import AppDirs

    in_tree = os.path.join(os.path.dirname(os.path.abspath(__file__)), "__pycache__")
    user_wide = AppDirs(appname="numba", appauthor=False).user_cache_dir
    if _writable_dir(in_tree) or _writable_dir(user_wide):
        return  # numba's own locators find these
    fallback = os.path.join(tempfile.gettempdir(), f"sdfdiff-numba-cache-{os.getuid()}")
    os.environ["NUMBA_CACHE_DIR"] = fallback
    numba.config.CACHE_DIR = fallback


def _start_thread_pool() -> None:
    """Starts numba's CPU thread pool, preferring its "omp" layer unless the user chose one.

    torch runs its CPU ops on GNU OpenMP, and numba's "omp" layer joins that same runtime, so the
    fused kernels and torch's ops take turns on one pool of threads (``_launch`` runs the kernels
    with torch's thread count). With numba's own "workqueue" pool beside it instead, torch's workers,
    which busy-wait for a while after each op, and numba's threads fought over the cores: with both
    stages fused, a forward + backward at 64^2, B = 32 on 2 cores took 86 ms that way and 54 ms on
    one pool (docs/measurements.md; when stage 2 was still dozens of PyTorch ops the spinning hurt
    those ops instead, and workqueue was the better choice). Where numba has no "omp" layer it takes
    "tbb", else "workqueue". The layer is process-wide and fixed when the pool starts, so nothing
    changes if numba's pool is already running or ``NUMBA_THREADING_LAYER`` is set. GNU OpenMP is
    not fork-safe: a forked child must not run numba parallel code (the project's process pools
    spawn their workers).
    """
    import numba

    try:
        from numba.np.ufunc import parallel
    except ImportError:  # an unusual numba: leave its defaults
        return
    if getattr(parallel, "_is_initialized", True):
        return
    if "NUMBA_THREADING_LAYER" not in os.environ and str(numba.config.THREADING_LAYER) == "default":
        numba.config.THREADING_LAYER_PRIORITY = ["omp", "tbb", "workqueue"]
    with _keeping_torch_threads():
        numba.get_num_threads()  # starts the pool now, with that layer


@contextlib.contextmanager
def _keeping_torch_threads():
    """Restores torch's thread count after the block: on the shared OpenMP runtime, starting
    numba's "omp" pool or launching a kernel sets the count torch reads to numba's own."""
    threads = torch.get_num_threads()
    try:
        yield
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)


def _kernel_threads() -> int:
    """The threads a CPU kernel runs with: torch's count (``torch.set_num_threads`` governs both),
    within numba's pool."""
    import numba

    return min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)


def start_cpu_thread_pool() -> None:
    """Starts numba's CPU thread pool the way the fused kernel wants it (see ``_start_thread_pool``).

    The pool's layer is fixed for the whole process when it first starts, so a program that runs
    numba parallel code of its own (e.g. a data generator) before its first render calls this
    first. Does nothing if the pool is already running.
    """
    _start_thread_pool()


@functools.lru_cache(maxsize=None)
def _load_march():
    _configure_cache()
    from . import raymarch as march_module

    _start_thread_pool()
    return march_module


@functools.lru_cache(maxsize=None)
def available(backend: str) -> tuple[bool, str]:
    """(True, "") if the fused ``backend`` ("cpu" or "cuda") can run here, else (False, reason)."""
    if backend not in FUSED_BACKENDS:
        raise ValueError(f"backend must be one of {FUSED_BACKENDS}, got {backend!r}")
    try:
        _load_march()
    except Exception as exc:  # numba missing or broken: the reference march still works
        return False, f"numba is unusable ({type(exc).__name__}: {exc})"
    if backend == "cpu":
        return True, ""
    if not torch.cuda.is_available():
        return False, "torch sees no CUDA GPU"
    try:
        from numba import cuda
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
    ok, why = available(backend)
    if not ok or backend == "cpu":
        return ok, why
    try:
        _shade_one_ray_on_gpu()
    except Exception as exc:
        return False, f"the fused stage 2 cannot build or run on the GPU ({type(exc).__name__}: {exc})"
    return True, ""


def _shade_one_ray_on_gpu() -> None:
    """Renders one ray into an 8^3 sphere grid on the GPU with the fused stage 2, forward and
    backward: the depth must be near 2.5 and the gradient finite and non-zero."""
    from ..cameras import Cameras
    from ..scene import Scene
    from ..stage2 import shade_trace_fused
    from ..trace import sphere_trace

    grid = _sphere_grid_on_gpu()
    values = grid.values.requires_grad_(True)
    cams = Cameras.look_at([[0.0, 0.0, 3.0]], fov_deg=1.0, image_size=1, device=grid.device)
    depth, _, silhouette, image = shade_trace_fused(grid, cams, sphere_trace(grid, cams, backend="cuda"), Scene(),
                                                    "cuda")
    (depth.sum() + silhouette.sum() + image.sum()).backward()
    d, g = float(depth.detach().reshape(-1)[0]), values.grad
    if abs(d - 2.5) > 0.1 or not bool(torch.isfinite(g).all()) or float(g.abs().sum()) == 0.0:
        raise RuntimeError(f"a one-ray render came back wrong (depth {d:.4f}, expected ~2.5)")


def _sphere_grid_on_gpu() -> SDFGrid:
    """An 8^3 grid of a sphere of radius 0.5 over [-1, 1]^3 (float32) on the current GPU, for the
    one-ray probes above and below."""
    dev = torch.device("cuda", torch.cuda.current_device())
    axis = torch.linspace(-1.0, 1.0, 8, device=dev)
    x, y, z = torch.meshgrid(axis, axis, axis, indexing="ij")
    return SDFGrid(((x * x + y * y + z * z).sqrt() - 0.5)[None])


def _march_one_ray_on_gpu() -> None:
    """Marches one ray into an 8^3 sphere grid (radius 0.5) on the current GPU (float32): the kernel
    is compiled (or loaded from the disk cache) and run, so a CUDA toolchain that cannot build it is
    found here, where ``backend="auto"`` can still fall back, rather than in the first render. The
    ray from z = 3 down the axis must hit near t = 2.5."""
    grid = _sphere_grid_on_gpu()
    dev = grid.device
    origin = torch.tensor([[0.0, 0.0, 3.0]], device=dev)
    direction = torch.tensor([[0.0, 0.0, -1.0]], device=dev)
    out = _run("cuda", grid, origin, direction, torch.zeros(1, dtype=torch.int64, device=dev),
               torch.full((1,), 1e-3, device=dev), TraceSettings())
    hit, t = bool(out["hit"][0]), float(out["t"][0])
    if not hit or abs(t - 2.5) > 0.1:
        raise RuntimeError(f"a ray into a sphere grid came back wrong (hit={hit}, t={t:.4f}, expected t~2.5)")


_DEVICE_CONSTANTS: dict[tuple, torch.Tensor] = {}


def _on_device(t: torch.Tensor, device: torch.device) -> torch.Tensor:
    """A small CPU tensor of kernel parameters on ``device``: on a GPU, one copy per distinct
    content, kept (a render copies no parameters to the GPU and waits for no copy after the first)."""
    if device.type == "cpu":
        return t
    key = (device, t.dtype, tuple(t.shape), tuple(t.reshape(-1).tolist()))
    out = _DEVICE_CONSTANTS.get(key)
    if out is None:
        if len(_DEVICE_CONSTANTS) > 4096:  # parameters of many distinct grids or scenes
            _DEVICE_CONSTANTS.clear()
        out = _DEVICE_CONSTANTS[key] = t.to(device)
    return out


def _params(grid: SDFGrid, settings: TraceSettings) -> tuple[torch.Tensor, torch.Tensor]:
    """The grid and settings packed for the kernels (layout in renderer/kernels/raymarch.py), made
    on the host from the grid's host box and copied to its device (``_on_device``)."""
    march_module = _load_march()
    dt = grid.dtype
    lo, hi = grid.host_box()
    res = torch.tensor(grid.resolution, dtype=dt)
    floor = min_threshold(grid)
    fixed = settings.threshold is not None
    consts = torch.tensor(
        [0.0, 1.0, TINY_DIRECTION, floor, settings.threshold_scale,
         max(float(settings.threshold), floor) if fixed else 0.0, -settings.inner_depth], dtype=dt)
    # The same tensor expressions as the reference, so the kernels see bit-identical constants.
    params = torch.cat([lo, hi, grid.host_voxel_size(), (lo + hi) / 2, res - 1, res - 2, consts]).contiguous()
    iparams = torch.tensor([*grid.resolution, settings.max_steps, settings.inner_steps, int(fixed)],
                           dtype=torch.int64)
    if params.numel() != march_module.N_PARAMS or iparams.numel() != march_module.N_IPARAMS:
        raise RuntimeError("renderer/kernels: the parameter layout and raymarch.py disagree")
    return _on_device(params, grid.device), _on_device(iparams, grid.device)


def _check_inputs(grid, origins, directions, grid_index, pixel_angle, settings, check_indices: bool = True) -> int:
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
    return r


@torch.no_grad()
def march(
    backend: str,
    grid: SDFGrid,
    origins: torch.Tensor,
    directions: torch.Tensor,
    grid_index: torch.Tensor,
    pixel_angle: torch.Tensor,
    settings: TraceSettings,
    check_indices: bool = True,
) -> dict[str, torch.Tensor]:
    """Sphere-traces R rays with the fused kernel: the same contract as ``march_reference``.

    Args:
        backend: "cpu" or "cuda"; the tensors must be on that device.
        grid: B grids, float32 or float64 (the march runs in that dtype).
        origins, directions: (R, 3) world, unit directions.
        grid_index: (R,) integer, the grid each ray reads.
        pixel_angle: (R,) pixel footprint per unit distance.
        settings: the march settings.
        check_indices: whether to check that ``grid_index`` lies in the grid batch (a min/max that
            waits for the GPU; ``sphere_trace`` makes the indices itself and skips it).
    Returns:
        dict with t (R,), hit (R,) bool, extreme (R, 3), t_extreme (R,) in the grid dtype and
        steps (R,) int32, on the grid's device, detached.
    """
    if backend not in FUSED_BACKENDS:
        raise ValueError(f"backend must be one of {FUSED_BACKENDS}, got {backend!r}")
    ok, why = available(backend)
    if not ok:
        raise RuntimeError(f"backend={backend!r} is not available: {why}")
    if (backend == "cuda") != (grid.device.type == "cuda"):
        raise ValueError(f"backend={backend!r} cannot march a grid on device {grid.device}")
    _check_inputs(grid, origins, directions, grid_index, pixel_angle, settings, check_indices)
    return _run(backend, grid, origins, directions, grid_index, pixel_angle, settings)


def _run(backend, grid, origins, directions, grid_index, pixel_angle, settings) -> dict[str, torch.Tensor]:
    """``march`` past its checks: packs the inputs, launches the kernel, returns its outputs."""
    r = origins.shape[0]
    dt, dev = grid.dtype, grid.device
    values = grid.values.detach().contiguous().reshape(-1)  # a view: no copy of a contiguous grid
    params, iparams = _params(grid, settings)
    inputs = [values, params, iparams, origins.detach().to(dt).contiguous(),
              directions.detach().to(dt).contiguous(), grid_index.to(torch.int64).contiguous(),
              pixel_angle.detach().to(dt).contiguous()]
    out = {
        "t": torch.empty(r, dtype=dt, device=dev),
        "hit": torch.empty(r, dtype=torch.uint8, device=dev),
        "extreme": torch.empty(r, 3, dtype=dt, device=dev),
        "t_extreme": torch.empty(r, dtype=dt, device=dev),
        "steps": torch.empty(r, dtype=torch.int32, device=dev),
    }
    march_module = _load_march()
    cuda_kernel = march_module.make_cuda_kernel() if backend == "cuda" else None
    _launch(backend, march_module.march_rays_cpu, cuda_kernel, inputs + list(out.values()), r)
    out["hit"] = out["hit"].view(torch.bool)
    return out


# ---------------------------------------------------------------------------- stage 2
def stage2_params(grid: SDFGrid, scene, pixels: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The scene packed for the stage-2 kernels (layouts in renderer/kernels/raymarch.py):
    ``sparams`` (grid dtype) and ``lights`` (L, 6) on the grid's device, ``sflags`` (int64; the
    gradient flags left 0) on the CPU."""
    from ..scene import PointLight

    m = _load_march()
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
    return _on_device(sparams, grid.device), sflags, _on_device(lights, grid.device)


def _launch(backend: str, cpu_kernel, cuda_kernel, tensors: list[torch.Tensor], rays: int) -> None:
    if not rays:
        return
    if backend == "cpu":
        import numba

        # Views: the kernels write the output tensors in place. One kernel at a time: numba's
        # workqueue pool (see _start_thread_pool) aborts the process on concurrent launches from
        # several Python threads.
        arrays = [x.numpy() if isinstance(x, torch.Tensor) else x for x in tensors]
        with _CPU_LAUNCH_LOCK, numba.parallel_chunksize(CPU_CHUNK_BLOCKS), _keeping_torch_threads():
            numba.set_num_threads(_kernel_threads())
            cpu_kernel(*arrays)
        return
    from numba import cuda

    device = tensors[0].device
    index = device.index if device.index is not None else torch.cuda.current_device()
    with cuda.gpus[index]:
        # Launch on torch's current stream: ordered after the ops that made the inputs and before
        # those that read the outputs, without a synchronisation.
        stream = cuda.external_stream(torch.cuda.current_stream(device).cuda_stream)
        arrays = [cuda.as_cuda_array(x, sync=False) if isinstance(x, torch.Tensor) else x for x in tensors]
        blocks = (rays + CUDA_THREADS_PER_BLOCK - 1) // CUDA_THREADS_PER_BLOCK
        cuda_kernel[blocks, CUDA_THREADS_PER_BLOCK, stream](*arrays)


def shade_forward(backend: str, values: torch.Tensor, params: torch.Tensor, iparams: torch.Tensor,
                  sparams: torch.Tensor, sflags: torch.Tensor, lights: torch.Tensor, rays: dict,
                  outputs: dict) -> None:
    """Runs stage 2's forward kernel: fills ``outputs`` (depth, normal, image, silhouette; empty
    where the scene does not ask for them) from the traced ``rays`` (see renderer/stage2.py)."""
    m = _load_march()
    tensors = [values, params, iparams, sparams, sflags, lights, rays["hit"], rays["t"], rays["points"],
               rays["directions"], rays["extreme"], rays["t_extreme"], rays["steps"], rays["cam_grid"],
               rays["pixel_angle"], rays["eyes"], outputs["depth"], outputs["normal"], outputs["image"],
               outputs["silhouette"]]
    if backend == "cpu":
        _launch("cpu", m.shade_rays_cpu, None, tensors, rays["hit"].shape[0])
    else:
        _launch("cuda", None, m.make_cuda_shade_kernels()[0], tensors, rays["hit"].shape[0])


def shade_backward(backend: str, values: torch.Tensor, params: torch.Tensor, iparams: torch.Tensor,
                   sparams: torch.Tensor, sflags: torch.Tensor, lights: torch.Tensor, rays: dict,
                   grads: dict, silhouette: torch.Tensor, grids: int) -> torch.Tensor:
    """Runs stage 2's backward kernel: the gradient of the flat ``values`` from the outputs'
    gradients ``grads`` (depth, normal, image, silhouette; empty where there is none) and the
    forward's ``silhouette`` (R,) (empty where the scene has none)."""
    m = _load_march()
    r = rays["hit"].shape[0]
    # The CPU kernel zeroes the gradient itself, grid by grid in the thread that fills it.
    grad = torch.empty_like(values) if backend == "cpu" else torch.zeros_like(values)
    common = [values, params, iparams, sparams, sflags, lights, rays["hit"], rays["points"], rays["directions"],
              rays["extreme"], rays["t_extreme"], rays["steps"], rays["cam_grid"], rays["pixel_angle"],
              rays["eyes"], grads["depth"], grads["normal"], grads["image"], grads["silhouette"], silhouette]
    if backend == "cpu":
        # Whole grids per thread when there are enough of them to share out (see the kernel).
        one_pass = grids >= 2 * _kernel_threads()
        scratch = torch.empty(0 if one_pass else r, 8, dtype=values.dtype)
        _launch("cpu", m.shade_rays_backward_cpu, None,
                common + [grids, scratch, grad], r)
    else:
        _launch("cuda", None, m.make_cuda_shade_kernels()[1], common + [grad], r)
    return grad
