"""The three-stage training schedule of paper section 6, driven by a composed hydra config.

This is the body of the entry points (``train.py``, ``sdfdiff-train``, ``python -m svr.demo``): it
reads the config and instantiates everything else (``_target_``) into plain objects.

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

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import pytorch_lightning as pl
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from pytorch_lightning.callbacks import ModelCheckpoint
from pytorch_lightning.loggers import CSVLogger

import renderer
from mvr.outputs import write_text

from .callbacks import AtomicCheckpointIO
from .distributed import launch_rank_is_zero
from .host_memory import keep_freed_memory
from .losses import LossWeights
from .models.module import (CHECKPOINT_KEY, STAGES, SVRLightningModule, check_stage, load_checkpoint,
                            load_network_weights)
from .models.network import SVRNet

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


def keep_previous_metrics(log_dir: Path) -> Optional[Path]:
    """Moves a ``metrics.csv`` left by an earlier (resumed or repeated) run of a stage aside to
    ``metrics.<k>.csv``: Lightning's CSV logger would delete it. Returns the new name, if any."""
    old = log_dir / "metrics.csv"
    if not old.is_file():
        return None
    k = 1
    while (log_dir / f"metrics.{k}.csv").exists():
        k += 1
    return old.rename(log_dir / f"metrics.{k}.csv")


def build_trainer(cfg: DictConfig, stage: str, stage_dir: Path) -> pl.Trainer:
    """A Trainer for one stage: its step budget, callbacks (checkpoints into ``stage_dir``),
    loggers (into ``stage_dir``) and atomic checkpoint files."""
    stage_cfg = cfg.stage[stage]
    callbacks = _instantiate_group(cfg.get("callbacks"))
    for cb in callbacks:
        if isinstance(cb, ModelCheckpoint) and cb.dirpath is None:
            cb.dirpath = str(stage_dir / "checkpoints")
    loggers = _instantiate_group(cfg.get("logger"), save_dir=str(stage_dir))
    for lg in loggers:
        if isinstance(lg, CSVLogger) and launch_rank_is_zero():
            keep_previous_metrics(Path(lg.log_dir))
    kwargs: dict[str, Any] = dict(
        max_steps=int(stage_cfg.max_steps),
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

    Args:
        cfg: the composed train config (configs/train.yaml).
        run_dir: the run's output folder (hydra's run dir for train.py).
    Returns:
        TrainResult with each stage's checkpoints.
    """
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    keep_freed_memory()  # a step's 64^3 grids reuse pages instead of faulting them in again
    if launch_rank_is_zero():  # the other DDP processes run this too, in the same folder
        write_text(run_dir / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))

    schedule = [check_stage(str(s)) for s in cfg.stage.schedule]
    if not schedule:
        raise ValueError(f"stage.schedule must name at least one of {STAGES}")
    if len(set(schedule)) != len(schedule):
        raise ValueError(f"stage.schedule must not repeat a stage, got {schedule}")
    init_from = cfg.stage.get("init_from", "best")
    if init_from not in INIT_FROM:
        raise ValueError(f"stage.init_from must be one of {INIT_FROM}, got {init_from!r}")

    pl.seed_everything(int(cfg.seed), workers=True)
    datamodule = instantiate(cfg.data)
    net = instantiate(cfg.model)
    if not isinstance(net, SVRNet):
        raise TypeError(f"model must instantiate a svr.models.SVRNet, got {type(net).__name__}")

    ckpt_path = cfg.get("ckpt_path")
    start, resume = 0, False
    if ckpt_path is not None:
        ckpt = load_checkpoint(ckpt_path)
        ckpt_stage = ckpt[CHECKPOINT_KEY]["stage"]
        start, resume = plan_schedule(schedule, ckpt_stage)
        if not resume:
            load_network_weights(net, ckpt, ckpt_path)
            log.info("initialised the network from %s (a %s checkpoint)", ckpt_path, ckpt_stage)
        else:
            log.info("resuming stage %s from %s", ckpt_stage, ckpt_path)
        del ckpt

    results: list[StageResult] = []
    for i, stage in enumerate(schedule[start:], start=start):
        pl.seed_everything(int(cfg.seed) + i, workers=True)
        stage_dir = run_dir / stage
        module = build_module(cfg, net, stage, datamodule)
        trainer = build_trainer(cfg, stage, stage_dir)
        for lg in trainer.loggers:
            lg.log_hyperparams(OmegaConf.to_container(cfg, resolve=True))
        log.info("stage %s: %d steps -> %s", stage, int(cfg.stage[stage].max_steps), stage_dir)
        trainer.fit(module, datamodule=datamodule,
                    ckpt_path=str(ckpt_path) if (resume and i == start) else None)
        final = stage_dir / "checkpoints" / "final.ckpt"
        trainer.save_checkpoint(final)
        best, last, score = _checkpoint_callbacks(trainer)
        results.append(StageResult(stage, stage_dir, best, last, final, score))
        log.info("stage %s done: best val IoU %s (%s), final %s", stage, score, best, final)
        if i + 1 < len(schedule):
            handoff = best if (init_from == "best" and best is not None) else final
            load_network_weights(net, load_checkpoint(handoff), handoff)
            log.info("next stage starts from %s", handoff)
    return TrainResult(run_dir, tuple(results))


__all__ = ["train", "StageResult", "TrainResult", "build_module", "build_scene", "build_trainer",
           "plan_schedule"]
