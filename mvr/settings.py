"""The multi-view command's typed settings: ``MVRSettings``, built from configs/mvr.yaml by
``sdfcommon.tooling.settings.build_settings`` (an unknown, mistyped or out-of-range value fails
before anything is written), its ``RuntimeSettings``, the ``${mvr_shapes:}`` resolver its --help
lists the built-in shapes with, and the helpers benchmarks and tests use to run exactly the
command's settings (``compose_config``, ``reconstruct_kwargs``, ``reconstruct_with_overrides``)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

from omegaconf import DictConfig, OmegaConf

from mvr.optimize import OptimSettings
from mvr.reconstruct import (GridSettings, NoiseSettings, ReconstructionResult, RigSettings, ScoringSettings,
                             TargetSettings, check_run_settings, reconstruct)
from mvr.schedule import Schedule
from mvr.shapes import SHAPES
from renderer import Scene, TraceSettings
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.settings import PathSettings, build_settings


@dataclass(frozen=True)
class RuntimeSettings:
    """How the process runs (``mvr.configure_runtime``): ``threads`` for torch and numba (None:
    every core this process may use), glibc's heap kept (``tune_malloc``), denormal floats flushed."""

    threads: Optional[int]
    tune_malloc: bool
    flush_denormal: bool

    def __post_init__(self) -> None:
        if self.threads is not None:
            check_int(self.threads, "runtime.threads", 1)


@dataclass(frozen=True)
class MVRSettings:
    """The multi-view command's settings (configs/mvr.yaml; its comments say more).

    Every setting but the target is checked when the settings are made (``__post_init__``: what
    each object checks itself, then ``mvr.reconstruct.check_run_settings``), before the command
    makes its folder; the target when the run starts, before it writes anything.

    Attributes:
        target: a built-in shape (``mvr.SHAPES``) or a watertight mesh file.
        out_dir: the run's folder (a rerun resumes after its last finished level).
        seed, resume, progress, backend: as ``mvr.reconstruct``'s.
        runtime: as ``RuntimeSettings``. paths: as ``PathSettings``.
        rig, grid, target_settings, schedule, optim, noise, evaluation, scene, trace: the settings
            objects ``mvr.reconstruct`` takes under those names.
    """

    target: str
    out_dir: str
    seed: int
    resume: bool
    progress: bool
    backend: str
    runtime: RuntimeSettings
    rig: RigSettings
    grid: GridSettings
    target_settings: TargetSettings
    schedule: Schedule
    optim: OptimSettings
    noise: NoiseSettings
    evaluation: ScoringSettings
    scene: Scene
    trace: TraceSettings
    paths: PathSettings

    def __post_init__(self) -> None:
        # Made when the settings are built: before the run folder is made
        # (sdfcommon.tooling.commands.RunFolderGuard) and before any work. The target is checked
        # when the run starts (mvr.make_target, before anything is written): settings name it
        # without reading the file system (benchmarks build them with a placeholder target).
        check_run_settings(scene=self.scene, optim=self.optim, target_settings=self.target_settings, grid=self.grid,
                           backend=self.backend, seed=self.seed)


# The fields of MVRSettings that are keyword arguments of mvr.reconstruct (target and out_dir aside).
RECONSTRUCT_KEYS = ("rig", "grid", "target_settings", "schedule", "optim", "noise", "evaluation", "scene", "trace",
                    "backend", "seed", "resume", "progress")


def reconstruct_kwargs(settings: Union[MVRSettings, DictConfig]) -> dict:
    """The keyword arguments of ``mvr.reconstruct`` (all but target and out_dir) from the command's
    settings, or from a composed mvr config (built into them first, ``build_settings``)."""
    if isinstance(settings, DictConfig):
        settings = build_settings(settings)
    return {key: getattr(settings, key) for key in RECONSTRUCT_KEYS}


def compose_config(overrides: Sequence[str] = ()) -> DictConfig:
    """configs/mvr.yaml with hydra overrides, outside a hydra run (for benchmarks and tests)."""
    return compose("mvr", overrides)


def reconstruct_with_overrides(target: str, out_dir: Union[str, Path],
                               overrides: Sequence[str] = ()) -> ReconstructionResult:
    """One multi-view reconstruction in this process, with the settings of
    ``python -m mvr target=<target> out_dir=<out_dir> progress=false <overrides>`` (configs/mvr.yaml,
    composed and built as the command does). The caller sets the process-wide runtime first
    (``mvr.configure_runtime``, as the command does from ``runtime.*``).

    Returns:
        the run's result; its ``metrics`` are what it writes to ``<out_dir>/metrics.json``.
    """
    cfg = compose_config([f"target={target}", f"out_dir={out_dir}", "progress=false", *overrides])
    return reconstruct(target, out_dir, **reconstruct_kwargs(cfg))


# ${mvr_shapes:} in configs/mvr.yaml's help: the built-in shapes, as mvr.shapes defines them.
OmegaConf.register_new_resolver("mvr_shapes", lambda: ", ".join(SHAPES), replace=True)


__all__ = ["MVRSettings", "RuntimeSettings", "RECONSTRUCT_KEYS", "reconstruct_kwargs", "compose_config",
           "reconstruct_with_overrides"]
