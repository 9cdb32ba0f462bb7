"""The single-view part of the accuracy-versus-time study: validation IoU against training time for
the model (tiny, small, pixel-aligned), the refiner (on/off), the supervised views per object, the
training render size and the decoder head's resolution (32^3 upsampled, or 64^3), one setting
changed from the default per run. Each run is ``svr.training.stages.train`` on configs/train.yaml
with hydra overrides: the procedural data of all 13 categories (generated once into
``<work>/svr_cache``), a fixed step budget (the coarse stage, then the refine stage; the joint stage
is left out), and the setting varied. One run gives two points: after its coarse stage (refiner off:
``stage.schedule=[coarse]`` trains exactly that stage) and after its refine stage (refiner on); each
is that stage's final checkpoint scored per validation object (``score_objects``), reported as the
mean over categories with a category-stratified bootstrap 95% interval over objects. A callback
(``StudyClock``) logs each validation's IoU and the time spent, so the training time excludes
validation and the plot shows each run's IoU over time. Run by
``python -m benchmarks.accuracy_vs_time --parts svr`` (``--docs DIR`` to keep docs/ as it is), which
runs ``python -m benchmarks.accuracy_vs_time_svr [--quick] [--steps COARSE,REFINE]``: the plot goes
to ``<docs>/study_svr.png`` and the section to ``<work>/sections/svr.md``, for the study's report.
"""
from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import pytorch_lightning as pl
from hydra.utils import instantiate

from benchmarks.common import (Point, bootstrap_means, fmt_value, parse_steps, progress_log, run_study_part,
                               study_folders, study_part_parser, timed, tradeoff_section)
import mvr
from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.settings import build_settings
from svr.data.procedural.generator import GENERATOR_VERSION
from svr.inference.prediction import load_model, predict_sdf
from svr.nmr.metrics import iou_direct
from svr.training.stages import train

QUICK_CATEGORIES = ("chair", "mug")
TRAIN_OBJECTS, VAL_OBJECTS = 8, 5  # per category (all 13 categories)
DEFAULT_STEPS, VAL_EVERY = (600, 300), 100  # (coarse, refine) steps per run; steps between validations


class StudyClock(pl.Callback):
    """Appends one JSON line per event to ``path``: ``start`` and ``end`` of each stage's training,
    and ``val`` after each validation (global step, its IoU ``val/iou``, and the wall and CPU
    seconds that validation took); every line carries ``wall`` (``time.time()``) and ``cpu``
    (``time.process_time()``) when it was written."""

    def __init__(self, path: str):
        if not path:
            raise ValueError("path must name the timeline file")
        self.path = Path(path)
        self._val_start: Optional[tuple[float, float]] = None

    def _write(self, trainer: pl.Trainer, pl_module: pl.LightningModule, event: str, **extra) -> None:
        line = {"event": event, "stage": getattr(pl_module, "stage", None), "step": int(trainer.global_step),
                "wall": time.time(), "cpu": time.process_time(), **extra}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a") as f:
            f.write(json.dumps(line) + "\n")

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._write(trainer, pl_module, "start")

    def on_validation_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._val_start = (time.time(), time.process_time())

    def on_validation_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if trainer.sanity_checking or self._val_start is None:
            return
        iou = trainer.callback_metrics.get("val/iou")
        self._write(trainer, pl_module, "val", iou=None if iou is None else float(iou),
                    val_wall=time.time() - self._val_start[0], val_cpu=time.process_time() - self._val_start[1])
        self._val_start = None

    def on_train_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._write(trainer, pl_module, "end")


@dataclass(frozen=True)
class Run:
    """One training run: its label, the setting it varies from the default (``axis``), the model
    config, views per object, training render size, the side of the decoder head's SDF grid (32:
    the model's own head, upsampled to its 64^3 grid; 64: ``HEAD_CHANNELS``' decoder, whose head
    makes the 64^3 grid itself), whether it is the default setting (its refine point is then the
    highlighted one), and ``coarse_only``: no refine stage, its steps given to the coarse stage
    instead (the refiner's time spent on more coarse training)."""

    label: str
    axis: str = "default"
    model: str = "small"
    views: int = 2
    render_size: int = 64
    head: int = 32
    default: bool = False
    coarse_only: bool = False

    def __post_init__(self) -> None:
        if not 1 <= self.views <= 24:
            raise ValueError(f"views must lie in 1..24, got {self.views!r}")
        if not 8 <= self.render_size <= 64:
            raise ValueError(f"render_size must lie in 8..64 (the data is 64^2), got {self.render_size!r}")
        if self.head not in HEAD_CHANNELS:
            raise ValueError(f"head must be one of {tuple(HEAD_CHANNELS)}, got {self.head!r}")


