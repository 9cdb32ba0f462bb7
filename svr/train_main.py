"""The training entry point: ``python train.py`` or the ``sdfdiff-train`` console script.

Composes configs/train.yaml with the command-line overrides (hydra), then runs
``svr.training.train`` in hydra's run folder (``outputs/train/<time>`` by default; one folder per
job with ``-m``).
"""
from __future__ import annotations

import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig

CONFIG_DIR = str(Path(__file__).resolve().parents[1] / "configs")

log = logging.getLogger(__name__)


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def main(cfg: DictConfig) -> float | None:
    """Trains; returns the last stage's best validation IoU (hydra sweepers can optimise it)."""
    from hydra.core.hydra_config import HydraConfig

    from .training import train

    result = train(cfg, HydraConfig.get().runtime.output_dir)
    for s in result.stages:
        log.info("%s: best val IoU %s  best %s  final %s", s.stage, s.best_val_iou, s.best, s.final)
    print(f"run folder: {result.run_dir}")
    return result.stages[-1].best_val_iou if result.stages else None


if __name__ == "__main__":
    main()
