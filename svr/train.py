"""The training command, ``python train.py`` / ``sdfdiff-train`` (configs/train.yaml): hydra
composes the config and ``run`` trains the three-stage schedule (``svr.training.stages.train``) in
hydra's run folder, ``outputs/train/<time>`` by default, one folder per job with ``-m``."""
from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from sdfcommon.tooling.commands import hydra_entry
from svr.distributed import launch_rank_is_zero
from svr.training.resume import resume_arguments, resumed_config, slurm_arguments
from svr.training.stages import train

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> float | None:
    """Trains in hydra's run folder; returns the last stage's best validation IoU (for hydra
    sweepers)."""
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
    handling of every entry point (a user's mistake is one line, exit status 2; a SIGTERM exits 143)."""
    argv = list(sys.argv)
    sys.argv.extend(slurm_arguments(sys.argv[1:], os.environ))
    sys.argv.extend(resume_arguments(sys.argv[1:]))
    try:
        _hydra_main()
    finally:
        sys.argv[:] = argv


if __name__ == "__main__":
    main()
