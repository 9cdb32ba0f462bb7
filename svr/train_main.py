"""The training entry point: ``python train.py`` or the ``sdfdiff-train`` console script.

Composes configs/train.yaml with the command-line overrides (hydra), then runs
``svr.training.train`` in hydra's run folder (``outputs/train/<time>`` by default; one folder per
job with ``-m``).

Resuming: ``ckpt_path=RUN`` (a run folder) or ``ckpt_path=RUN/<stage>/checkpoints/last.ckpt``
continues that run in its own folder, with its saved ``config.yaml``; the command line may change
only ``svr.training.RESUMABLE_KEYS`` (each change is logged as a warning). hydra's ``.hydra/``
record of the original run is left as it was. SLURM batch jobs: see ``slurm_arguments``.
"""
from __future__ import annotations

import logging
import os
import sys
from pathlib import Path
from typing import Mapping, Optional, Sequence

from omegaconf import DictConfig, OmegaConf

from sdfcommon.cli import hydra_entry

CONFIG_DIR = str(Path(__file__).resolve().parents[1] / "configs")

log = logging.getLogger(__name__)


def _override_value(argv: Sequence[str], key: str) -> Optional[str]:
    """The value of a ``key=value`` (or ``+key=value``) command-line override, the last one wins."""
    value = None
    for arg in argv:
        for prefix in (f"{key}=", f"+{key}=", f"++{key}="):
            if arg.startswith(prefix):
                value = arg[len(prefix):].strip("'\"")
    return value


def resume_arguments(argv: Sequence[str]) -> list[str]:
    """The hydra overrides that make a resume command run in the resumed run's own folder.

    ``ckpt_path`` naming a run folder, or a checkpoint inside one, resumes that run: hydra's run
    folder becomes it (unless ``hydra.run.dir`` is given: then the run is continued in a new
    folder), and hydra does not rewrite its ``.hydra/``. Nothing for multirun (``-m``).
    """
    from .training import run_folder_of

    if "-m" in argv or "--multirun" in argv or any(a.startswith("hydra.run.dir=") for a in argv):
        return []
    ckpt = _override_value(argv, "ckpt_path")
    if ckpt in (None, "", "null"):
        return []
    path = Path(ckpt).expanduser()
    run = path.resolve() if (path / "config.yaml").is_file() else run_folder_of(path)
    if run is None:
        return []
    quoted = str(run).replace("\\", "\\\\").replace("'", "\\'")
    return [f"hydra.run.dir='{quoted}'", "hydra.output_subdir=null"]


def resumed_config(cfg: DictConfig, run_dir: Path, overrides: Sequence[str]) -> DictConfig:
    """``cfg`` for a fresh run; for a run resumed in its own folder, the folder's ``config.yaml``
    with the changes the command line may make (``svr.training.resume_config``), each logged."""
    from .training import resume_config, run_folder_of

    ckpt = cfg.get("ckpt_path")
    if ckpt is None:
        return cfg
    path = Path(ckpt).expanduser()
    run = path.resolve() if (path / "config.yaml").is_file() else run_folder_of(path)
    if run is None or run != run_dir.resolve():
        return cfg
    saved = OmegaConf.load(run / "config.yaml")
    merged, changes = resume_config(saved, cfg, overrides)
    for change in changes:
        log.warning("resuming %s with a changed setting: %s", run, change)
    return merged


def slurm_arguments(argv: Sequence[str], environ: Mapping[str, str]) -> list[str]:
    """The hydra overrides that let SLURM's requeue continue a run (as Lightning intends: on the
    signal SLURM sends before the time limit, ``#SBATCH --signal=SIGUSR1@90``, Lightning saves
    ``<stage>/hpc_ckpt_<n>.ckpt`` and requeues the job; at the limit, SIGTERM saves ``last.ckpt``).

    In a SLURM batch job (not an interactive one, as Lightning tells them apart) the run folder is
    ``outputs/train/slurm-<job id>`` (``<array job>_<task>`` for arrays) unless ``hydra.run.dir``
    is given, so the requeued job finds it; when the job was requeued (``SLURM_RESTART_COUNT`` > 0)
    and names no ``ckpt_path``, it resumes that folder's latest checkpoint.
    """
    job = environ.get("SLURM_JOB_ID")
    if not job or environ.get("SLURM_JOB_NAME") in ("bash", "interactive"):
        return []
    if "-m" in argv or "--multirun" in argv or any(a.startswith("hydra.run.dir=") for a in argv):
        return []
    if environ.get("SLURM_ARRAY_JOB_ID") and environ.get("SLURM_ARRAY_TASK_ID"):
        job = f"{environ['SLURM_ARRAY_JOB_ID']}_{environ['SLURM_ARRAY_TASK_ID']}"
    run = Path("outputs") / "train" / f"slurm-{job}"
    out = [f"hydra.run.dir={run}"]
    requeued = int(environ.get("SLURM_RESTART_COUNT") or 0) > 0
    if requeued and _override_value(argv, "ckpt_path") in (None, "", "null") and (run / "config.yaml").is_file():
        out += [f"ckpt_path={run}", "hydra.output_subdir=null"]
    return out


def run(cfg: DictConfig) -> float | None:
    """Trains in hydra's run folder (see the module docstring); returns the last stage's best
    validation IoU (for hydra sweepers)."""
    from hydra.core.hydra_config import HydraConfig

    from .distributed import launch_rank_is_zero
    from .training import train

    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    # Rank zero only: it writes config.yaml before the other processes of a DDP run start or look.
    if cfg.get("ckpt_path") is None and launch_rank_is_zero() and (run_dir / "config.yaml").is_file():
        raise ValueError(f"hydra.run.dir={run_dir} already holds a training run: resume it with "
                         f"ckpt_path={run_dir}, or give another hydra.run.dir")
    cfg = resumed_config(cfg, run_dir, list(hydra_cfg.overrides.task))
    result = train(cfg, run_dir)
    for s in result.stages:
        log.info("%s: best val IoU %s  best %s  final %s", s.stage, s.best_val_iou, s.best, s.final)
    print(f"run folder: {result.run_dir}")
    return result.stages[-1].best_val_iou if result.stages else None


_hydra_main = hydra_entry("sdfdiff-train", "train", run)


def main() -> None:
    """``python train.py`` / ``sdfdiff-train``: SLURM and resume settings (``slurm_arguments``,
    ``resume_arguments``) added to the command line, then hydra and ``run`` under the shared error
    handling of every entry point (``sdfcommon.cli``: a user's mistake is one line, exit status 2;
    a SIGTERM exits 143)."""
    argv = list(sys.argv)
    sys.argv.extend(slurm_arguments(sys.argv[1:], os.environ))
    sys.argv.extend(resume_arguments(sys.argv[1:]))
    try:
        _hydra_main()
    finally:
        sys.argv[:] = argv


if __name__ == "__main__":
    main()
