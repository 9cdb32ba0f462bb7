"""One single-view training step, phase by phase (where the time and the memory of a step go), run
as ``python -m benchmarks.train_step_speed [OVERRIDE ...] [--device cpu|cuda] [--baseline PATH]``
and written to docs/bench_train_step.md (docs/bench_train_step_cuda.md on CUDA). The positional
arguments are hydra overrides of ``configs/train.yaml`` (default ``experiment=demo``); the data
module, network and loss are built from that config exactly as ``train.py`` builds them, and one
training batch of it is used throughout (the procedural data is generated first if needed). Each
phase (data, encoder, decoder, refiner, render, regularisers, optimiser, and a whole step of each
stage) is timed alone, the median over ``--repeats`` after one warm-up, with its peak memory;
``--baseline PATH`` measures another checkout in the same run for a before/after ratio.
``--help`` lists the phases and how memory is measured.
"""
from __future__ import annotations

import argparse
import gc
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable, Optional

import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

import svr
from benchmarks.common import atomic_write_text, machine_info, peak_rss_kib, reset_peak_rss
from sdfcommon.tooling.host_memory import keep_freed_memory
from sdfcommon.tooling.settings import build_settings
from svr import losses
from svr.models.checkpoint_layout import STAGES
from svr.training.stages import build_module, fill_shape_prior, resolve_model

ROOT = Path(__file__).resolve().parents[1]
# The configs of the checkout measured, beside its svr package: run in a --baseline checkout, that
# checkout's own (the installed configs package, sdfdiff_configs, is the installed checkout's).
CONFIGS = Path(svr.__file__).resolve().parents[1] / "configs"

PHASES = ("data", "prior", "encoder", "decoder", "refiner", "render", "regularisers", "optimiser")
STAGE_STEPS = tuple(f"step {stage}" for stage in STAGES)


# ---------------------------------------------------------------------------- measuring (one process)
def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def measure_time(fn: Callable[[], None], repeats: int, device: torch.device) -> float:
    """Median wall ms of ``fn`` over ``repeats`` calls after one warm-up call."""
    fn()
    _sync(device)
    times = []
    for _ in range(repeats):
        _sync(device)
        t0 = time.perf_counter()
        fn()
        _sync(device)
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def measure_memory(fn: Callable[[], None], device: torch.device) -> float:
    """Peak extra memory (MiB) of one call of ``fn`` after a warm-up call: CUDA's peak allocated
    memory, or on the CPU the peak resident set (VmHWM reset through /proc/self/clear_refs; NaN
    where that is not available). Meaningful on the CPU only while freed memory goes back to the
    system (glibc's defaults): measured before ``keep_freed_memory``."""
    fn()
    _sync(device)
    gc.collect()
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
        before = torch.cuda.memory_allocated(device)
        fn()
        _sync(device)
        return (torch.cuda.max_memory_allocated(device) - before) / 2**20
    before = reset_peak_rss()
    if before is None:
        return float("nan")
    fn()
    after = peak_rss_kib()
    return float("nan") if after is None else (after - before) / 1024.0


