"""The three-stage training schedule of paper section 6 (``train``): coarse (encoder + decoder),
refine (the refiner, the rest frozen), joint (all three), each a Lightning ``fit`` with its own
optimiser, step budget and checkpoints in the run folder (``svr.training.run_folder``), each later
stage starting from the previous one's best (or final) weights. It takes the typed
``TrainSettings`` and instantiates the components (data module, network, trainer, callbacks,
loggers) when it needs them. A ``ckpt_path`` of a scheduled stage resumes that stage (weights,
optimiser, step counters, callbacks) and runs the rest of the schedule; one of another stage only
initialises the weights. With several processes (``trainer=ddp``) every process runs ``train`` in
the same folder; only global rank 0 writes files."""
from __future__ import annotations

import dataclasses
import logging
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pytorch_lightning as pl
from hydra.utils import instantiate
from pytorch_lightning.callbacks import ModelCheckpoint, ProgressBar
from pytorch_lightning.utilities.exceptions import SIGTERMException

import renderer
from sdfcommon.tooling.command_line import invoked_as
from sdfcommon.tooling.host_memory import keep_freed_memory
from sdfcommon.tooling.outputs import remove_stale_temporaries
from sdfcommon.tooling.settings import settings_record

from svr.data.datamodules import SVRDataModule
from svr.data.symmetry import AXIS_NAMES, mirror_scores, symmetry_axis
from svr.distributed import launch_rank_is_zero
from svr.inference.checkpoints import load_checkpoint, load_network_weights
from svr.models.checkpoint_layout import CHECKPOINT_KEY
from svr.models.module import SVRLightningModule
from svr.models.network import SVRNet
from svr.training.callbacks import AtomicCheckpointIO
from svr.training.logs import keep_earlier_metrics, quiet_known_noise
from svr.training.run_folder import RunFolder
from svr.training.settings import LossSettings, TrainSettings
from svr.training.stopping import SaveOnStop, StopRequest, TrainingStopped

log = logging.getLogger(__name__)

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


# ------------------------------------------------------------------------------------------------
# Building blocks from the config


def build_scene(loss: LossSettings, shading_model) -> renderer.Scene:
    """The renderer.Scene of the image loss: silhouettes, plus shading when the dataset's shading
    model is known and ``loss.shading`` allows it ("auto": when known and weighted)."""
    if loss.shading is True and shading_model is None:
        raise ValueError("loss.shading=true needs a dataset whose shading model is known (the procedural "
                         "data); this data module has none: use loss.shading=auto or false")
    use = shading_model is not None and loss.weights.shading > 0 and loss.shading is not False
    if use:
        return shading_model.scene(effects=("silhouette", "shading"), silhouette_sigma=loss.silhouette_sigma)
    return renderer.Scene(effects=("silhouette",), silhouette_sigma=loss.silhouette_sigma)


def resolve_mirror_axis(settings: TrainSettings, datamodule) -> TrainSettings:
    """The settings with a pixel-aligned head's ``mirror_axis: auto`` replaced by the axis the
    training split's voxels are mirror-symmetric across (``svr.data.symmetry.symmetry_axis``; None
    when none is), so the network and every checkpoint's model config hold the measured value."""
    local = settings.model.get("local") if isinstance(settings.model, dict) else None
    if not isinstance(local, dict) or local.get("mirror_axis") != "auto":
        return settings
    datamodule.prepare_data()
    train_set = datamodule.dataset("train")
    voxels = np.stack([train_set.voxels(g).numpy() for g in range(len(train_set))])
    scores = mirror_scores(voxels)
    axis = symmetry_axis(voxels)
    log.info("mirror symmetry of the %d training shapes (mean IoU with their mirror across x, y, z = 0): %s -> "
             "model.local.mirror_axis=%s", len(voxels), ", ".join(f"{n} {v:.3f}" for n, v in zip(AXIS_NAMES, scores)),
             axis)
    model = {**settings.model, "local": {**local, "mirror_axis": axis}}
    return dataclasses.replace(settings, model=model)