# Head side -> the decoder channels that make it (None: the model's own). With head_stride 2 the
# head's side is base_resolution (4) * 2**(len(channels) - 1) * 2, so four levels give 64.
HEAD_CHANNELS = {32: None, 64: (64, 32, 16, 8)}


def runs(quick: bool = False) -> tuple[Run, ...]:
    """The runs: the default (model=small, 2 views, 64^2 renders, 32^3 head, refiner on) and
    changes of one setting each."""
    if quick:
        return (Run("tiny 2v", model="tiny", render_size=16, default=True),
                Run("tiny 2v coarse-only", "refiner", model="tiny", render_size=16, coarse_only=True))
    return (Run("small 2v", default=True), Run("small 2v coarse-only", "refiner", coarse_only=True),
            Run("tiny 2v", "model", model="tiny"), Run("pixel 2v", "model", model="pixel"),
            Run("small 1v", "views", views=1), Run("small 4v", "views", views=4), Run("small 8v", "views", views=8),
            Run("small 2v r16", "render size", render_size=16), Run("small 2v r32", "render size", render_size=32),
            Run("small 2v h64", "head", head=64))


def data_overrides(cache: Path, quick: bool) -> list[str]:
    """The procedural dataset (the same for every run): all 13 categories (two with ``quick``)."""
    cats = [f"data.categories=[{','.join(QUICK_CATEGORIES)}]"] if quick else []
    sizes = ("data.train=2", "data.val=2") if quick else (f"data.train={TRAIN_OBJECTS}", f"data.val={VAL_OBJECTS}")
    return [f"data.cache_dir={cache}", *cats, *sizes, "data.test=0", "data.supersample=1",
            f"data.batch_size={2 if quick else 8}", "data.eval_batch_size=32",
            f"data.val_views=[{','.join(map(str, val_views(quick)))}]", "data.progress=false"]


def val_views(quick: bool) -> tuple[int, ...]:
    """The views of each validation object that are scored."""
    return (0, 12) if quick else (0, 6, 12, 18)


def run_overrides(run: Run, data: Sequence[str], steps: tuple[int, int], val_every: int, clock: Path,
                  quick: bool) -> list[str]:
    """configs/train.yaml overrides of one run: data, model, views, render size, head, step budget,
    quiet trainer, the clock callback, and a shorter march with ``quick``."""
    if min(steps) < 1 or val_every < 1:
        raise ValueError(f"steps and val_every must be positive, got {steps!r}, {val_every!r}")
    toy = ["loss.trace.max_steps=64"] if quick else []
    channels = HEAD_CHANNELS[run.head]
    head = [f"model.decoder.channels=[{','.join(map(str, channels))}]"] if channels else []
    stages = (["stage.schedule=[coarse]", f"stage.coarse.max_steps={sum(steps)}"] if run.coarse_only else
              ["stage.schedule=[coarse,refine]", f"stage.coarse.max_steps={steps[0]}",
               f"stage.refine.max_steps={steps[1]}"])
    return [*data, f"model={run.model}", *head, f"data.views_per_sample={run.views}",
            f"loss.render_size={run.render_size}", *stages,
            f"trainer.val_check_interval={val_every}", "trainer.log_every_n_steps=10",
            "trainer.enable_progress_bar=false", "trainer.enable_model_summary=false", "logger=csv",
            "callbacks.progress_bar=null", "callbacks.image_logger=null", "callbacks.last_checkpoint=null",
            "callbacks.lr_monitor=null", "+callbacks.study_clock._target_=benchmarks.accuracy_vs_time_svr.StudyClock",
            f"+callbacks.study_clock.path={clock}", *toy]


def compose_train(overrides: Sequence[str]):
    """configs/train.yaml composed with overrides, outside a hydra run."""
    return compose("train", overrides)


def read_timeline(path: Path, start_wall: float, start_cpu: float) -> list[dict]:
    """The clock's events with ``train_cpu``/``train_wall``: seconds since the run started, less
    the validations before (and including) the event."""
    events, val_cpu, val_wall = [], 0.0, 0.0
    for line in path.read_text().splitlines():
        e = json.loads(line)
        val_cpu += e.get("val_cpu", 0.0)
        val_wall += e.get("val_wall", 0.0)
        e["train_cpu"] = e["cpu"] - start_cpu - val_cpu
        e["train_wall"] = e["wall"] - start_wall - val_wall
        e["val_cpu_total"] = val_cpu
        events.append(e)
    return events


