"""Command line: ``python -m mvr target=<shape or mesh file> out_dir=<folder> [hydra overrides]``.

The only place in mvr that reads hydra configuration (configs/mvr.yaml and the groups under
configs/mvr/); everything below it takes plain objects. The console script ``sdfdiff-mvr`` is
this ``main``, with the same overrides. Benchmarks reuse ``compose_config`` and
``reconstruct_kwargs`` so that they run with exactly the command's settings.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Sequence

import hydra
from omegaconf import DictConfig

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"


def reconstruct_kwargs(cfg: DictConfig) -> dict:
    """The keyword arguments of ``mvr.reconstruct`` (all but target and out_dir), instantiated
    from a composed mvr config (``_target_`` nodes -> plain objects)."""
    from hydra.utils import instantiate

    return dict(
        rig=instantiate(cfg.rig),
        grid=instantiate(cfg.grid),
        target_settings=instantiate(cfg.target_settings),
        schedule=instantiate(cfg.schedule, _convert_="all"),
        optim=instantiate(cfg.optim, _convert_="all"),
        noise=instantiate(cfg.noise),
        evaluation=instantiate(cfg.evaluation, _convert_="all"),
        scene=instantiate(cfg.scene, _convert_="all"),
        trace=instantiate(cfg.trace),
        backend=str(cfg.backend),
        seed=int(cfg.seed),
        resume=bool(cfg.resume),
        progress=bool(cfg.progress),
    )


def compose_config(overrides: Sequence[str] = ()) -> DictConfig:
    """configs/mvr.yaml with hydra overrides, outside a hydra run (for benchmarks and tests)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose(config_name="mvr", overrides=list(overrides))


# An absolute path: a relative one would resolve against the package when main() runs as the
# console script (hydra then looks for a Python package "configs").
@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="mvr")
def main(cfg: DictConfig) -> float:
    """Runs one reconstruction; returns its relative Hausdorff distance (for hydra sweepers)."""
    from .reconstruct import reconstruct
    from .runtime import configure_runtime

    configure_runtime(cfg.runtime.threads, cfg.runtime.tune_malloc, cfg.runtime.flush_denormal)
    result = reconstruct(str(cfg.target), cfg.out_dir, **reconstruct_kwargs(cfg))
    m = result.metrics
    logging.getLogger("mvr").info("wrote %s", result.out_dir)
    print(f"hausdorff_rel={m.get('hausdorff_rel')} chamfer_rel={m.get('chamfer_rel')} "
          f"seconds={m['seconds']:.1f} out_dir={result.out_dir}")
    value = m.get("hausdorff_rel")
    return float("nan") if value is None else float(value)


if __name__ == "__main__":
    main()
