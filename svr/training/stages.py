"""The three-stage training schedule of paper section 6, driven by a composed hydra config, and its
entry point: ``python train.py`` / ``sdfdiff-train`` (``main``: hydra composes configs/train.yaml
with the overrides; ``run`` trains in hydra's run folder, ``outputs/train/<time>`` by default, one
folder per job with ``-m``). ``train`` is the body (also of ``python -m svr.demo``): it reads the
config and instantiates everything else (``_target_``) into plain objects. Resuming a run:
``svr.training.resume``.

Run folder layout (``run_dir``)::

    config.yaml                    the resolved config of the run
    <stage>/checkpoints/best.ckpt  best validation IoU (fast direct variant) of that stage
    <stage>/checkpoints/last.ckpt  rewritten every few steps: what a killed run resumes from
    <stage>/checkpoints/final.ckpt the weights at the end of the stage
    <stage>/tensorboard/, <stage>/csv/metrics.csv, <stage>/images/step_*.png

Several processes (``trainer=ddp``): every process runs ``train`` with the same ``run_dir``; only
global rank 0 writes files (config.yaml here, the rest through Lightning's rank-zero loggers,
checkpoints and callbacks).

``ckpt_path``: a checkpoint of a stage that is in the schedule resumes that stage (weights,
optimiser, step counters, callbacks) and runs the rest of the schedule after it; a checkpoint of
another stage (e.g. a coarse one with ``stage=refine``) only initialises the network's weights.
"""
from __future__ import annotations

import contextlib
import csv
import logging
import signal
import sys
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import pytorch_lightning as pl
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from pytorch_lightning.callbacks import ModelCheckpoint
from pytorch_lightning.loggers import CSVLogger
from pytorch_lightning.utilities.exceptions import SIGTERMException

import renderer
from sdfcommon.tooling.host_memory import keep_freed_memory
from sdfcommon.tooling.outputs import remove_stale_temporaries, write_csv, write_text

from svr.training.callbacks import AtomicCheckpointIO
from svr.inference.checkpoints import CHECKPOINT_KEY, STAGES, check_stage, load_checkpoint, load_network_weights
from svr.distributed import launch_rank_is_zero
from svr.losses import LossWeights
from svr.models.module import SVRLightningModule
from svr.models.network import SVRNet
from svr.training.resume import latest_checkpoint, resume_arguments, resumed_config, run_folder_of, slurm_arguments

log = logging.getLogger(__name__)

SHADING_MODES = ("auto", True, False)
INIT_FROM = ("best", "final")


@dataclass(frozen=True)
class StageResult:
    """Where one stage left its checkpoints (None when a file was not written)."""

    stage: str
    directory: Path
    best: Optional[Path]
    last: Optional[Path]
    final: Path
    best_val_iou: Optional[float]


@dataclass(frozen=True)
class TrainResult:
    """The run folder and the stages that ran, in order."""

    run_dir: Path
    stages: tuple[StageResult, ...] = field(default_factory=tuple)

    def checkpoint(self, stage: Optional[str] = None, which: str = "best") -> Path:
        """A stage's checkpoint ("best", falling back to "final"; or "final"); the last stage by default."""
        if not self.stages:
            raise ValueError("no stage ran")
        res = self.stages[-1] if stage is None else next((s for s in self.stages if s.stage == stage), None)
        if res is None:
            raise ValueError(f"stage {stage!r} did not run; ran {[s.stage for s in self.stages]}")
        if which == "best" and res.best is not None:
            return res.best
        if which not in ("best", "final"):
            raise ValueError(f"which must be 'best' or 'final', got {which!r}")
        return res.final