@dataclass(frozen=True)
class ObjectScores:
    """A checkpoint's scores on the validation objects: ``category`` (O,) int64 category index of
    each object and ``iou`` (O,) float64 its mean direct voxel IoU over the scored views."""

    category: np.ndarray
    iou: np.ndarray

    def benchmark_mean(self) -> tuple[float, tuple[float, float]]:
        """The mean over categories of the per-category mean IoU, and its 95% interval
        (``benchmarks.common.bootstrap_means``: objects resampled within each category)."""
        means = [self.iou[self.category == c].mean() for c in np.unique(self.category)]
        return float(np.mean(means)), bootstrap_means(self.iou, self.category)[1]


def score_objects(checkpoint: Path, datamodule) -> ObjectScores:
    """Scores a checkpoint on every validation object of ``datamodule`` (its ``val_dataloader``:
    the ``val_views`` of each object): per image the direct voxel IoU
    (``svr.nmr.metrics.iou_direct``, level 0, as ``val/iou``) of the prediction from that
    view (``predict_sdf`` with its view index), then the mean over each object's views."""
    model = load_model(checkpoint, device="cpu")
    hs = model.half_side
    ious, keys = [], []
    for batch in datamodule.val_dataloader():
        pred = predict_sdf(model, batch.images[:, 0], batch_size=len(batch), views=batch.view_ids[:, 0])
        ious.append(iou_direct(pred.final, batch.voxels, -hs, hs).numpy())
        keys.append(np.stack([batch.category.numpy(), batch.object_index.numpy()], 1))
    objects, index = np.unique(np.concatenate(keys), axis=0, return_inverse=True)
    index = index.reshape(-1)
    iou = np.bincount(index, weights=np.concatenate(ious)) / np.bincount(index)
    return ObjectScores(category=objects[:, 0].astype(np.int64), iou=iou.astype(np.float64))


def warm_up(run: Run, work: Path, data: Sequence[str], quick: bool) -> None:
    """Trains ``run`` for one step per stage, untimed, and deletes it: the first timed run then
    does not pay for compiling (or loading) the renderer's kernels and the libraries' first calls."""
    run_dir = work / "svr" / "warm-up"
    shutil.rmtree(run_dir, ignore_errors=True)
    train(build_settings(compose_train(run_overrides(run, data, (1, 1), 1, run_dir / "timeline.jsonl", quick))),
          run_dir)
    shutil.rmtree(run_dir)


def measure(run: Run, work: Path, data: Sequence[str], datamodule, steps: tuple[int, int], val_every: int,
            quick: bool) -> tuple[list[Point], list[tuple[float, float]]]:
    """Trains one run afresh; a Point per stage (after coarse, after refine; seconds: training CPU
    seconds without validation; error: 1 - the benchmark mean of the stage's final checkpoint on
    the validation objects, ``score_objects``, with its 95% interval) and its curve of (training
    CPU seconds, 1 - ``val/iou``) at each validation."""
    run_dir = work / "svr" / run.label.replace(" ", "_")
    if run_dir.exists():
        shutil.rmtree(run_dir)  # a fresh run: no resumed stage, no old timeline
    clock = run_dir / "timeline.jsonl"
    cfg = compose_train(run_overrides(run, data, steps, val_every, clock, quick))
    start_wall, start_cpu = time.time(), time.process_time()
    t = timed(lambda: train(build_settings(cfg), run_dir))
    events = read_timeline(clock, start_wall, start_cpu)
    ends = {e["stage"]: e for e in events if e["event"] == "end"}
    curve = [(e["train_cpu"], 1.0 - e["iou"]) for e in events if e["event"] == "val" and e["iou"] is not None]
    points = []
    for stage_result in t.result.stages:
        end = ends[stage_result.stage]
        # The final weights, not the best validation's: the validation objects choose no checkpoint.
        scores = score_objects(stage_result.final, datamodule)
        iou, (lo, hi) = scores.benchmark_mean()
        refine = stage_result.stage == "refine"
        label = run.label + (" +ref" if refine else "")
        points.append(Point(label, end["train_cpu"], 1.0 - iou, default=run.default and refine,
                            error_interval=(1.0 - hi, 1.0 - lo), extra={
                                "iou": iou, "iou_interval": (lo, hi), "objects": len(scores.iou),
                                "train_cpu_s": end["train_cpu"], "val_cpu_s": end["val_cpu_total"],
                                "wall_s": end["wall"] - start_wall, "load": t.load, "run": run.label,
                                "axis": run.axis, "stage": stage_result.stage,
                                "stages": "coarse+refine" if refine else "coarse",
                                "steps": int(end["step"]) + (steps[0] if refine else 0)}))
    return points, curve


