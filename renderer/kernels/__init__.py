"""The renderer's fused kernels (numba CPU and CUDA), compiled and launched: the sphere-tracing
march and the differentiable stage 2 (forward and backward), whose per-ray code is
renderer/kernels/raymarch.py. This module takes plain tensors and the packed parameter arrays
(renderer/fused.py packs them and checks the inputs; renderer/backends.py decides whether a
backend works and which runs), hands the kernels zero-copy views (CPU: ``Tensor.numpy()``; CUDA:
``numba.cuda.as_cuda_array``, the CUDA array interface) and returns torch tensors. The kernels
compile on first use, once per dtype, and numba caches them on disk (next to this package, else
in numba's user cache directory, else in a temporary directory; ``NUMBA_CACHE_DIR`` overrides);
the CPU kernels run on numba's "omp" thread pool, torch's GNU OpenMP runtime, unless the pool was
already started or the user chose a layer (``_start_thread_pool`` says why).
"""
from __future__ import annotations

import contextlib
import functools
import os
import tempfile
import threading

import torch

from ..records import MarchedRays, ShadingRays

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
    import numba  # optional and slow to import: only when the kernels load
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
    import numba  # optional and slow to import: only when the kernels load

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
    import numba  # optional and slow to import: only when the kernels load

    return min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)


def start_cpu_thread_pool() -> None:
    """Starts numba's CPU thread pool the way the fused kernel wants it (see ``_start_thread_pool``).

    The pool's layer is fixed for the whole process when it first starts, so a program that runs
    numba parallel code of its own (e.g. a data generator) before its first render calls this
    first. Does nothing if the pool is already running.
    """
    _start_thread_pool()


@functools.lru_cache(maxsize=None)
def load():
    """The compiled per-ray module (renderer/kernels/raymarch.py), imported once; raises what numba
    raises where it is missing or broken."""
    _configure_cache()
    # numba, imported with the kernels' module on first use: the renderer imports without it.
    from . import raymarch as march_module

    _start_thread_pool()
    return march_module


_DEVICE_CONSTANTS: dict[tuple, torch.Tensor] = {}


def on_device(t: torch.Tensor, device: torch.device) -> torch.Tensor:
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


def _launch(backend: str, cpu_kernel, cuda_kernel, tensors: list[torch.Tensor], rays: int) -> None:
    if not rays:
        return
    if backend == "cpu":
        import numba  # optional: loaded with the kernels

        # Views: the kernels write the output tensors in place. One kernel at a time: numba's
        # workqueue pool (see _start_thread_pool) aborts the process on concurrent launches from
        # several Python threads.
        arrays = [x.detach().numpy() if isinstance(x, torch.Tensor) else x for x in tensors]
        with _CPU_LAUNCH_LOCK, numba.parallel_chunksize(CPU_CHUNK_BLOCKS), _keeping_torch_threads():
            numba.set_num_threads(_kernel_threads())
            cpu_kernel(*arrays)
        return
    from numba import cuda  # optional, and imports only where numba-cuda is installed

    device = tensors[0].device
    index = device.index if device.index is not None else torch.cuda.current_device()
    with cuda.gpus[index]:
        # Launch on torch's current stream: ordered after the ops that made the inputs and before
        # those that read the outputs, without a synchronisation.
        stream = cuda.external_stream(torch.cuda.current_stream(device).cuda_stream)
        # detach(): torch refuses the array interface of a tensor that requires grad (the backward's
        # saved silhouette is such an output); the kernels read and write the same storage.
        arrays = [cuda.as_cuda_array(x.detach(), sync=False) if isinstance(x, torch.Tensor) else x
                  for x in tensors]
        blocks = (rays + CUDA_THREADS_PER_BLOCK - 1) // CUDA_THREADS_PER_BLOCK
        cuda_kernel[blocks, CUDA_THREADS_PER_BLOCK, stream](*arrays)


