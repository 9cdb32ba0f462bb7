"""The training command, ``python train.py`` / ``sdfdiff-train`` (configs/train.yaml): hydra
composes the config, ``run`` gets it as ``TrainSettings``, writes the run's ``config.yaml`` and
trains the three-stage schedule (``svr.training.stages.train``) in hydra's run folder:
``<paths.output_dir>/train/<time>`` for a new run, the run's own folder when ``ckpt_path`` names
one (a resume), one folder per job with ``-m``. A run that fails before its first checkpoint
removes the stage folders it made (the command's error handling its records): nothing in the
folder stops the same command from running again."""
from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from sdfcommon.tooling.commands import hydra_entry
from sdfcommon.tooling.outputs import write_text
from svr.distributed import launch_rank_is_zero
from svr.training.resume import requeued_run, resumed_settings
from svr.training.run_folder import RunFolder
from svr.training.settings import TrainSettings
from svr.training.stages import train

log = logging.getLogger(__name__)


def run(settings: TrainSettings) -> float | None:
    """Trains in hydra's run folder; returns the last stage's best validation IoU (for hydra
    sweepers)."""
    hydra_cfg = HydraConfig.get()
    folder = RunFolder(Path(hydra_cfg.runtime.output_dir).resolve())
    if settings.ckpt_path is None:
        requeued = requeued_run(os.environ, settings.paths.output_dir)
        if requeued is not None and requeued.root.resolve() == folder.root:
            settings = settings.with_ckpt_path(str(folder.root))  # a requeued SLURM job goes on
    # Rank zero only: it writes config.yaml before the other processes of a DDP run start or look.
    # A run that never reached a checkpoint holds nothing to resume and is no obstacle.
    if settings.ckpt_path is None and launch_rank_is_zero() and folder.holds_run() and folder.holds_checkpoint():
        raise ValueError(f"hydra.run.dir={folder.root} already holds a training run: resume it with "
                         f"ckpt_path={folder.root}, or give another hydra.run.dir")
    settings, record = resumed_settings(settings, folder, list(hydra_cfg.overrides.task))
    made = [d for d in folder.stage_dirs() if not d.exists()]
    if launch_rank_is_zero():
        folder.root.mkdir(parents=True, exist_ok=True)
        write_text(folder.config, OmegaConf.to_yaml(record))
    try:
        result = train(settings, folder.root)
    except Exception:
        # Failed before its first checkpoint (a data or setting error): what the stages made goes,
        # and the command's error handling removes the records, so a retry finds the folder as it was.
        if launch_rank_is_zero() and not folder.holds_checkpoint():
            for stage_dir in made:
                shutil.rmtree(stage_dir, ignore_errors=True)
        raise
    for s in result.stages:
        log.info("%s: best val IoU %s  best %s  final %s", s.stage, s.best_val_iou, s.best, s.final)
    print(f"run folder: {result.run_dir}")
    return result.stages[-1].best_val_iou if result.stages else None


main = hydra_entry("train", run)


if __name__ == "__main__":
    main()
