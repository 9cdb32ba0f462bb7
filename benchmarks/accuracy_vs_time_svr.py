"""The single-view part of the accuracy-versus-time study: validation IoU against training time for
the model width, the refiner (on/off) and the number of supervised views per object. Each run is
``svr.training.stages.train`` on configs/train.yaml with hydra overrides: a small procedural dataset
(generated once into ``<work>/svr_cache``), a fixed step budget (the coarse stage, then the refine
stage; the joint stage is left out), and the setting varied. One run gives two points: after its
coarse stage (refiner off: ``stage.schedule=[coarse]`` trains exactly that stage) and after its
refine stage (refiner on). A callback (``StudyClock``) logs each validation's IoU and the time
spent, so the training time excludes validation and the plot shows each run's IoU over time. Run by
``python -m benchmarks.accuracy_vs_time --parts svr`` (``--docs DIR`` to keep docs/ as it is).
"""
from __future__ import annotations

import json
import logging
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import pytorch_lightning as pl
from hydra.utils import instantiate

from benchmarks.report import Point, progress_log, timed, tradeoff_section
from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.settings import build_settings
from svr.data.procedural.generator import GENERATOR_VERSION
from svr.training.stages import train

CATEGORIES = ("chair", "table", "airplane", "mug")
QUICK_CATEGORIES = ("chair", "mug")


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
    """One training run: its label, the model config and views per object, whether it is the
    default setting (its refine point is then the highlighted one), and ``coarse_only``: no refine
    stage, its steps given to the coarse stage instead (the refiner's time spent on more coarse
    training)."""

    label: str
    model: str = "small"
    views: int = 2
    default: bool = False
    coarse_only: bool = False

    def __post_init__(self) -> None:
        if not 1 <= self.views <= 24:
            raise ValueError(f"views must lie in 1..24, got {self.views!r}")


def runs(quick: bool = False) -> tuple[Run, ...]:
    """The runs: the default (model=small, 2 views) and one-setting changes of it."""
    if quick:
        return (Run("tiny 2v", "tiny", 2, default=True), Run("tiny 1v coarse-only", "tiny", 1, coarse_only=True))
    return (Run("small 2v", "small", 2, default=True), Run("small 2v coarse-only", "small", 2, coarse_only=True),
            Run("tiny 2v", "tiny", 2), Run("small 1v", "small", 1), Run("small 4v", "small", 4))


def data_overrides(cache: Path, quick: bool) -> list[str]:
    """The small procedural dataset (the same for every run)."""
    cats = QUICK_CATEGORIES if quick else CATEGORIES
    sizes = ("data.train=2", "data.val=1", "data.test=1") if quick else ("data.train=8", "data.val=2", "data.test=1")
    return [f"data.cache_dir={cache}", f"data.categories=[{','.join(cats)}]", *sizes, "data.supersample=1",
            f"data.batch_size={2 if quick else 8}", "data.eval_batch_size=32",
            f"data.val_views={'[0,12]' if quick else '[0,6,12,18]'}", "data.progress=false"]