COLUMNS = (("val IoU", "iou"), ("95% interval", "iou_interval"), ("training CPU s", "train_cpu_s"),
           ("validation CPU s", "val_cpu_s"), ("wall s (all)", "wall_s"), ("load", "load"), ("varies", "axis"),
           ("stages", "stages"), ("steps", "steps"))


def overlaps(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Whether two (low, high) intervals share a value."""
    return a[0] <= b[1] and b[0] <= a[1]


def compare(p: Point, ref: Point) -> str:
    """``p`` against ``ref`` in words: IoU with interval, time, the difference and whether the
    95% intervals resolve it (they do not where they overlap)."""
    diff = p.extra["iou"] - ref.extra["iou"]
    resolved = not overlaps(p.extra["iou_interval"], ref.extra["iou_interval"])
    verdict = (f"{'higher' if diff > 0 else 'lower'}, resolved (the intervals do not overlap)" if resolved else
               "not resolved (the intervals overlap)")
    return (f"{p.label} {describe(p)} ({p.seconds / ref.seconds:.2f}x the time): {diff:+.3f}, {verdict}")


def describe(p: Point) -> str:
    """``p``'s val IoU with its interval and its training time, in words."""
    lo, hi = p.extra["iou_interval"]
    return f"{p.extra['iou']:.3f} [{lo:.3f}, {hi:.3f}] in {fmt_value(p.seconds)} s"


def choice(points: Sequence[Point]) -> str:
    """The section's reading, computed from the points: each one-setting change against the default
    (refine points against its refine point; the refiner as the default's coarse point and the
    coarse-only run), what the 95% intervals resolve, and what each change costs in time."""
    ref = next(p for p in points if p.default)
    coarse = next(p for p in points if p.extra["run"] == ref.extra["run"] and p.extra["stage"] == "coarse")
    others = [p for p in points if p.extra["run"] != ref.extra["run"]
              and (p.extra["stage"] == "refine" or p.extra["axis"] == "refiner")]
    text = [f"Against the default, {ref.label} (val IoU {describe(ref)} of training), each change of one "
            f"setting: its refine point against the default's (for the refiner: the default's coarse point, "
            f"refiner off, and the coarse-only run):"]
    resolved = []
    for axis in dict.fromkeys(["refiner", *(p.extra["axis"] for p in others)]):
        group = ([coarse] if axis == "refiner" else []) + [p for p in others if p.extra["axis"] == axis]
        text.append(f"*{axis}*: " + "; ".join(compare(p, ref) for p in group) + ".")
        resolved += [p.label for p in group if not overlaps(p.extra["iou_interval"], ref.extra["iou_interval"])]
    objects = ref.extra["objects"]
    text.append((f"Only {', '.join(resolved)} {'differs' if len(resolved) == 1 else 'differ'} from the default by more "
                 f"than the intervals" if resolved else "No change differs from the default by more than the intervals")
                + f" ({objects} validation objects); the other differences are not resolved at this budget, "
                  f"whichever way their means lie.")
    return " ".join(text)


def run(out_dir: Path, work: Path, quick: bool = False, steps: Optional[tuple[int, int]] = None,
        progress: bool = True, prefix: str = "study_svr") -> str:
    """Generates the dataset (once), trains every run, scores its stages' checkpoints per object,
    writes ``<out_dir>/<prefix>.png`` and returns the report's markdown section.

    Args:
        steps: (coarse, refine) steps per run; default ``DEFAULT_STEPS``, or (2, 2) with ``quick``.
    """
    steps = steps or ((2, 2) if quick else DEFAULT_STEPS)
    val_every = 2 if quick else VAL_EVERY
    log = progress_log(progress)
    for name in ("pytorch_lightning", "lightning", "lightning.pytorch", "lightning_fabric"):
        logging.getLogger(name).setLevel(logging.ERROR)
    data = data_overrides((work / "svr_cache").resolve(), quick)
    log("svr: dataset")
    datamodule = instantiate(compose_train(data).data)
    datamodule.prepare_data()
    d = next(r for r in runs(quick) if r.default)
    log("svr: warm-up")
    warm_up(d, work, data, quick)
    points, curves = [], {}
    for r in runs(quick):
        log(f"svr: {r.label}")
        pts, curves[r.label] = measure(r, work, data, datamodule, steps, val_every, quick)
        points += pts
    cats = [n for _, n in datamodule.categories]
    axes: dict[str, list[str]] = {}
    for r in runs(quick):
        if not r.default:
            axes.setdefault(r.axis, []).append(r.label)
    variants = "; ".join(f"*{axis}*: {', '.join(labels)}" for axis, labels in axes.items())
    train_n, val_n = (2, 2) if quick else (TRAIN_OBJECTS, VAL_OBJECTS)
    views = val_views(quick)
    intro = (
        f"`svr.training.stages.train` (configs/train.yaml) on the procedural data (generator version "
        f"{GENERATOR_VERSION}): {len(cats)} categories ({', '.join(cats)}), {train_n} training and {val_n} "
        f"validation objects per category, 24 views each, `data.supersample=1`, batch of {2 if quick else 8} "
        f"objects (made once and cached; not counted). Every run: {steps[0]} coarse steps then {steps[1]} refine "
        f"steps (the stages' default optimisers; the joint stage left out; one untimed step of each first, so "
        f"that no run pays for compiling the renderer's kernels), validation every {val_every} steps. "
        f"The default is {d.label} (`model={d.model}`, `data.views_per_sample={d.views}`, "
        f"`loss.render_size={d.render_size}`, the decoder's {d.head}^3 head) with the refiner; each other run changes "
        f"one setting: {variants}. Labels: the model (`model=tiny`, `small`, or `pixel`: the pixel-aligned head), "
        f"*Nv*: `data.views_per_sample=N`, *rN*: `loss.render_size=N`, *h64*: "
        f"`model.decoder.channels=[{','.join(map(str, HEAD_CHANNELS[64]))}]`, a 64^3 head that makes the 64^3 grid "
        f"itself instead of the 32^3 head upsampled to it. Each run "
        f"gives two points: after its coarse stage (*refiner off*; `stage.schedule=[coarse]` trains exactly "
        f"that) and after its refine stage (*+ref*); *coarse-only* gives the refine stage's steps to the coarse "
        f"stage instead. Score: each stage's final checkpoint on the {len(cats) * val_n} validation objects, per "
        f"object the mean direct voxel IoU (`iou_direct`, as `val/iou`) of its predictions from views "
        f"{', '.join(map(str, views))}; *val IoU* is the mean over categories of the per-category means, with a "
        f"95% bootstrap interval over objects resampled within each category "
        f"(`benchmarks.common.bootstrap_means`). Error: 1 - val IoU (error bars: the interval); time: "
        f"training CPU seconds (1 thread) without the validations; the grey lines are each run's validations "
        f"(`val/iou`) over time. A difference counts as resolved only where the two intervals do not overlap. "
        f"At this budget the networks are early in training, so the IoUs are low. A longer budget: "
        f"`python -m benchmarks.accuracy_vs_time --parts svr --svr-steps 2000,500`.")
    section = tradeoff_section(
        points, COLUMNS, out_dir / f"{prefix}.png", title="Single-view reconstruction: validation IoU against "
        "training time", setting_name="setting", xlabel="training CPU seconds (without validation)",
        ylabel="1 - val IoU (95% interval)", unit="s", error_name="1 - IoU", logx=True, logy=False, curves=curves,
        choice=choice(points), figsize=(8.0, 5.6))
    return "\n".join(["## Single-view reconstruction", "", intro, "", section])


def main(argv: Optional[list[str]] = None) -> None:
    ap = study_part_parser(__doc__)
    ap.add_argument("--steps", default=None, help="coarse,refine training steps per run (default "
                    f"{','.join(map(str, DEFAULT_STEPS))}; 2,2 with --quick)")
    args = ap.parse_args(argv)
    try:
        steps = parse_steps(args.steps)
    except ValueError as exc:
        ap.error(str(exc))
    docs, work = study_folders(args.quick, args.docs, args.work)
    mvr.configure_runtime(threads=args.threads)
    run_study_part("svr", lambda: run(docs, work, quick=args.quick, steps=steps, progress=not args.no_progress),
                   work, args.quick)


if __name__ == "__main__":
    main()