def resolve_camera_elevation(settings: TrainSettings, datamodule) -> TrainSettings:
    """The settings with a camera head's ``elevation: auto`` replaced by whether training draws
    extra views (``data.extra_view_share`` > 0): the only views at other elevations than NMR's 30
    degrees, so the only ones that teach the head's elevation output anything."""
    camera = settings.model.get("camera") if isinstance(settings.model, dict) else None
    if not isinstance(camera, dict) or camera.get("elevation") != "auto":
        return settings
    elevation = float(getattr(datamodule, "extra_view_share", 0.0)) > 0
    log.info("model.camera.elevation=%s (training %s extra views)", elevation, "draws" if elevation else "draws no")
    model = {**settings.model, "camera": {**camera, "elevation": elevation}}
    return dataclasses.replace(settings, model=model)


def resolve_shape_prior(settings: TrainSettings, datamodule) -> TrainSettings:
    """The settings with a shape prior's ``objects: auto`` and ``categories: auto`` replaced by the
    training split's counts (``svr.models.ShapePrior`` holds a row per training object)."""
    prior = settings.model.get("prior") if isinstance(settings.model, dict) else None
    if not isinstance(prior, dict) or "auto" not in (prior.get("objects"), prior.get("categories")):
        return settings
    datamodule.prepare_data()
    train_set = datamodule.dataset("train")
    resolved = {**prior, "objects": len(train_set), "categories": len(train_set.offsets) - 1}
    return dataclasses.replace(settings, model={**settings.model, "prior": resolved})


def fill_shape_prior(net: SVRNet, datamodule) -> None:
    """Reads the training split into the network's shape prior, where it has one."""
    if net.prior is None:
        return
    datamodule.prepare_data()
    train_set = datamodule.dataset("train")
    started = time.perf_counter()
    net.prior.fill(train_set)
    log.info("shape prior: the silhouettes and visual hulls of %d training objects (%.1f s)", len(train_set),
             time.perf_counter() - started)


def resolve_model(settings: TrainSettings, datamodule) -> TrainSettings:
    """The settings with the model's ``auto`` values measured on the data (``resolve_mirror_axis``,
    ``resolve_camera_elevation``, ``resolve_shape_prior``): the network as training builds it."""
    settings = resolve_camera_elevation(resolve_mirror_axis(settings, datamodule), datamodule)
    return resolve_shape_prior(settings, datamodule)


def build_module(settings: TrainSettings, net: SVRNet, stage: str, datamodule: SVRDataModule) -> SVRLightningModule:
    """The LightningModule of one stage, from the loss and stage settings."""
    loss = settings.stage_loss(stage)
    stage_settings = settings.stage.of(stage)
    optimizer = instantiate(stage_settings.optimizer)
    scheduler = instantiate(stage_settings.scheduler) if stage_settings.scheduler is not None else None
    return SVRLightningModule(
        net=net,
        stage=stage,
        loss_weights=loss.weights,
        scene=build_scene(loss, datamodule.shading),
        render_size=loss.render_size,
        trace_settings=loss.trace,
        backend=loss.backend,
        optimizer=optimizer,
        scheduler=scheduler,
        categories=datamodule.categories,
        model_config=settings.model,
    )


def _instantiate_group(group: Optional[dict], **extra) -> list:
    """Instantiates every non-null ``_target_`` entry of a config group (callbacks, loggers)."""
    out = []
    if group is None:
        return out
    for name, node in group.items():
        if node is None:
            continue
        if not isinstance(node, dict) or "_target_" not in node:
            raise ValueError(f"{name}: expected a config with a _target_, got {node!r}")
        out.append(instantiate(node, **extra))
    return out


