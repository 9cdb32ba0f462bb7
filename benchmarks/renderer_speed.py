"""Renderer speed, run as ``python -m benchmarks.renderer_speed [--quick] [--threads N]
[--device cpu|cuda] [--out FILE]``: the PyTorch reference pipeline against the fused kernels, the
march alone and a full differentiable render (forward + backward), timed and with their peak
memory, in one run that writes docs/bench_renderer.md (docs/bench_renderer_cuda.md with
``--device cuda``). Torch and numba use every core, as users get them, unless ``--threads`` or
``--torch-threads`` says otherwise; the scenes are batches of 64^3 tori seen by one camera each.
``--help`` says what is timed and how memory is measured.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import torch

import renderer
from benchmarks.common import median_times_ms, peak_rss_kib, reset_peak_rss
from renderer import Cameras, Scene, SDFGrid, render, shade_trace, sphere_trace
from sdfcommon.tooling.outputs import write_text

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Config:
    """One benchmark case: B grids of ``grid``^3, one ``image``^2 camera each."""

    image: int
    batch: int
    grid: int = 64

    @property
    def name(self) -> str:
        return f"{self.image}^2, B={self.batch}"

    @property
    def rays(self) -> int:
        return self.image * self.image * self.batch


CONFIGS = (Config(64, 32), Config(128, 8), Config(256, 8))
CUDA_CONFIGS = CONFIGS + (Config(512, 16),)
def fused_backend(device: torch.device) -> str:
    return "cuda" if device.type == "cuda" else "cpu"


def march_backends(device: torch.device) -> dict[str, str]:
    """The march backend behind each march column label ("reference", "fused") on ``device``. On
    CUDA the fused CPU march of the same host is timed too ("host", in ``time_config``), for the
    CUDA-vs-CPU ratio."""
    return {"reference": "reference", "fused": fused_backend(device)}


def render_variants(device: torch.device) -> dict[str, tuple[str, str, str]]:
    """The (march backend, stage 2, gradient) behind each render column label: the reference
    pipeline, the fused march with the PyTorch stage 2, both stages fused (the paper's gradient),
    and the visibility gradient (the fused march with grazing points, the PyTorch stage 2)."""
    fused = fused_backend(device)
    return {"reference": ("reference", "auto", "paper"), "fused_march": (fused, "reference", "paper"),
            "fused": (fused, "auto", "paper"), "visibility": (fused, "auto", "visibility")}


def torus_grids(batch: int, n: int, seed: int = 0) -> torch.Tensor:
    """(batch, n, n, n) float32 torus SDFs over [-1, 1]^3 (ring in the xz plane), radii varied per grid."""
    gen = torch.Generator().manual_seed(seed)
    axis = torch.linspace(-1.0, 1.0, n)
    x, y, z = torch.meshgrid(axis, axis, axis, indexing="ij")
    big = 0.5 + 0.1 * torch.rand(batch, generator=gen)
    small = 0.15 + 0.1 * torch.rand(batch, generator=gen)
    ring = torch.sqrt(x * x + z * z)[None] - big[:, None, None, None]
    return torch.sqrt(ring * ring + (y * y)[None]) - small[:, None, None, None]


def scene_for(cfg: Config, seed: int = 0) -> tuple[torch.Tensor, Cameras]:
    """Grid values (B, N, N, N) and B cameras at distance 2.5 looking at the origin."""
    gen = torch.Generator().manual_seed(seed + 1)
    eyes = torch.randn(cfg.batch, 3, generator=gen, dtype=torch.float64)
    eyes = 2.5 * eyes / eyes.norm(dim=-1, keepdim=True)
    ups = torch.where(eyes[:, 1:2].abs() > 2.4, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64),
                      torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64))
    cams = Cameras.look_at(eyes, up=ups, fov_deg=40.0, image_size=cfg.image)
    return torus_grids(cfg.batch, cfg.grid, seed), cams


def forward_backward(values: torch.Tensor, cams: Cameras, backend: str, stage2: str = "auto",
                     gradient: str = "paper") -> None:
    """One differentiable render of every camera and the backward pass into the grid values
    (``render`` with ``Scene(gradient=gradient)``; with ``stage2`` other than "auto", its two
    stages called with that stage 2)."""
    v = values.detach().requires_grad_(True)
    grid = SDFGrid(v)
    scene = Scene(gradient=gradient)
    if stage2 == "auto":
        out = render(grid, cams, scene, backend=backend)
    else:
        out = shade_trace(grid, cams, sphere_trace(grid, cams, backend=backend), scene, stage2=stage2)
    loss = out.image.mean() + out.silhouette.mean() + out.depth.mean()
    loss.backward()
    if v.is_cuda:
        torch.cuda.synchronize(v.device)  # the timers read the host clock


def trace_synced(grid: SDFGrid, cams: Cameras, backend: str) -> None:
    """``sphere_trace`` with every backend; on a GPU, waits for the march to finish."""
    sphere_trace(grid, cams, backend=backend)
    if grid.device.type == "cuda":
        torch.cuda.synchronize(grid.device)


def time_config(cfg: Config, repeats: int, device: torch.device = torch.device("cpu")) -> dict[str, float]:
    """Medians (ms) of the march per ``march_backends`` column and of forward + backward per
    ``render_variants`` column on ``device`` (on CUDA also the host's fused CPU kernels, "host"),
    with hit fraction and mean steps."""
    values, cams = scene_for(cfg)
    fns = {}
    for label, backend in march_backends(device).items():
        grid = SDFGrid(values.to(device))
        fns[f"march_{label}"] = lambda grid=grid, backend=backend: trace_synced(grid, cams, backend)
    for label, (backend, stage2, gradient) in render_variants(device).items():
        v = values.to(device)
        fns[f"render_{label}"] = lambda v=v, b=backend, s2=stage2, g=gradient: forward_backward(v, cams, b, s2, g)
    if device.type == "cuda":  # the host's fused CPU kernels on the same scenes
        grid = SDFGrid(values)
        fns["march_host"] = lambda: trace_synced(grid, cams, "cpu")
        fns["render_host"] = lambda: forward_backward(values, cams, "cpu")
    row = median_times_ms(fns, repeats)
    trace = sphere_trace(SDFGrid(values.to(device)), cams, backend=fused_backend(device))
    row["hit_fraction"] = float(trace.hit.float().mean())
    row["mean_steps"] = float(trace.steps.float().mean())
    return row


def measure_cuda_memory(cfg: Config, backend: str, stage2: str, gradient: str,
                        device: torch.device) -> dict[str, float | str]:
    """Peak extra GPU memory (MiB) of one forward + backward: what the caching allocator handed out
    beyond what was allocated before it."""
    values, cams = scene_for(cfg)
    values = values.to(device)
    forward_backward(values, cams, backend, stage2, gradient)  # warm-up: kernels loaded, workspaces made
    torch.cuda.synchronize(device)
    torch.cuda.reset_peak_memory_stats(device)
    before = torch.cuda.memory_allocated(device)
    forward_backward(values, cams, backend, stage2, gradient)
    return {"peak_mib": (torch.cuda.max_memory_allocated(device) - before) / 2**20,
            "method": "torch.cuda.max_memory_allocated"}


# ---------------------------------------------------------------------------- memory (subprocess)
def measure_memory(cfg: Config, backend: str, stage2: str, gradient: str) -> dict[str, float | str]:
    """Peak extra resident memory (MiB) of one forward + backward, in this (fresh) process."""
    import gc
    import resource

    values, cams = scene_for(cfg)
    forward_backward(values[:1].clone(), Cameras.look_at([[0.0, 0.0, 2.5]], image_size=8), backend, stage2,
                     gradient)
    gc.collect()
    before = reset_peak_rss()
    if before is not None:
        forward_backward(values, cams, backend, stage2, gradient)
        peak = peak_rss_kib()
        method = "VmHWM"
    else:
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        forward_backward(values, cams, backend, stage2, gradient)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        method = "ru_maxrss"
    return {"peak_mib": (peak - before) / 1024.0, "method": method}


def memory_in_subprocess(cfg: Config, backend: str, stage2: str, gradient: str, threads: int | None,
                         torch_threads: int | None = None) -> dict[str, float | str]:
    cmd = [sys.executable, "-m", "benchmarks.renderer_speed", "--memory-probe", f"{cfg.image},{cfg.batch},{cfg.grid}",
           f"{backend},{stage2},{gradient}"]
    if threads:
        cmd += ["--threads", str(threads)]
    if torch_threads is not None:
        cmd += ["--torch-threads", str(torch_threads)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------------- report
def _march_cells(cfg: Config, r: dict, digits: int) -> str:
    """A row's leading cells, shared by both wall-clock tables: config, rays, hits, the two march
    times (``digits`` decimals), the speed-up and the fused march's rays/s."""
    return (f"| {cfg.name} | {cfg.rays} | {100 * r['hit_fraction']:.0f}% | {r['march_reference']:.{digits}f} "
            f"| {r['march_fused']:.{digits}f} | {r['march_reference'] / r['march_fused']:.1f}x "
            f"| {cfg.rays / (r['march_fused'] / 1e3):.3g}")


def table(rows: list[tuple[Config, dict]]) -> str:
    """The wall-clock table (medians), with speed-ups and peak memory."""
    head = ("| config | rays | hits | march ref (ms) | march fused (ms) | march speed-up | fused rays/s "
            "| f+b reference (ms) | f+b fused march + PyTorch stage 2 (ms) | f+b fused (ms) | fused per image (ms) "
            "| f+b speed-up vs reference | fused f+b / fused march | f+b visibility gradient (ms) "
            "| visibility / fused f+b "
            "| peak mem f+b ref / fused march + PyTorch stage 2 / fused / visibility (MiB) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for cfg, r in rows:
        lines.append(
            _march_cells(cfg, r, 1) + f" | {r['render_reference']:.1f} | {r['render_fused_march']:.1f} "
            f"| {r['render_fused']:.1f} | {r['render_fused'] / cfg.batch:.2f} "
            f"| {r['render_reference'] / r['render_fused']:.1f}x | {r['render_fused'] / r['march_fused']:.2f} "
            f"| {r['render_visibility']:.1f} | {r['render_visibility'] / r['render_fused']:.2f} "
            f"| {r['mem_reference']:.0f} / {r['mem_fused_march']:.0f} / {r['mem_fused']:.0f} "
            f"/ {r['mem_visibility']:.0f} |")
    return "\n".join(lines)


def cuda_table(rows: list[tuple[Config, dict]]) -> str:
    """The GPU table: reference and fused kernels on CUDA, and the host's fused CPU kernels."""
    head = ("| config | rays | hits | march ref CUDA (ms) | march fused CUDA (ms) | speed-up | fused CUDA rays/s "
            "| march fused CPU (ms) | CUDA vs CPU | f+b ref CUDA (ms) | f+b fused march + PyTorch stage 2 CUDA (ms) "
            "| f+b fused CUDA (ms) | speed-up | fused f+b / fused march | f+b fused CPU (ms) | CUDA vs CPU "
            "| f+b visibility gradient CUDA (ms) "
            "| peak GPU mem f+b ref / fused march + PyTorch stage 2 / fused / visibility (MiB) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for cfg, r in rows:
        lines.append(
            _march_cells(cfg, r, 2) + f" | {r['march_host']:.1f} "
            f"| {r['march_host'] / r['march_fused']:.1f}x | {r['render_reference']:.2f} "
            f"| {r['render_fused_march']:.2f} | {r['render_fused']:.2f} "
            f"| {r['render_reference'] / r['render_fused']:.1f}x | {r['render_fused'] / r['march_fused']:.2f} "
            f"| {r['render_host']:.1f} | {r['render_host'] / r['render_fused']:.1f}x "
            f"| {r['render_visibility']:.2f} "
            f"| {r['mem_reference']:.0f} / {r['mem_fused_march']:.0f} / {r['mem_fused']:.0f} "
            f"/ {r['mem_visibility']:.0f} |")
    return "\n".join(lines)


def cpu_table(rows: list[tuple[Config, dict]]) -> str:
    """The same runs in CPU time (all threads of the process; medians): less sensitive to a busy
    machine than wall time, but blind to how well the work spreads over the cores."""
    head = ("| config | march ref (CPU ms) | march fused (CPU ms) | ratio | f+b reference (CPU ms) "
            "| f+b fused march + PyTorch stage 2 (CPU ms) | f+b fused (CPU ms) | ratio ref / fused "
            "| f+b visibility gradient (CPU ms) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for cfg, r in rows:
        lines.append(
            f"| {cfg.name} | {r['march_reference_cpu']:.1f} | {r['march_fused_cpu']:.1f} "
            f"| {r['march_reference_cpu'] / r['march_fused_cpu']:.1f}x | {r['render_reference_cpu']:.1f} "
            f"| {r['render_fused_march_cpu']:.1f} | {r['render_fused_cpu']:.1f} "
            f"| {r['render_reference_cpu'] / r['render_fused_cpu']:.1f}x | {r['render_visibility_cpu']:.1f} |")
    return "\n".join(lines)


def machine(device: torch.device = torch.device("cpu")) -> str:
    import numba

    def threads(n: int) -> str:
        return f"{n} thread{'s' if n != 1 else ''}"

    gpu = ""
    if device.type == "cuda":
        from importlib import metadata

        try:  # the NVIDIA package that numba's CUDA target now lives in; older numbas bundle it
            numba_cuda = f"numba-cuda {metadata.version('numba-cuda')}"
        except metadata.PackageNotFoundError:
            numba_cuda = "numba's bundled CUDA target"
        cc = torch.cuda.get_device_capability(device)
        gpu = (f"GPU {torch.cuda.get_device_name(device)} (compute capability {cc[0]}.{cc[1]}, "
               f"CUDA {torch.version.cuda}, {numba_cuda}), ")
    return (f"{gpu}{platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs, "
            f"torch {torch.__version__} ({threads(torch.get_num_threads())}), numba {numba.__version__} "
            f"({threads(numba.get_num_threads())}, {numba.threading_layer()} threading layer), "
            f"Python {platform.python_version()}")


DETAILS = """\
examples:
  python -m benchmarks.renderer_speed            # full run, writes docs/bench_renderer.md
  python -m benchmarks.renderer_speed --quick    # fewer repeats (a smoke run)
  python -m benchmarks.renderer_speed --threads 1 --out docs/bench_renderer_1thread.md
  python -m benchmarks.renderer_speed --device cuda   # on a GPU: writes docs/bench_renderer_cuda.md

threads:
  As users get them unless told otherwise: torch and numba each use every core (their defaults).
  --threads N sets both; --torch-threads torch's alone (0: its default).

scenes:
  B grids of 64^3 (a torus, its radii varied a little per grid), one camera per grid at distance
  2.5 from a random direction, 40 degree field of view (the torus fills part of the image), the
  default renderer.Scene() (silhouette, depth, normals, Lambert shading). Configs: 64^2 with
  B = 32, then 128^2 and 256^2 with B = 8.

what is timed (medians over the repeats, after one warm-up that also loads the compiled kernels):
  march        renderer.sphere_trace (ray generation + the no-gradient march) per backend
  render f+b   a render + a scalar loss over image, silhouette and depth + backward() into the
               grid values, four ways: render(backend="reference") (the PyTorch march and
               stage 2: the specification), the fused march with the PyTorch stage 2
               (sphere_trace + shade_trace(..., stage2="reference"): the pipeline before stage 2
               was fused), render with the fused kernels of both stages (the default),
               and render with Scene(gradient="visibility") (the fused march finding grazing
               points, then the PyTorch stage 2 with the edge term: the visibility gradient's cost)

--device cuda:
  Times the same calls on the GPU (the reference march on CUDA tensors against the fused CUDA
  kernel, each call ended by torch.cuda.synchronize()), adds the fused CPU march of the same host
  on the same scenes for the CUDA-vs-CPU ratio, and one larger config (512^2, B = 16) where the
  GPU has enough rays to fill it. Memory there is the peak extra GPU memory of one forward +
  backward (torch.cuda.max_memory_allocated), measured in the timing process.

memory (CPU):
  Each (config, march) runs once more in a fresh subprocess that builds the scene, warms up on a
  tiny image, resets the kernel's peak-RSS counter (/proc/self/clear_refs), runs one forward +
  backward and reports VmHWM - VmRSS before: the peak extra resident memory of that forward +
  backward (torch CPU tensors, numba buffers and all), in MiB. Where clear_refs is not available
  it falls back to the growth of ru_maxrss, which can under-report.
"""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, epilog=DETAILS,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="one timed repeat per measurement")
    parser.add_argument("--repeats", type=int, default=None, help="timed repeats per measurement (default 5)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="where the grids live: cpu (reference vs fused CPU march) or cuda (reference "
                             "on CUDA vs the fused CUDA march, plus the host's fused CPU march)")
    parser.add_argument("--out", type=Path, default=None,
                        help="markdown file for the table (default docs/bench_renderer.md, "
                             "docs/bench_renderer_cuda.md with --device cuda)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--threads", type=int, default=None, help="torch and numba threads (default: all)")
    parser.add_argument("--torch-threads", type=int, default=None,
                        help="torch threads (default: --threads if given, else torch's default; 0: torch's default)")
    parser.add_argument("--memory-probe", nargs=2, metavar=("IMAGE,BATCH,GRID", "BACKEND,STAGE2,GRADIENT"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.repeats is not None and args.repeats < 1:
        raise ValueError(f"--repeats must be at least 1, got {args.repeats}")
    if args.threads is not None:
        if args.threads < 1:
            raise ValueError(f"--threads must be at least 1, got {args.threads}")
        import numba

        torch.set_num_threads(args.threads)
        numba.set_num_threads(args.threads)
    if args.torch_threads is None:
        args.torch_threads = args.threads or 0
    if args.torch_threads < 0:
        raise ValueError(f"--torch-threads must be 0 (torch's default) or more, got {args.torch_threads}")
    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)
    if args.memory_probe:
        image, batch, grid = (int(x) for x in args.memory_probe[0].split(","))
        backend, stage2, gradient = args.memory_probe[1].split(",")
        print(json.dumps(measure_memory(Config(image, batch, grid), backend, stage2, gradient)))
        return
    device = torch.device(args.device)
    for backend in ("cpu", fused_backend(device)):
        ok, why = renderer.backend_available(backend)
        if not ok:
            raise SystemExit(f"--device {args.device}: the fused {backend} march is unavailable: {why}")
    repeats = args.repeats or (1 if args.quick else 5)
    load_before = os.getloadavg()
    rows = []
    for cfg in CUDA_CONFIGS if device.type == "cuda" else CONFIGS:
        print(f"timing {cfg.name} ...", file=sys.stderr, flush=True)
        row = time_config(cfg, repeats, device)
        for label, (backend, stage2, gradient) in render_variants(device).items():
            if device.type == "cuda":
                mem = measure_cuda_memory(cfg, backend, stage2, gradient, device)
            else:
                mem = memory_in_subprocess(cfg, backend, stage2, gradient, args.threads, args.torch_threads)
            row[f"mem_{label}"] = float(mem["peak_mib"])
            row["mem_method"] = mem["method"]
        rows.append((cfg, row))
    load_after = os.getloadavg()
    if device.type == "cuda":
        print(cuda_table(rows))
        if not args.no_write:
            write_cuda_report(args.out or ROOT / "docs" / "bench_renderer_cuda.md", rows, repeats, argv, device)
        return
    text = table(rows)
    text_cpu = cpu_table(rows)
    print(text + "\n\n" + text_cpu)
    print(f"load average (1 min) before/after: {load_before[0]:.1f} / {load_after[0]:.1f}", file=sys.stderr)
    if not args.no_write:
        args.out = args.out or ROOT / "docs" / "bench_renderer.md"
        method = rows[0][1]["mem_method"]
        command = _command(argv)
        doc = (
            "# Renderer benchmark\n\n"
            f"Made by `{command}` (medians of "
            f"{repeats} timed run{'s' if repeats > 1 else ''} after a warm-up; see the script's docstring "
            "for the scenes).\n\n"
            f"Machine: {machine()}; 1-minute load average {load_before[0]:.1f} before the run and "
            f"{load_after[0]:.1f} after it (the machine is shared: a load above its CPU count slows the "
            "reference, a long chain of small PyTorch ops, more than the fused kernels).\n\n"
            + text + "\n\n"
            "CPU time of the same calls (user + system, all threads of the process):\n\n"
            + text_cpu + "\n\n"
            "- march: `renderer.sphere_trace` (rays + the no-gradient march); ref = the vectorised-PyTorch "
            "reference (renderer/reference.py), fused = the numba CPU kernel (renderer/kernels/).\n"
            "- f+b: a render with the default Scene plus `backward()` into the grid values: reference = "
            "`render(backend=\"reference\")` (PyTorch march and stage 2), fused march + PyTorch stage 2 = "
            "the fused march with `shade_trace(stage2=\"reference\")` (the pipeline before stage 2 was "
            "fused), fused = `render()` with both stages fused (renderer/fused.py), the default; visibility "
            "gradient = `render()` with `Scene(gradient=\"visibility\")` (the fused march with grazing points, "
            "the PyTorch stage 2 with the edge term).\n"
            f"- peak mem: the peak extra resident memory of one forward + backward in a fresh process "
            f"({method}; see the script's docstring).\n"
        )
        write_text(args.out, doc)
        print(f"wrote {args.out}", file=sys.stderr)


def _command(argv: list[str] | None) -> str:
    return " ".join(["python -m benchmarks.renderer_speed", *(argv if argv is not None else sys.argv[1:])])


def write_cuda_report(path: Path, rows: list[tuple[Config, dict]], repeats: int, argv: list[str] | None,
                      device: torch.device) -> None:
    doc = (
        "# Renderer benchmark on a GPU\n\n"
        f"Made by `{_command(argv)}` (medians of {repeats} timed run{'s' if repeats > 1 else ''} after a "
        "warm-up, each call ended by `torch.cuda.synchronize()`; see the script's docstring for the scenes).\n\n"
        f"Machine: {machine(device)}.\n\n"
        + cuda_table(rows) + "\n\n"
        "- march: `renderer.sphere_trace` (rays + the no-gradient march): ref = the vectorised-PyTorch reference "
        "on CUDA tensors, fused CUDA = the numba CUDA kernel (renderer/kernels/), fused CPU = the numba CPU "
        "kernel on the same host's cores, on the same scenes.\n"
        "- f+b: a render with the default Scene plus `backward()` into the grid values: reference (PyTorch "
        "march and stage 2), the fused march with the PyTorch stage 2, and both stages fused (the default); "
        "fused CPU = both stages fused on the host's cores.\n"
        "- peak GPU mem: the peak extra GPU memory of one forward + backward (torch.cuda.max_memory_allocated "
        "beyond what was allocated before it).\n"
    )
    write_text(path, doc)
    print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    main()