class TrainingStopped(SystemExit):
    """Training stopped by a signal (SIGTERM: ``kill``, a scheduler's time limit, a container stop)
    after saving a resumable checkpoint. Its exit status is 128 + the signal number (143 for
    SIGTERM), as a shell reports a process killed by that signal, so ``train && evaluate`` chains
    and job schedulers see a failure."""

    def __init__(self, message: str, signum: int = int(signal.SIGTERM), checkpoint: Optional[Path] = None):
        super().__init__(128 + int(signum))
        self.message = message
        self.checkpoint = checkpoint


class SaveOnStop(pl.Callback):
    """Saves a resumable checkpoint (``path``, the stage's ``last.ckpt``) when a SIGTERM arrives,
    and then lets Lightning stop.

    The signal is only noted when it arrives; the checkpoint is written at the end of the training
    step that is running (or the next one, when the signal came during validation or before the
    first step), at ``on_train_batch_end``, where Lightning's periodic checkpoints are written too:
    the state its resume logic restores exactly. Only then is Lightning told (its own SIGTERM
    handler), so it stops after that step. Had Lightning heard the signal itself, it would stop in
    the middle of a validation (before the step's learning-rate update: a resumed run would then
    be one scheduler step behind) or after an epoch's last step (a checkpoint that resumes one
    epoch too far). A signal after the stage's last step is kept in ``pending`` for ``train``.
    The training data loader records its place in the epoch (``ResumableLoader``).
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self.saved_step: Optional[int] = None
        self.pending = False
        self._lightning_handler: Any = None

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        # Lightning installed its handler when fit began; hear the signal first (main thread only).
        if threading.current_thread() is threading.main_thread():
            self._lightning_handler = signal.getsignal(signal.SIGTERM)
            signal.signal(signal.SIGTERM, self._note)

    def _note(self, signum: int, frame: Any) -> None:
        self.pending = True

    def _save(self, trainer: pl.Trainer) -> None:
        if self.saved_step is None:
            trainer.save_checkpoint(self.path, weights_only=False)
            self.saved_step = int(trainer.global_step)

    def on_train_batch_end(self, trainer: pl.Trainer, *args: Any) -> None:
        if self.pending or trainer.received_sigterm:
            self._save(trainer)
            if callable(self._lightning_handler) and not trainer.received_sigterm:
                self._lightning_handler(signal.SIGTERM, None)  # Lightning stops after this step

    def on_exception(self, trainer: pl.Trainer, pl_module: pl.LightningModule, exception: BaseException) -> None:
        if isinstance(exception, SIGTERMException):  # Lightning heard it first (e.g. broadcast by DDP)
            self._save(trainer)


class _DropAdvertisements(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("\U0001f4a1 Tip:")  # "try installing <a cloud logger>"


def quiet_known_noise() -> None:
    """Silences the messages every stage would print that say nothing about this run: Lightning's
    advertisement for a cloud logger, a deprecation inside Lightning's own code (LeafSpec), and
    the warning about modules in eval mode (the stages freeze parts of the network on purpose:
    their batch-norm statistics must not move, ``SVRLightningModule.apply_stage``)."""
    rank_zero = logging.getLogger("pytorch_lightning.utilities.rank_zero")
    if not any(isinstance(f, _DropAdvertisements) for f in rank_zero.filters):
        rank_zero.addFilter(_DropAdvertisements())
    warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated")
    warnings.filterwarnings("ignore", message=r"Found \d+ module\(s\) in eval mode at the start of training")


# ------------------------------------------------------------------------------------------------
# Building blocks from the config


def build_scene(loss_cfg: DictConfig, weights: LossWeights, shading_model) -> renderer.Scene:
    """The renderer.Scene of the image loss: silhouettes, plus shading when the dataset's shading
    model is known and ``loss.shading`` allows it ("auto": when known and weighted)."""
    mode = loss_cfg.get("shading", "auto")
    if mode not in SHADING_MODES:
        raise ValueError(f"loss.shading must be one of {SHADING_MODES}, got {mode!r}")
    sigma = float(loss_cfg.get("silhouette_sigma", 0.3))
    if mode is True and shading_model is None:
        raise ValueError("loss.shading=true needs a dataset whose shading model is known (the procedural "
                         "data); this data module has none: use loss.shading=auto or false")
    use = shading_model is not None and weights.shading > 0 and mode is not False
    if use:
        return shading_model.scene(effects=("silhouette", "shading"), silhouette_sigma=sigma)
    return renderer.Scene(effects=("silhouette",), silhouette_sigma=sigma)


def stage_loss_config(cfg: DictConfig, stage: str) -> DictConfig:
    """The loss config of one stage: ``loss`` with the stage's ``stage.<name>.loss`` entries on top
    (e.g. a wider soft silhouette early on)."""
    extra = cfg.stage[stage].get("loss")
    return OmegaConf.merge(cfg.loss, extra) if extra else cfg.loss


def build_module(cfg: DictConfig, net: SVRNet, stage: str, datamodule) -> SVRLightningModule:
    """The LightningModule of one stage, from the loss and stage config groups."""
    loss_cfg = stage_loss_config(cfg, stage)
    weights = instantiate(loss_cfg.weights)
    if not isinstance(weights, LossWeights):
        raise TypeError(f"loss.weights must instantiate a svr.losses.LossWeights, got {type(weights).__name__}")
    trace = instantiate(loss_cfg.trace) if loss_cfg.get("trace") is not None else renderer.TraceSettings()
    stage_cfg = cfg.stage[stage]
    optimizer = instantiate(stage_cfg.optimizer) if stage_cfg.get("optimizer") is not None else None
    scheduler = instantiate(stage_cfg.scheduler) if stage_cfg.get("scheduler") is not None else None
    return SVRLightningModule(
        net=net,
        stage=stage,
        loss_weights=weights,
        scene=build_scene(loss_cfg, weights, getattr(datamodule, "shading", None)),
        render_size=int(loss_cfg.get("render_size", 64)),
        trace_settings=trace,
        backend=str(loss_cfg.get("backend", "auto")),
        optimizer=optimizer,
        scheduler=scheduler,
        categories=getattr(datamodule, "categories", None),
        model_config=OmegaConf.to_container(cfg.model, resolve=True),
    )


def _instantiate_group(group: Optional[DictConfig], **extra) -> list:
    """Instantiates every non-null ``_target_`` entry of a config group (callbacks, loggers)."""
    out = []
    if group is None:
        return out
    for name, node in group.items():
        if node is None:
            continue
        if not isinstance(node, DictConfig) or "_target_" not in node:
            raise ValueError(f"{name}: expected a config with a _target_, got {node!r}")
        out.append(instantiate(node, **extra))
    return out


def continue_metrics(log_dir: Path, resume_step: Optional[int]) -> Optional[Path]:
    """Keeps the metrics of earlier runs of a stage in its ``metrics.csv``, which Lightning's CSV
    logger would delete when it starts.

    Resuming (``resume_step``: the checkpoint's step), the rows up to that step are kept in
    ``metrics.csv`` and the logger appends to them (rows after it were logged by steps the resumed
    run trains again). Otherwise an earlier file is moved aside to ``metrics.<k>.csv``.

    Returns:
        the file holding the earlier rows (``metrics.csv`` or the moved one), or None.
    """
    old = log_dir / "metrics.csv"
    if not old.is_file():
        return None
    if resume_step is not None:  # rewritten in place, atomically
        with open(old, newline="") as f:
            reader = csv.DictReader(f)
            columns = list(reader.fieldnames or [])
            rows = [r for r in reader if _step_of(r) is not None and _step_of(r) <= resume_step]
        return write_csv(old, rows, columns)
    k = 1
    while (log_dir / f"metrics.{k}.csv").exists():
        k += 1
    return old.rename(log_dir / f"metrics.{k}.csv")


def _step_of(row: dict) -> Optional[int]:
    try:
        return int(float(row.get("step") or ""))
    except ValueError:
        return None


def _adopt_metrics_file(logger: CSVLogger) -> None:
    """Points a fresh CSV logger at a resumed stage's log folder: it appends to the ``metrics.csv``
    kept by ``continue_metrics`` (its writer would delete the file, and warn about the folder,
    when it starts)."""
    log_dir = Path(logger.log_dir)
    if not log_dir.is_dir():
        return
    path = log_dir / "metrics.csv"
    columns = None
    if path.is_file():
        with open(path, newline="") as f:
            columns = next(csv.reader(f), [])
    kept = log_dir.rename(log_dir.with_name(f".{log_dir.name}.kept"))
    writer = logger.experiment  # creates log_dir anew, empty
    for item in kept.iterdir():
        item.rename(log_dir / item.name)
    kept.rmdir()
    if columns is not None:
        writer.metrics_keys = list(columns)


def stage_max_steps(cfg: DictConfig, stage: str) -> int:
    """``stage.<stage>.max_steps``, checked: a whole number of steps >= 1 (Lightning would take -1
    as "no limit")."""
    value = cfg.stage[stage].get("max_steps")
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"stage.{stage}.max_steps must be an integer >= 1, got {value!r}")
    return value


def build_trainer(cfg: DictConfig, stage: str, stage_dir: Path, resume_step: Optional[int] = None) -> pl.Trainer:
    """A Trainer for one stage: its step budget, callbacks (checkpoints into ``stage_dir``; a
    checkpoint at a SIGTERM), loggers (into ``stage_dir``; resuming from step ``resume_step``, the
    CSV log goes on in the same file) and atomic checkpoint files."""
    stage_cfg = cfg.stage[stage]
    max_steps = stage_max_steps(cfg, stage)
    callbacks = _instantiate_group(cfg.get("callbacks"))
    for cb in callbacks:
        if isinstance(cb, ModelCheckpoint) and cb.dirpath is None:
            cb.dirpath = str(stage_dir / "checkpoints")
    callbacks.append(SaveOnStop(stage_dir / "checkpoints" / "last.ckpt"))
    loggers = _instantiate_group(cfg.get("logger"), save_dir=str(stage_dir))
    for lg in loggers:
        if isinstance(lg, CSVLogger) and launch_rank_is_zero():
            continue_metrics(Path(lg.log_dir), resume_step)
            if resume_step is not None:
                _adopt_metrics_file(lg)
    kwargs: dict[str, Any] = dict(
        max_steps=max_steps,
        callbacks=callbacks,
        logger=loggers if loggers else False,
        default_root_dir=str(stage_dir),
        plugins=[AtomicCheckpointIO()],
    )
    if stage_cfg.get("max_time") is not None:
        kwargs["max_time"] = stage_cfg.max_time
    return instantiate(cfg.trainer, **kwargs)


def _checkpoint_callbacks(trainer: pl.Trainer) -> tuple[Optional[Path], Optional[Path], Optional[float]]:
    best = last = score = None
    for cb in trainer.checkpoint_callbacks:
        if cb.monitor is not None and cb.best_model_path:
            best = Path(cb.best_model_path)
            score = float(cb.best_model_score) if cb.best_model_score is not None else None
        if cb.last_model_path:
            last = Path(cb.last_model_path)
    return best, last, score


# ------------------------------------------------------------------------------------------------
# The schedule


def plan_schedule(schedule: list[str], ckpt_stage: Optional[str]) -> tuple[int, bool]:
    """Where the schedule starts and whether the checkpoint resumes that first stage.

    Returns:
        (index of the first stage to run, resume): a checkpoint of a scheduled stage resumes it
        (earlier stages are skipped); otherwise the whole schedule runs (the checkpoint, if any,
        only initialises the weights).
    """
    if ckpt_stage is not None and ckpt_stage in schedule:
        return schedule.index(ckpt_stage), True
    return 0, False


def train(cfg: DictConfig, run_dir: str | Path) -> TrainResult:
    """Runs the stages of ``cfg.stage.schedule`` in order (see the module docstring).

    Resuming (``ckpt_path`` of a scheduled stage) into the checkpoint's own run folder goes on with
    that run: its best-checkpoint tracking, its metrics file, its place in the training data. On a
    SIGTERM the stage saves ``last.ckpt`` and ``TrainingStopped`` is raised.

    Args:
        cfg: the composed train config (configs/train.yaml).
        run_dir: the run's output folder (hydra's run dir for train.py).
    Returns:
        TrainResult with each stage's checkpoints.
    Raises:
        TrainingStopped: a SIGTERM stopped a stage (its ``last.ckpt`` holds the step reached).
    """
    run_dir = Path(run_dir)
    schedule = [check_stage(str(s)) for s in cfg.stage.schedule]
    if not schedule:
        raise ValueError(f"stage.schedule must name at least one of {STAGES}")
    if len(set(schedule)) != len(schedule):
        raise ValueError(f"stage.schedule must not repeat a stage, got {schedule}")
    for stage in schedule:
        stage_max_steps(cfg, stage)
    init_from = cfg.stage.get("init_from", "best")
    if init_from not in INIT_FROM:
        raise ValueError(f"stage.init_from must be one of {INIT_FROM}, got {init_from!r}")

    ckpt_path = cfg.get("ckpt_path")
    if ckpt_path is not None and Path(ckpt_path).expanduser().is_dir():
        found = latest_checkpoint(Path(ckpt_path).expanduser(), schedule)
        if found is None:
            raise FileNotFoundError(f"ckpt_path={ckpt_path}: the folder holds no <stage>/checkpoints/last.ckpt or "
                                    f"final.ckpt of the stages {schedule}: nothing to resume")
        ckpt_path = str(found)
    start, resume, resume_step = 0, False, None
    ckpt = None
    if ckpt_path is not None:
        ckpt = load_checkpoint(ckpt_path)
        start, resume = plan_schedule(schedule, ckpt[CHECKPOINT_KEY]["stage"])
        resume_step = int(ckpt.get("global_step", 0)) if resume else None

    run_dir.mkdir(parents=True, exist_ok=True)
    quiet_known_noise()
    keep_freed_memory()  # a step's 64^3 grids reuse pages instead of faulting them in again
    if launch_rank_is_zero():  # the other DDP processes run this too, in the same folder
        for stale in remove_stale_temporaries(run_dir):
            log.info("removed %s, left by a run killed while writing it", stale)
        config = cfg
        if resume and run_folder_of(ckpt_path) == run_dir.resolve():
            # The run's own config.yaml records what it started from, not the checkpoint it resumes.
            config = cfg.copy()
            config.ckpt_path = OmegaConf.load(run_dir / "config.yaml").get("ckpt_path")
        write_text(run_dir / "config.yaml", OmegaConf.to_yaml(config, resolve=True))

    pl.seed_everything(int(cfg.seed), workers=True)
    datamodule = instantiate(cfg.data)
    net = instantiate(cfg.model)
    if not isinstance(net, SVRNet):
        raise TypeError(f"model must instantiate a svr.models.SVRNet, got {type(net).__name__}")
    if ckpt is not None:
        if not resume:
            load_network_weights(net, ckpt, ckpt_path)
            log.info("initialised the network from %s (a %s checkpoint)", ckpt_path, ckpt[CHECKPOINT_KEY]["stage"])
        else:
            log.info("resuming stage %s at step %d from %s", schedule[start], resume_step, ckpt_path)
        ckpt = None

    with _stop_outside_fit(run_dir):
        return _run_schedule(cfg, run_dir, schedule, start, resume, resume_step, ckpt_path, net, datamodule, init_from)


_IN_FIT = False  # Lightning's SIGTERM handling is active


@contextlib.contextmanager
def _stop_outside_fit(run_dir: Path):
    """A SIGTERM outside a stage's ``fit`` (data generation, between stages) raises
    ``TrainingStopped`` instead of killing the process silently; inside it Lightning handles the
    signal (``SaveOnStop``). Main thread only (where signal handlers can be set)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        if not _IN_FIT:
            message = (f"training stopped by signal {signum} outside a training step; resume from the latest "
                       f"checkpoint with: python train.py ckpt_path={run_dir}")
            if launch_rank_is_zero():
                print(message, file=sys.stderr, flush=True)
            raise TrainingStopped(message, signum)

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _run_schedule(cfg: DictConfig, run_dir: Path, schedule: list[str], start: int, resume: bool,
                  resume_step: Optional[int], ckpt_path, net: SVRNet, datamodule, init_from: str) -> TrainResult:
    global _IN_FIT
    results: list[StageResult] = []
    for i, stage in enumerate(schedule[start:], start=start):
        pl.seed_everything(int(cfg.seed) + i, workers=True)
        stage_dir = run_dir / stage
        resuming = resume and i == start
        module = build_module(cfg, net, stage, datamodule)
        trainer = build_trainer(cfg, stage, stage_dir, resume_step if resuming else None)
        for lg in trainer.loggers:
            lg.log_hyperparams(OmegaConf.to_container(cfg, resolve=True))
        log.info("stage %s: %d steps -> %s", stage, int(cfg.stage[stage].max_steps), stage_dir)
        try:
            _IN_FIT = True
            with warnings.catch_warnings():
                if resuming:  # the run's own folder: of course it holds checkpoints and logs
                    warnings.filterwarnings("ignore", message=r"(Checkpoint|Experiment logs) directory .* exists and "
                                                              r"is not empty")
                # weights_only: our checkpoints hold tensors and plain values only (never unpickle code)
                trainer.fit(module, datamodule=datamodule, ckpt_path=str(ckpt_path) if resuming else None,
                            weights_only=True)
        except SIGTERMException:
            raise _stopped(trainer, stage, run_dir) from None
        finally:
            _IN_FIT = False
        final = stage_dir / "checkpoints" / "final.ckpt"
        trainer.save_checkpoint(final, weights_only=False)  # a full, resumable checkpoint
        saver = next(cb for cb in trainer.callbacks if isinstance(cb, SaveOnStop))
        if saver.pending:  # the signal came with or after the stage's last step: stop before the next stage
            raise _stopped(trainer, stage, run_dir, final)
        best, last, score = _checkpoint_callbacks(trainer)
        results.append(StageResult(stage, stage_dir, best, last, final, score))
        log.info("stage %s done: best val IoU %s (%s), final %s", stage, score, best, final)
        if i + 1 < len(schedule):
            handoff = best if (init_from == "best" and best is not None) else final
            load_network_weights(net, load_checkpoint(handoff), handoff)
            log.info("next stage starts from %s", handoff)
    return TrainResult(run_dir, tuple(results))


def _stopped(trainer: pl.Trainer, stage: str, run_dir: Path, checkpoint: Optional[Path] = None) -> TrainingStopped:
    saver = next((cb for cb in trainer.callbacks if isinstance(cb, SaveOnStop)), None)
    if checkpoint is None and saver is not None and saver.saved_step is not None:
        checkpoint = saver.path
    if checkpoint is None:
        return TrainingStopped(f"training stopped by SIGTERM in stage {stage}; no checkpoint was saved at the signal")
    message = (f"training stopped by SIGTERM in stage {stage} at step {int(trainer.global_step)}; saved "
               f"{checkpoint}. Resume with: python train.py ckpt_path={run_dir}")
    if launch_rank_is_zero():
        print(message, file=sys.stderr, flush=True)
    return TrainingStopped(message, checkpoint=checkpoint)


__all__ = ["train", "StageResult", "TrainResult", "TrainingStopped", "build_module", "build_scene",
           "build_trainer", "plan_schedule"]
