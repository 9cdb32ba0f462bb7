"""Command line: ``python -m mvr target=<shape or mesh file> out_dir=<folder> [hydra overrides]``.

The only place in mvr that reads hydra configuration (configs/mvr.yaml and the groups under
configs/mvr/); everything below it takes plain objects. The console script ``sdfdiff-mvr`` is
this ``main``, with the same overrides.
"""
from __future__ import annotations

import logging

import hydra
from omegaconf import DictConfig


@hydra.main(version_base="1.3", config_path="../configs", config_name="mvr")
def main(cfg: DictConfig) -> float:
    """Runs one reconstruction; returns its relative Hausdorff distance (for hydra sweepers)."""
    from hydra.utils import instantiate

    from .reconstruct import reconstruct
    from .runtime import configure_runtime

    configure_runtime(cfg.runtime.threads, cfg.runtime.tune_malloc)
    result = reconstruct(
        str(cfg.target),
        cfg.out_dir,
        rig=instantiate(cfg.rig),
        grid=instantiate(cfg.grid),
        target_settings=instantiate(cfg.target_settings),
        schedule=instantiate(cfg.schedule, _convert_="all"),
        optim=instantiate(cfg.optim, _convert_="all"),
        noise=instantiate(cfg.noise),
        evaluation=instantiate(cfg.evaluation, _convert_="all"),
        scene=instantiate(cfg.scene, _convert_="all"),
        trace=instantiate(cfg.trace),
        backend=cfg.backend,
        seed=int(cfg.seed),
        resume=bool(cfg.resume),
        progress=bool(cfg.progress),
    )
    m = result.metrics
    logging.getLogger("mvr").info("wrote %s", result.out_dir)
    print(f"hausdorff_rel={m.get('hausdorff_rel')} chamfer_rel={m.get('chamfer_rel')} "
          f"seconds={m['seconds']:.1f} out_dir={result.out_dir}")
    value = m.get("hausdorff_rel")
    return float("nan") if value is None else float(value)


if __name__ == "__main__":
    main()