def run_overrides(run: Run, data: Sequence[str], steps: tuple[int, int], val_every: int, clock: Path,
                  quick: bool) -> list[str]:
    """configs/train.yaml overrides of one run: data, model, views, step budget, quiet trainer,
    the clock callback, and the toy renderer settings with ``quick``."""
    if min(steps) < 1 or val_every < 1:
        raise ValueError(f"steps and val_every must be positive, got {steps!r}, {val_every!r}")
    toy = ["loss.render_size=16", "loss.trace.max_steps=64"] if quick else []
    stages = (["stage.schedule=[coarse]", f"stage.coarse.max_steps={sum(steps)}"] if run.coarse_only else
              ["stage.schedule=[coarse,refine]", f"stage.coarse.max_steps={steps[0]}",
               f"stage.refine.max_steps={steps[1]}"])
    return [*data, f"model={run.model}", f"data.views_per_sample={run.views}", *stages,
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


def measure(run: Run, work: Path, data: Sequence[str], steps: tuple[int, int], val_every: int,
            quick: bool) -> tuple[list[Point], list[tuple[float, float]]]:
    """Trains one run afresh; a Point per stage (after coarse, after refine; seconds: training CPU
    seconds without validation; error: 1 - the stage's best validation IoU) and its curve of
    (training CPU seconds, 1 - IoU) at each validation."""
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
        iou = stage_result.best_val_iou
        refine = stage_result.stage == "refine"
        label = run.label + (" +ref" if refine else "")
        points.append(Point(label, end["train_cpu"], 1.0 - iou if iou is not None else float("nan"),
                            default=run.default and refine, extra={
                                "iou": iou if iou is not None else float("nan"), "train_cpu_s": end["train_cpu"],
                                "val_cpu_s": end["val_cpu_total"], "wall_s": end["wall"] - start_wall,
                                "load": t.load, "model": run.model, "views": run.views,
                                "stages": "coarse+refine" if refine else "coarse",
                                "steps": int(end["step"]) + (steps[0] if refine else 0)}))
    return points, curve


COLUMNS = (("best val IoU", "iou"), ("training CPU s", "train_cpu_s"), ("validation CPU s", "val_cpu_s"),
           ("wall s (all)", "wall_s"), ("load", "load"), ("model", "model"), ("views", "views"),
           ("stages", "stages"), ("steps", "steps"))


def run(out_dir: Path, work: Path, quick: bool = False, steps: Optional[tuple[int, int]] = None,
        progress: bool = True, prefix: str = "study_svr") -> str:
    """Generates the dataset (once), trains every run, writes ``<out_dir>/<prefix>.png`` and
    returns the report's markdown section.

    Args:
        steps: (coarse, refine) steps per run; default (200, 100), or (2, 2) with ``quick``.
    """
    steps = steps or ((2, 2) if quick else (200, 100))
    val_every = 2 if quick else 50
    log = progress_log(progress)
    for name in ("pytorch_lightning", "lightning", "lightning.pytorch", "lightning_fabric"):
        logging.getLogger(name).setLevel(logging.ERROR)
    data = data_overrides((work / "svr_cache").resolve(), quick)
    log("svr: dataset")
    instantiate(compose_train(data).data).prepare_data()
    points, curves = [], {}
    for r in runs(quick):
        log(f"svr: {r.label}")
        pts, curves[r.label] = measure(r, work, data, steps, val_every, quick)
        points += pts
    cats = QUICK_CATEGORIES if quick else CATEGORIES
    d = next(r for r in runs(quick) if r.default)
    intro = (
        f"`svr.training.stages.train` (configs/train.yaml) on a small procedural dataset (generator version "
        f"{GENERATOR_VERSION}): {len(cats)} categories "
        f"({', '.join(cats)}), {'2' if quick else '8'} training and {'1' if quick else '2'} validation objects per "
        f"category, 24 views each, `data.supersample=1`, batch of {'2' if quick else '8'} objects (made once and "
        f"cached; not counted). Every run: {steps[0]} coarse steps then {steps[1]} refine steps "
        f"(the stages' default optimisers; the joint stage left out), validation every {val_every} steps on views "
        f"{'0, 12' if quick else '0, 6, 12, 18'} of the validation objects (direct voxel IoU, `val/iou`). The "
        f"default is {d.label} (`model={d.model}`, `data.views_per_sample={d.views}`) with the refiner. Each run gives "
        f"two points: after its coarse stage (*refiner off*; `stage.schedule=[coarse]` trains exactly that) and "
        f"after its refine stage (*+ref*); *coarse-only* gives the refine stage's steps to the coarse stage "
        f"instead, which compares the refiner with the same steps spent on more coarse training. Error: 1 - the "
        f"stage's best validation IoU; time: training CPU seconds "
        f"(1 thread) without the validations; the grey lines are each run's validations over time. At this budget "
        f"the networks are early in training, so the IoUs are low, and with few validation objects the smaller "
        f"differences between settings are within the noise: read the costs with confidence and close IoUs "
        f"with care. A longer budget: `python -m benchmarks.accuracy_vs_time --parts svr --svr-steps 2000,500`.")
    section = tradeoff_section(
        points, COLUMNS, out_dir / f"{prefix}.png", title="Single-view reconstruction: validation IoU against "
        "training time", setting_name="setting", xlabel="training CPU seconds (without validation)",
        ylabel="1 - best validation IoU", unit="s", error_name="1 - IoU", logx=True, logy=False, curves=curves,
        tolerance=0.01)  # 1 % of 1 - IoU: about 0.01 IoU
    return "\n".join(["## Single-view reconstruction", "", intro, "", section])


def parse_steps(text: Optional[str]) -> Optional[tuple[int, int]]:
    """``"150,50"`` -> (150, 50); None stays None."""
    if text is None:
        return None
    try:
        coarse, refine = (int(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"steps must be two integers 'coarse,refine', got {text!r}") from None
    if coarse < 1 or refine < 1:
        raise ValueError(f"steps must be positive, got {text!r}")
    return coarse, refine