def build_trainer(settings: TrainSettings, stage: str, run: RunFolder, stop: StopRequest,
                  resume_step: Optional[int] = None) -> pl.Trainer:
    """A Trainer for one stage: its step budget, callbacks (checkpoints into the stage's folder; a
    checkpoint at a SIGTERM), loggers (into the stage's folder; resuming from step ``resume_step``,
    the CSV log goes on in the same file) and atomic checkpoint files."""
    stage_settings = settings.stage.of(stage)
    stage_dir = run.stage_dir(stage)
    callbacks = _instantiate_group(settings.callbacks)
    if settings.trainer.get("enable_progress_bar", True) is False:
        # trainer.enable_progress_bar=false alone turns the bars off: Lightning refuses a progress
        # bar callback beside it, and callbacks.progress_bar is one by default.
        callbacks = [cb for cb in callbacks if not isinstance(cb, ProgressBar)]
    for cb in callbacks:
        if isinstance(cb, ModelCheckpoint) and cb.dirpath is None:
            cb.dirpath = str(run.checkpoints(stage))
    callbacks.append(SaveOnStop(run.last(stage), stop))
    loggers = _instantiate_group(settings.logger, save_dir=str(stage_dir))
    keep_earlier_metrics(loggers, resume_step)
    kwargs: dict[str, Any] = dict(
        max_steps=stage_settings.max_steps,
        callbacks=callbacks,
        logger=loggers if loggers else False,
        default_root_dir=str(stage_dir),
        plugins=[AtomicCheckpointIO()],
    )
    if stage_settings.max_time is not None:
        kwargs["max_time"] = stage_settings.max_time
    return instantiate(settings.trainer, **kwargs)


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


def train(settings: TrainSettings, run_dir: str | Path) -> TrainResult:
    """Runs the stages of ``settings.stage.schedule`` in order (see the module docstring) in
    ``run_dir``, whose ``config.yaml`` the command has written.

    Resuming (``ckpt_path`` of a scheduled stage) into the checkpoint's own run folder goes on with
    that run: its best-checkpoint tracking, its metrics file, its place in the training data. A run
    folder as ``ckpt_path`` resumes from its latest checkpoint; ``run_dir`` itself holding none (the
    run stopped before its first) starts from the first step. On a SIGTERM the stage saves
    ``last.ckpt`` and ``TrainingStopped`` is raised.

    Args:
        settings: the training settings (``svr.training.settings.TrainSettings``).
        run_dir: the run's output folder.
    Returns:
        TrainResult with each stage's checkpoints.
    Raises:
        TrainingStopped: a SIGTERM stopped a stage (its ``last.ckpt`` holds the step reached).
    """
    run = RunFolder(Path(run_dir))
    schedule = list(settings.stage.schedule)
    ckpt_path = settings.ckpt_path
    if ckpt_path is not None and Path(ckpt_path).expanduser().is_dir():
        named = RunFolder(Path(ckpt_path).expanduser())
        found = named.latest_checkpoint(schedule)
        if found is None and named.root.resolve() == run.root.resolve() and not named.holds_checkpoint():
            log.info("%s holds a run stopped before its first checkpoint: it starts again from its first step",
                     named.root)
        elif found is None:
            raise FileNotFoundError(f"ckpt_path={ckpt_path}: the folder holds no <stage>/checkpoints/last.ckpt or "
                                    f"final.ckpt of the stages {schedule}: nothing to resume")
        ckpt_path = str(found) if found is not None else None
    start, resume, resume_step = 0, False, None
    ckpt = None
    if ckpt_path is not None:
        ckpt = load_checkpoint(ckpt_path)
        start, resume = plan_schedule(schedule, ckpt[CHECKPOINT_KEY]["stage"])
        resume_step = int(ckpt.get("global_step", 0)) if resume else None

    run.root.mkdir(parents=True, exist_ok=True)
    quiet_known_noise()
    keep_freed_memory()  # a step's 64^3 grids reuse pages instead of faulting them in again
    if launch_rank_is_zero():  # the other DDP processes run this too, in the same folder
        for stale in remove_stale_temporaries(run.root):
            log.info("removed %s, left by a run killed while writing it", stale)

    pl.seed_everything(int(settings.seed), workers=True)
    datamodule = instantiate(settings.data)
    settings = resolve_model(settings, datamodule)
    net = instantiate(settings.model)
    if not isinstance(net, SVRNet):
        raise TypeError(f"model must instantiate a svr.models.SVRNet, got {type(net).__name__}")
    fill_shape_prior(net, datamodule)
    if ckpt is not None:
        if not resume:
            load_network_weights(net, ckpt, ckpt_path)
            log.info("initialised the network from %s (a %s checkpoint)", ckpt_path, ckpt[CHECKPOINT_KEY]["stage"])
        else:
            log.info("resuming stage %s at step %d from %s", schedule[start], resume_step, ckpt_path)
        ckpt = None

    with StopRequest(run.root).installed() as stop:
        return _run_schedule(settings, run, stop, start, resume, resume_step, ckpt_path, net, datamodule)