@torch.no_grad()
def march(backend: str, values: torch.Tensor, params: torch.Tensor, iparams: torch.Tensor, origins: torch.Tensor,
          directions: torch.Tensor, grid_index: torch.Tensor, pixel_angle: torch.Tensor,
          grazing: bool = False) -> MarchedRays:
    """Launches the march kernel of ``backend`` ("cpu" or "cuda") on R rays.

    Args:
        values: (B * Nx * Ny * Nz,) the grids flattened (C order), float32 or float64, contiguous.
        params, iparams: the grid and the march settings packed (layouts in raymarch.py), on the
            values' device.
        origins, directions: (R, 3) world, unit directions; pixel_angle (R,): in the values' dtype,
            contiguous. grid_index: (R,) int64, contiguous, each in [0, B).
        grazing: whether ``iparams`` asks for grazing points (then returned, else None).
    Returns:
        MarchedRays on the values' device.
    """
    r = origins.shape[0]
    dt, dev = values.dtype, values.device
    t = torch.empty(r, dtype=dt, device=dev)
    hit = torch.empty(r, dtype=torch.uint8, device=dev)
    extreme = torch.empty(r, 3, dtype=dt, device=dev)
    t_extreme = torch.empty(r, dtype=dt, device=dev)
    steps = torch.empty(r, dtype=torch.int32, device=dev)
    graze = torch.empty(r if grazing else 1, 2, dtype=dt, device=dev)  # (gap, distance); unwritten if not asked
    m = load()
    cuda_kernel = m.make_cuda_kernel() if backend == "cuda" else None
    _launch(backend, m.march_rays_cpu, cuda_kernel,
            [values, params, iparams, origins, directions, grid_index, pixel_angle, t, hit, extreme, t_extreme,
             steps, graze], r)
    if not grazing:
        return MarchedRays(t=t, hit=hit.view(torch.bool), extreme=extreme, t_extreme=t_extreme, steps=steps)
    return MarchedRays(t=t, hit=hit.view(torch.bool), extreme=extreme, t_extreme=t_extreme, steps=steps,
                       graze_t=graze[:, 1], graze_gap=graze[:, 0])


def _ray_arrays(rays: ShadingRays) -> list[torch.Tensor]:
    return [rays.hit.view(torch.uint8), rays.t, rays.points, rays.directions, rays.extreme, rays.t_extreme,
            rays.steps, rays.camera_grid, rays.pixel_angle, rays.eyes]


def shade_forward(backend: str, values: torch.Tensor, params: torch.Tensor, iparams: torch.Tensor,
                  sparams: torch.Tensor, sflags: torch.Tensor, lights: torch.Tensor, rays: ShadingRays,
                  depth: torch.Tensor, normal: torch.Tensor, image: torch.Tensor, silhouette: torch.Tensor) -> None:
    """Launches stage 2's forward kernel: fills depth (R,), normal (R, 3), image (R, C) and
    silhouette (R,) (each empty, 0 rows, where the scene does not ask for it) from ``rays``.

    values: the flat grids as in ``march``; params, iparams: the grid packed as for the march;
    sparams, sflags, lights: the scene packed (layouts in raymarch.py), on the values' device.
    """
    m = load()
    hit, t, points, directions, extreme, t_extreme, steps, camera_grid, pixel_angle, eyes = _ray_arrays(rays)
    tensors = [values, params, iparams, sparams, sflags, lights, hit, t, points, directions, extreme, t_extreme,
               steps, camera_grid, pixel_angle, eyes, depth, normal, image, silhouette]
    if backend == "cpu":
        _launch("cpu", m.shade_rays_cpu, None, tensors, rays.count)
    else:
        _launch("cuda", None, m.make_cuda_shade_kernels()[0], tensors, rays.count)


def shade_backward(backend: str, values: torch.Tensor, params: torch.Tensor, iparams: torch.Tensor,
                   sparams: torch.Tensor, sflags: torch.Tensor, lights: torch.Tensor, rays: ShadingRays,
                   grad_depth: torch.Tensor, grad_normal: torch.Tensor, grad_image: torch.Tensor,
                   grad_silhouette: torch.Tensor, silhouette: torch.Tensor, grids: int) -> torch.Tensor:
    """Launches stage 2's backward kernel: the gradient of the flat ``values`` from the outputs'
    gradients (shaped as the outputs of ``shade_forward``; empty where there is none) and the
    forward's ``silhouette`` (R,) (empty where the scene has none). ``grids``: B, the grids in
    ``values``; sflags: with the gradient flags of the outputs that brought one set."""
    m = load()
    r = rays.count
    hit, _, points, directions, extreme, t_extreme, steps, camera_grid, pixel_angle, eyes = _ray_arrays(rays)
    # The CPU kernel zeroes the gradient itself, grid by grid in the thread that fills it.
    grad = torch.empty_like(values) if backend == "cpu" else torch.zeros_like(values)
    common = [values, params, iparams, sparams, sflags, lights, hit, points, directions, extreme, t_extreme, steps,
              camera_grid, pixel_angle, eyes, grad_depth, grad_normal, grad_image, grad_silhouette, silhouette]
    if backend == "cpu":
        # Whole grids per thread when there are enough of them to share out (see the kernel).
        one_pass = grids >= 2 * _kernel_threads()
        scratch = torch.empty(0 if one_pass else r, 8, dtype=values.dtype)
        _launch("cpu", m.shade_rays_backward_cpu, None, common + [grids, scratch, grad], r)
    else:
        _launch("cuda", None, m.make_cuda_shade_kernels()[1], common + [grad], r)
    return grad
