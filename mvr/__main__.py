"""The multi-view command, ``python -m mvr target=<shape or mesh file> [out_dir=<folder>]`` /
``sdfdiff-mvr`` (configs/mvr.yaml and the groups under configs/mvr/): hydra composes the config,
``run`` gets it as ``mvr.settings.MVRSettings`` (an unknown or mistyped key fails before out_dir is
made), sets up the process (``mvr.configure_runtime``) and
reconstructs (``mvr.reconstruct``) into ``out_dir``, by default ``<paths.output_dir>/mvr/<time>``. The
only place in mvr that reads hydra configuration; benchmarks run with exactly the command's
settings through ``mvr.reconstruct_with_overrides`` (``compose_config``, ``reconstruct_kwargs``).
Errors in settings or files (missing, empty or non-watertight mesh, unknown shape, a rerun into an
out_dir of other settings, a corrupt level checkpoint, ``optim.lr=fast``) are one line
``sdfdiff-mvr: error: ...`` with exit status 2, and a refused run leaves out_dir as it was
(``sdfcommon.tooling.commands``)."""
from __future__ import annotations

import logging

from mvr.reconstruct import reconstruct
from mvr.runtime import configure_runtime
from mvr.settings import MVRSettings, reconstruct_kwargs
from sdfcommon.tooling.commands import hydra_entry

log = logging.getLogger("mvr")


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


__all__ = ["run", "main"]