def _run_schedule(settings: TrainSettings, run: RunFolder, stop: StopRequest, start: int, resume: bool,
                  resume_step: Optional[int], ckpt_path, net: SVRNet, datamodule) -> TrainResult:
    schedule = list(settings.stage.schedule)
    hyperparameters = settings_record(settings)
    results: list[StageResult] = []
    for i, stage in enumerate(schedule[start:], start=start):
        pl.seed_everything(int(settings.seed) + i, workers=True)
        stage_dir = run.stage_dir(stage)
        resuming = resume and i == start
        module = build_module(settings, net, stage, datamodule)
        trainer = build_trainer(settings, stage, run, stop, resume_step if resuming else None)
        for lg in trainer.loggers:
            lg.log_hyperparams(hyperparameters)
        log.info("stage %s: %d steps -> %s", stage, settings.stage.of(stage).max_steps, stage_dir)
        try:
            with stop.fitting(), warnings.catch_warnings():
                if resuming:  # the run's own folder: of course it holds checkpoints and logs
                    warnings.filterwarnings("ignore", message=r"(Checkpoint|Experiment logs) directory .* exists and "
                                                              r"is not empty")
                # weights_only: our checkpoints hold tensors and plain values only (never unpickle code)
                trainer.fit(module, datamodule=datamodule, ckpt_path=str(ckpt_path) if resuming else None,
                            weights_only=True)
        except SIGTERMException:
            raise _stopped(trainer, stage, run) from None
        final = run.final(stage)
        trainer.save_checkpoint(final, weights_only=False)  # a full, resumable checkpoint
        if stop.pending:  # the signal came with or after the stage's last step: stop before the next stage
            raise _stopped(trainer, stage, run, final)
        best, last, score = _checkpoint_callbacks(trainer)
        results.append(StageResult(stage, stage_dir, best, last, final, score))
        log.info("stage %s done: best val IoU %s (%s), final %s", stage, score, best, final)
        if i + 1 < len(schedule):
            handoff = best if (settings.stage.init_from == "best" and best is not None) else final
            load_network_weights(net, load_checkpoint(handoff), handoff)
            log.info("next stage starts from %s", handoff)
    return TrainResult(run.root, tuple(results))


def _stopped(trainer: pl.Trainer, stage: str, run: RunFolder, checkpoint: Optional[Path] = None) -> TrainingStopped:
    saver = next((cb for cb in trainer.callbacks if isinstance(cb, SaveOnStop)), None)
    if checkpoint is None and saver is not None and saver.saved_step is not None:
        checkpoint = saver.path
    if checkpoint is None:
        return TrainingStopped(f"training stopped by SIGTERM in stage {stage}; no checkpoint was saved at the signal")
    message = (f"training stopped by SIGTERM in stage {stage} at step {int(trainer.global_step)}; saved "
               f"{checkpoint}. Resume with: {invoked_as('python train.py')} ckpt_path={run.root}")
    if launch_rank_is_zero():
        print(message, file=sys.stderr, flush=True)
    return TrainingStopped(message, checkpoint=checkpoint)


__all__ = ["train", "StageResult", "TrainResult", "TrainingStopped", "build_module", "build_scene",
           "build_trainer", "plan_schedule", "fill_shape_prior", "resolve_camera_elevation", "resolve_mirror_axis",
           "resolve_model", "resolve_shape_prior"]
