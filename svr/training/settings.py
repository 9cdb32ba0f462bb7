"""The typed settings of training (configs/train.yaml and its groups), built from the composed
config by ``sdfcommon.tooling.settings.build_settings``: ``TrainSettings`` holds the loss
(``LossSettings``), the stage schedule (``ScheduleSettings`` of ``StageSettings``) and, as
``_target_`` components the training instantiates when it needs them, the data module, the network,
the Lightning trainer, its callbacks and loggers. Every default is written once, in the YAML."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Optional, Union

import renderer
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.hardware import check_backend, check_cuda_devices
from sdfcommon.tooling.settings import Component, PathSettings, build_dataclass, settings_record
from svr.losses import LossWeights
from svr.models.checkpoint_layout import STAGES
from svr.nmr.format import IMAGE_SHAPE

SHADING_MODES = ("auto", True, False)
INIT_FROM = ("best", "final")
# Every dataset's images are NMR's 64^2 (svr.nmr.format); renders are area-downsampled images of them.
IMAGE_SIDE = IMAGE_SHAPE[-1]
GPU_ACCELERATORS = ("gpu", "cuda")


@dataclass(frozen=True)
class LossSettings:
    """The single-view loss and the renders it compares (configs/loss/).

    Attributes:
        weights: the terms' weights (``svr.losses.LossWeights``).
        shading: "auto" (shade where the data module knows its shading model and the shading
            weight is positive), True (require it) or False (silhouettes only).
        render_size: side of the training renders (the images are area-downsampled to it, so it
            divides their side, 64).
        silhouette_sigma: soft silhouette width in pixels.
        backend: the renderer's march ("auto", "reference", "cpu", "cuda").
        trace: how rays are marched (``renderer.TraceSettings``).
    """

    weights: LossWeights
    shading: Union[bool, str]
    render_size: int
    silhouette_sigma: float
    backend: str
    trace: renderer.TraceSettings

    def __post_init__(self) -> None:
        if not any(type(self.shading) is type(m) and self.shading == m for m in SHADING_MODES):
            raise ValueError(f"shading must be one of {', '.join(map(str, SHADING_MODES))}, got {self.shading!r}")
        check_int(self.render_size, "render_size", 1)
        if IMAGE_SIDE % self.render_size:
            sizes = ", ".join(str(d) for d in range(1, IMAGE_SIDE + 1) if IMAGE_SIDE % d == 0)
            raise ValueError(f"render_size must divide the images' side {IMAGE_SIDE} ({sizes}), "
                             f"got {self.render_size!r}")
        check_backend(self.backend)


@dataclass(frozen=True)
class StageSettings:
    """One stage of the schedule (configs/stage/).

    Attributes:
        max_steps: training steps of the stage.
        max_time: a wall-time cap ("DD:HH:MM:SS", Lightning's format), or None.
        optimizer: a partial optimiser (``_target_`` + ``_partial_``; the module gives the parameters).
        scheduler: a partial learning-rate schedule taking the optimiser, or None.
        loss: entries replacing the loss group's for this stage (e.g. {silhouette_sigma: 1.0}), or None.
    """

    max_steps: int
    max_time: Optional[str]
    optimizer: Component
    scheduler: Optional[Component]
    loss: Optional[dict]

    def __post_init__(self) -> None:
        check_int(self.max_steps, "max_steps", 1)
        if self.max_time is not None:
            parts = self.max_time.strip().split(":")
            if len(parts) != 4 or not all(p.isdigit() for p in parts) or not any(int(p) for p in parts):
                raise ValueError(f"max_time must be a duration 'DD:HH:MM:SS' longer than 0 (e.g. "
                                 f"'00:01:30:00', an hour and a half), got {self.max_time!r}")


@dataclass(frozen=True)
class ScheduleSettings:
    """The stage schedule: which stages run in order, how each hands its weights on, and each
    stage's settings."""

    schedule: list[str]
    init_from: str
    coarse: StageSettings
    refine: StageSettings
    joint: StageSettings

    def __post_init__(self) -> None:
        if not self.schedule:
            raise ValueError(f"schedule must name at least one of {STAGES}")
        for stage in self.schedule:
            if stage not in STAGES:
                raise ValueError(f"schedule must hold stages of {STAGES}, got {stage!r}")
        if len(set(self.schedule)) != len(self.schedule):
            raise ValueError(f"schedule must not repeat a stage, got {self.schedule}")
        if self.init_from not in INIT_FROM:
            raise ValueError(f"init_from must be one of {INIT_FROM}, got {self.init_from!r}")

    def of(self, stage: str) -> StageSettings:
        """The settings of one stage by name."""
        return getattr(self, stage)


@dataclass(frozen=True)
class TrainSettings:
    """The training command's settings (configs/train.yaml).

    Attributes:
        seed: seeds weights, sampling and each stage (seed + stage index); 0 .. 2^32 - 3.
        ckpt_path: a checkpoint (or run folder) to resume or to initialise from, or None.
        data, model, trainer: ``_target_`` components (a data module, an ``svr.models.SVRNet``,
            a ``pytorch_lightning.Trainer``; a GPU accelerator is refused where torch sees no GPU).
        callbacks, logger: name -> ``_target_`` component (None switches one off).
        loss, stage: as their classes say. paths: as ``PathSettings``.
    """

    seed: int
    ckpt_path: Optional[str]
    data: Component
    model: Component
    loss: LossSettings
    stage: ScheduleSettings
    trainer: Component
    callbacks: dict[str, Optional[Component]]
    logger: dict[str, Optional[Component]]
    paths: PathSettings

    def __post_init__(self) -> None:
        # seed + stage index seeds each stage, within numpy's range [0, 2^32 - 1]
        check_int(self.seed, "seed", 0, 2**32 - len(STAGES))
        accelerator = self.trainer.get("accelerator")
        if isinstance(accelerator, str) and accelerator.lower() in GPU_ACCELERATORS:
            devices = self.trainer.get("devices")
            count = (len(devices) if isinstance(devices, (list, tuple)) else
                     devices if isinstance(devices, int) and not isinstance(devices, bool) else 1)
            check_cuda_devices(f"trainer.accelerator={accelerator!r}" + (f" with trainer.devices={devices}"
                                                                       if count > 1 else ""), count,
                               "train on the CPU with trainer=cpu (it overrides an experiment's trainer=gpu too)")

    def stage_loss(self, stage: str) -> LossSettings:
        """The loss of one stage: ``loss`` with the stage's ``loss`` entries on top."""
        extra = self.stage.of(stage).loss
        if not extra:
            return self.loss
        merged = _merge(settings_record(self.loss), extra)
        return build_dataclass(LossSettings, merged, f"stage.{stage}.loss")

    def with_ckpt_path(self, ckpt_path: Optional[str]) -> "TrainSettings":
        """A copy that resumes from (or starts with the weights of) ``ckpt_path``."""
        return dataclasses.replace(self, ckpt_path=ckpt_path)


def _merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for k, v in extra.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


__all__ = ["LossSettings", "StageSettings", "ScheduleSettings", "TrainSettings", "SHADING_MODES", "INIT_FROM",
           "IMAGE_SIDE"]
