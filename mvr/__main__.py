"""The multi-view command, ``python -m mvr target=<shape or mesh file> [out_dir=<folder>]`` /
``sdfdiff-mvr`` (configs/mvr.yaml and the groups under configs/mvr/): hydra composes the config,
``run`` gets it as ``MVRSettings`` (built by ``sdfcommon.tooling.settings.build_settings``: an unknown
or mistyped key fails before out_dir is made), sets up the process (``mvr.configure_runtime``) and
reconstructs (``mvr.reconstruct``) into ``out_dir``, by default ``<paths.output_dir>/mvr/<time>``. The
only place in mvr that reads hydra configuration; benchmarks reuse ``compose_config`` and
``reconstruct_kwargs`` so that they run with exactly the command's settings. Errors in settings or
files (missing, empty or non-watertight mesh, unknown shape, a rerun into an out_dir of other
settings, a corrupt level checkpoint, ``optim.lr=fast``) are one line ``sdfdiff-mvr: error: ...``
with exit status 2, and a refused run leaves out_dir as it was (``sdfcommon.tooling.commands``)."""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional, Sequence, Union

from omegaconf import DictConfig

from mvr import (EvalSettings, GridSettings, NoiseSettings, OptimSettings, RigSettings, Schedule, TargetSettings,
                 configure_runtime, reconstruct)
from renderer import Scene, TraceSettings
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.commands import compose, hydra_entry
from sdfcommon.tooling.settings import PathSettings, build_settings

log = logging.getLogger("mvr")


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
    evaluation: EvalSettings
    scene: Scene
    trace: TraceSettings
    paths: PathSettings


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


def run(settings: MVRSettings) -> float:
    """Runs one reconstruction; returns its relative Hausdorff distance (for hydra sweepers)."""
    configure_runtime(settings.runtime.threads, settings.runtime.tune_malloc, settings.runtime.flush_denormal)
    result = reconstruct(settings.target, settings.out_dir, **reconstruct_kwargs(settings))
    m = result.metrics
    log.info("wrote %s", result.out_dir)
    print(f"hausdorff_rel={m.get('hausdorff_rel')} chamfer_rel={m.get('chamfer_rel')} "
          f"seconds={m['seconds']:.1f} out_dir={result.out_dir}")
    value = m.get("hausdorff_rel")
    return float("nan") if value is None else float(value)


main = hydra_entry("mvr", run)


if __name__ == "__main__":
    main()


__all__ = ["MVRSettings", "RuntimeSettings", "reconstruct_kwargs", "compose_config", "run", "main"]