def run_phases(overrides: list[str], device_name: str, repeats: int, stages: bool = True) -> dict:
    """Every phase of ``PHASES`` (and the stages' whole steps) for the composed config, in this process."""
    device = torch.device(device_name)
    with initialize_config_dir(config_dir=str(CONFIGS), version_base=None):
        cfg = compose(config_name="train", overrides=list(overrides))
    torch.manual_seed(int(cfg.seed))
    dm = instantiate(cfg.data)
    dm.prepare_data()
    dm.setup("fit")
    loader = dm.train_dataloader()
    it = iter(loader)
    batch = next(it).to(device)
    # The network as training builds it: a pixel head's mirror_axis "auto" measured on the split,
    # the camera head's elevation "auto" from the data's extra views.
    settings = resolve_model(build_settings(cfg), dm)
    net = instantiate(settings.model)
    fill_shape_prior(net, dm)
    net = net.to(device)
    module = build_module(settings, net, "joint", dm).to(device)
    module.train()
    images = batch.images[:, 0]
    hs, h = net.half_side, net.voxel_size
    w = module.loss_weights
    with torch.no_grad():
        latent0 = net.encoder(images)
        coarse0 = net.decoder(latent0)
    g_latent = torch.randn_like(latent0)
    g_grid = torch.randn_like(coarse0) * 1e-3

    def data() -> None:
        nonlocal it
        try:
            next(it)
        except StopIteration:
            it = iter(loader)
            next(it)

    exclude = net.prior.exclusion(batch.category, batch.object_index) if net.prior is not None else None

    def prior() -> None:
        with torch.no_grad():
            net.shape_prior(images, batch.views[:, 0], exclude)

    def encoder() -> None:
        net.zero_grad(set_to_none=True)
        (net.encoder(images) * g_latent).sum().backward()

    def decoder() -> None:
        net.zero_grad(set_to_none=True)
        (net.decoder(latent0) * g_grid).sum().backward()

    def refiner() -> None:
        net.zero_grad(set_to_none=True)
        (net.refiner(coarse0) * g_grid).sum().backward()

    def render() -> None:
        sdf = coarse0.clone().requires_grad_(True)
        img = losses.image_loss(sdf, hs, batch.images, batch.view_ids, module.scene, module.render_size,
                                w.silhouette_kind, module.trace_settings, module.backend)
        total = w.silhouette * img.silhouette + (w.shading * img.shading if img.shading is not None else 0.0)
        total.backward()

    def regularisers() -> None:
        sdf = coarse0.clone().requires_grad_(True)
        (w.eikonal * losses.eikonal_loss(sdf, h, w.band_mu)
         + w.laplacian * losses.laplacian_loss(sdf, h, w.band_mu)).backward()

    params = [p for p in net.parameters()]
    for p in params:
        p.grad = torch.zeros_like(p)
    opt = module.optimizer_factory(params)

    def optimiser() -> None:
        opt.step()

    fns = dict(data=data, encoder=encoder, decoder=decoder, refiner=refiner, render=render,
               regularisers=regularisers, optimiser=optimiser)
    if net.prior is not None:
        fns["prior"] = prior
    if stages:
        for stage in STAGES:
            mod = build_module(settings, net, stage, dm).to(device)
            mod.train()
            stage_opt = mod.optimizer_factory([p for p in mod.parameters() if p.requires_grad])

            def step(mod=mod, stage_opt=stage_opt) -> None:
                stage_opt.zero_grad(set_to_none=True)
                mod.training_step(batch, 0).backward()
                stage_opt.step()

            fns[f"step {stage}"] = step
    results: dict[str, dict[str, float]] = {name: {"peak_mib": measure_memory(fn, device)} for name, fn in fns.items()}
    # What svr.training.stages.train does first: the times are a training's, the memory above is not.
    allocator = "keep_freed_memory" if keep_freed_memory() else "glibc defaults"
    for name, fn in fns.items():
        results[name]["ms"] = measure_time(fn, repeats, device)
        if name.startswith("step "):
            results[name]["images_per_s"] = len(batch) / (results[name]["ms"] / 1e3)
    n_params = {k: sum(p.numel() for p in getattr(net, k).parameters()) for k in ("encoder", "decoder", "refiner")}
    return {"phases": results, "batch": len(batch), "views": int(batch.images.shape[1]),
            "render_size": module.render_size, "grid": net.grid_resolution, "params": n_params,
            "torch_threads": torch.get_num_threads(), "allocator": allocator,
            "device": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"}


# ---------------------------------------------------------------------------- report
def _ms(r: dict) -> str:
    return f"{r['ms']:.1f}"


def _mib(r: dict) -> str:
    v = r.get("peak_mib", float("nan"))
    return "n/a" if v != v else f"{v:.0f}"


def table(res: dict) -> str:
    lines = ["| phase | ms (median) | peak MiB | images/s |", "|---|---:|---:|---:|"]
    for name in tuple(s for s in PHASES + STAGE_STEPS if s in res["phases"]):
        r = res["phases"][name]
        ips = f"{r['images_per_s']:.1f}" if "images_per_s" in r else ""
        lines.append(f"| {name} | {_ms(r)} | {_mib(r)} | {ips} |")
    return "\n".join(lines)


def compare_table(before: dict, after: dict) -> str:
    lines = ["| phase | before ms | after ms | speed-up | before MiB | after MiB |",
             "|---|---:|---:|---:|---:|---:|"]
    for name in PHASES + STAGE_STEPS:
        b, a = before["phases"].get(name), after["phases"].get(name)
        if b is None or a is None:
            continue
        lines.append(f"| {name} | {_ms(b)} | {_ms(a)} | {b['ms'] / a['ms']:.2f}x | {_mib(b)} | {_mib(a)} |")
    return "\n".join(lines)


def _setup_line(res: dict) -> str:
    p = res["params"]
    return (f"batch {res['batch']}, {res['views']} views, renders {res['render_size']}^2, grid {res['grid']}^3, "
            f"parameters: encoder {p['encoder']:,}, decoder {p['decoder']:,}, refiner {p['refiner']:,}; "
            f"torch threads {res['torch_threads']}, device {res['device']}, host allocator: "
            f"{res['allocator']}")


def _merge(runs: list[dict]) -> dict:
    """Per phase, the median over the rounds' medians (memory: the median too)."""
    out = dict(runs[0])
    out["phases"] = {}
    for name in runs[0]["phases"]:
        rows = [r["phases"][name] for r in runs]
        merged = {k: statistics.median([row[k] for row in rows]) for k in rows[0]}
        out["phases"][name] = merged
    return out


def measure_checkout(code: Path, overrides: list[str], device: str, repeats: int) -> dict:
    """``run_phases`` in a fresh process of the checkout at ``code``: its own copy of this benchmark
    (``python -m benchmarks.train_step_speed --json`` run in that folder, which imports that
    checkout's svr, renderer and configs before the installed ones)."""
    cmd = [sys.executable, "-m", "benchmarks.train_step_speed", "--json", "--device", device,
           "--repeats", str(repeats), *overrides]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=code)
    return json.loads(out.stdout.strip().splitlines()[-1])


