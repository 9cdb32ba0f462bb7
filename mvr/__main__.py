"""Command line: ``python -m mvr target=<shape or mesh file> out_dir=<folder> [hydra overrides]``.

The only place in mvr that reads hydra configuration (configs/mvr.yaml and the groups under
configs/mvr/); everything below it takes plain objects. The console script ``sdfdiff-mvr`` is
this ``main``, with the same overrides. Benchmarks reuse ``compose_config`` and
``reconstruct_kwargs`` so that they run with exactly the command's settings.

Errors in settings or files (missing, empty or non-watertight mesh, unknown shape, a rerun into an
out_dir of other settings, a corrupt level checkpoint, ``optim.lr=fast``) are one line
``sdfdiff-mvr: error: ...`` with exit status 2, and a refused run leaves out_dir as it was
(``sdfcommon.tooling.commands``).
"""
from __future__ import annotations

import logging
from typing import Sequence

from omegaconf import DictConfig

from sdfcommon.tooling.commands import compose, config_bool, config_int, config_object, config_value, hydra_entry

# The settings nodes (each a ``_target_``) and the keyword of ``mvr.reconstruct`` they become.
SETTINGS_NODES = {"rig": "rig", "grid": "grid", "target_settings": "target_settings", "schedule": "schedule",
                  "optim": "optim", "noise": "noise", "evaluation": "evaluation", "scene": "scene",
                  "trace": "trace"}


def reconstruct_kwargs(cfg: DictConfig) -> dict:
    """The keyword arguments of ``mvr.reconstruct`` (all but target and out_dir), instantiated
    from a composed mvr config (``_target_`` nodes -> plain objects, their values checked against
    the settings' field types first: ``sdfcommon.tooling.commands.config_object``)."""
    kwargs = {name: config_object(cfg, key, _convert_="all") for key, name in SETTINGS_NODES.items()}
    return dict(kwargs, backend=str(config_value(cfg, "backend")), seed=config_int(cfg, "seed"),
                resume=config_bool(cfg, "resume"), progress=config_bool(cfg, "progress"))


def compose_config(overrides: Sequence[str] = ()) -> DictConfig:
    """configs/mvr.yaml with hydra overrides, outside a hydra run (for benchmarks and tests)."""
    return compose("mvr", overrides)


def run(cfg: DictConfig) -> float:
    """Runs one reconstruction; returns its relative Hausdorff distance."""
    from .reconstruct import reconstruct
    from .runtime import configure_runtime

    kwargs = reconstruct_kwargs(cfg)
    threads = config_value(cfg, "runtime.threads")  # null: every core (mvr.runtime.available_cores)
    configure_runtime(None if threads is None else config_int(cfg, "runtime.threads", minimum=1),
                      config_bool(cfg, "runtime.tune_malloc"), config_bool(cfg, "runtime.flush_denormal"))
    result = reconstruct(str(config_value(cfg, "target")), str(config_value(cfg, "out_dir")), **kwargs)
    m = result.metrics
    logging.getLogger("mvr").info("wrote %s", result.out_dir)
    print(f"hausdorff_rel={m.get('hausdorff_rel')} chamfer_rel={m.get('chamfer_rel')} "
          f"seconds={m['seconds']:.1f} out_dir={result.out_dir}")
    value = m.get("hausdorff_rel")
    return float("nan") if value is None else float(value)


main = hydra_entry("sdfdiff-mvr", "mvr", run)


if __name__ == "__main__":
    main()
