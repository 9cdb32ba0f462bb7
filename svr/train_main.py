"""The training entry point: ``python train.py`` or the ``sdfdiff-train`` console script.

Composes configs/train.yaml with the command-line overrides (hydra), then runs
``svr.training.train`` in hydra's run folder (``outputs/train/<time>`` by default; one folder per
job with ``-m``).

Resuming: ``ckpt_path=RUN`` (a run folder) or ``ckpt_path=RUN/<stage>/checkpoints/last.ckpt``
continues that run in its own folder, with its saved ``config.yaml``; the command line may change
only ``svr.training.RESUMABLE_KEYS`` (each change is logged as a warning). hydra's ``.hydra/``
record of the original run is left as it was.
"""
from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Optional, Sequence

import hydra
from omegaconf import DictConfig, OmegaConf

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


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def _main(cfg: DictConfig) -> float | None:
    from hydra.core.hydra_config import HydraConfig

    from .training import train

    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    cfg = resumed_config(cfg, run_dir, list(hydra_cfg.overrides.task))
    result = train(cfg, run_dir)
    for s in result.stages:
        log.info("%s: best val IoU %s  best %s  final %s", s.stage, s.best_val_iou, s.best, s.final)
    print(f"run folder: {result.run_dir}")
    return result.stages[-1].best_val_iou if result.stages else None


def main() -> float | None:
    """Trains; returns the last stage's best validation IoU (hydra sweepers can optimise it)."""
    sys.argv.extend(resume_arguments(sys.argv[1:]))
    return _main()


if __name__ == "__main__":
    main()