DETAILS = """\
examples:
  python -m benchmarks.train_step_speed                          # experiment=demo, writes docs/bench_train_step.md
  python -m benchmarks.train_step_speed model=paper data.batch_size=8 --no-write
  python -m benchmarks.train_step_speed --device cuda            # on a GPU: docs/bench_train_step_cuda.md
  python -m benchmarks.train_step_speed --baseline ../old-checkout   # before/after, same run

phases (each timed alone, median over --repeats after one warm-up; CUDA calls are synchronised):
  data           one batch from the training data loader (its worker processes included, as
                 training sees it)
  prior          the shape prior's lookup for the batch's inputs (model=pixel_prior only): the
                 training objects whose silhouettes look most like each input, and their hulls
  encoder / decoder / refiner
                 forward + backward of that module alone (weights' gradients; the refiner's input
                 is the decoder's output, detached, as in the refine stage)
  render         the image loss (sphere tracing, differentiable shading, silhouette and colour
                 terms) forward + backward into the grid values
  regularisers   the narrow-band eikonal + Laplacian terms forward + backward into the grid values
  optimiser      one step of the stage optimiser over the joint stage's parameters
  step <stage>   a whole training step of each stage as the LightningModule runs it (forward,
                 loss, backward, optimiser step) on the same batch; images/s = batch size / step time

memory:
  On CUDA the peak allocated memory of each phase (torch.cuda.max_memory_allocated); on the CPU
  the peak extra resident memory of one call (VmHWM after resetting it through
  /proc/self/clear_refs; "n/a" where that is not available).

--baseline PATH:
  Runs the same measurements with the code and configs of another checkout of this layout (e.g. a
  git worktree of main before a change), each checkout by its own copy of this benchmark, in
  alternating subprocesses (--rounds each) and reports both and their ratio: a speed claim against
  a baseline measured in the same run.
"""


def main(argv: Optional[list[str]] = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__, epilog=DETAILS,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("overrides", nargs="*", help="hydra overrides of configs/train.yaml (default: experiment=demo)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per phase (default 5)")
    parser.add_argument("--rounds", type=int, default=2, help="with --baseline: alternating runs of each checkout")
    parser.add_argument("--baseline", type=Path, default=None, help="another checkout to measure in the same run")
    parser.add_argument("--out", type=Path, default=None, help="report path (default docs/bench_train_step[_cuda].md)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    if args.rounds < 1:
        parser.error(f"--rounds must be >= 1, got {args.rounds}")
    overrides = args.overrides or ["experiment=demo"]
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: no CUDA device is visible to torch")
    if args.json:
        print(json.dumps(run_phases(overrides, args.device, args.repeats)))
        return
    if args.baseline is not None:
        base = args.baseline.resolve()
        if not all((base / part).is_file() for part in ("svr/__init__.py", "configs/train.yaml",
                                                          "benchmarks/train_step_speed.py")):
            parser.error(f"--baseline {base}: not a checkout of this project's layout (no svr/, "
                         "configs/train.yaml and benchmarks/train_step_speed.py)")
        before_runs, after_runs = [], []
        for r in range(args.rounds):
            print(f"round {r + 1}/{args.rounds}: baseline {base}", file=sys.stderr, flush=True)
            before_runs.append(measure_checkout(base, overrides, args.device, args.repeats))
            print(f"round {r + 1}/{args.rounds}: this checkout", file=sys.stderr, flush=True)
            after_runs.append(measure_checkout(ROOT, overrides, args.device, args.repeats))
        before, after = _merge(before_runs), _merge(after_runs)
        body = (f"Before: `{base}` ({_git_rev(base)}); {_setup_line(before)}.\n\n"
                f"After: this checkout ({_git_rev(ROOT)}); {_setup_line(after)}.\n\n"
                f"{compare_table(before, after)}\n")
    else:
        res = run_phases(overrides, args.device, args.repeats)
        body = f"{_setup_line(res)}.\n\n{table(res)}\n"
    command = "python -m benchmarks.train_step_speed " + " ".join(argv)
    text = (f"# Single-view training step, phase by phase\n\n`{command.strip()}` "
            f"(config overrides: `{' '.join(overrides)}`; medians of {args.repeats} calls"
            + (f", median over {args.rounds} alternating rounds per checkout" if args.baseline else "")
            + f"; written {time.strftime('%Y-%m-%d %H:%M')}).\n\n{body}\n{machine_info()}\n")
    print(text)
    if not args.no_write:
        out = args.out or ROOT / "docs" / ("bench_train_step_cuda.md" if args.device == "cuda" else "bench_train_step.md")
        atomic_write_text(out, text)
        print(f"wrote {out}", file=sys.stderr)


def _git_rev(path: Path) -> str:
    try:
        return subprocess.run(["git", "-C", str(path), "rev-parse", "--short", "HEAD"], check=True,
                              capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "not a git checkout"


if __name__ == "__main__":
    main()
