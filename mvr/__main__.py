"""The multi-view command, ``python -m mvr target=<shape or mesh file> [out_dir=<folder>]`` /
``sdfdiff-mvr`` (configs/mvr.yaml and the groups under configs/mvr/): hydra composes the config,
``run`` gets it as ``mvr.settings.MVRSettings`` (an unknown or mistyped key fails before out_dir is
made), sets up the process (``mvr.configure_runtime``) and
reconstructs (``mvr.reconstruct``) into ``out_dir``, by default ``<paths.output_dir>/mvr/<time>``. The
only place in mvr that reads hydra configuration; benchmarks run with exactly the command's
settings through ``mvr.reconstruct_with_overrides`` (``compose_config``, ``reconstruct_kwargs``).
Errors in settings or files (missing, empty or non-watertight mesh, unknown shape, a rerun into an
out_dir of other settings, a corrupt level checkpoint, ``optim.lr=fast``, ``seed=-1``) are one line
``sdfdiff-mvr: error: ...`` with exit status 2, and a refused run leaves out_dir as it was
(``sdfcommon.tooling.commands``); every setting is checked before any work (``MVRSettings``). Ctrl+C
or SIGTERM stops a run with one line that says after which level and how to resume (rerunning the
same command, with its out_dir, resumes after the last finished level), exit status 130 or 143."""
from __future__ import annotations

import logging
import os
import shlex
import signal
import sys

from hydra.core.hydra_config import HydraConfig

from mvr.reconstruct import finished_levels, reconstruct, stage_count
from mvr.runtime import configure_runtime
from sdfcommon.tooling.stopping import sigterm_as_interrupt, stop_signal
from mvr.settings import MVRSettings, reconstruct_kwargs
from sdfcommon.tooling.commands import hydra_entry

log = logging.getLogger("mvr")


def run(settings: MVRSettings) -> float:
    """Runs one reconstruction; returns its relative Hausdorff distance (for hydra sweepers)."""
    try:
        with sigterm_as_interrupt():
            configure_runtime(settings.runtime.threads, settings.runtime.tune_malloc,
                              settings.runtime.flush_denormal)
            result = reconstruct(settings.target, settings.out_dir, **reconstruct_kwargs(settings))
    except KeyboardInterrupt as stop:  # Ctrl+C, or SIGTERM (sdfcommon.tooling.stopping.Terminated)
        signum = stop_signal(stop)
        print(f"{_prog()}: {stopped_message(settings, signum)}", file=sys.stderr, flush=True)
        raise SystemExit(128 + signum) from None
    m = result.metrics
    log.info("wrote %s", result.out_dir)
    print(f"hausdorff_rel={m.get('hausdorff_rel')} chamfer_rel={m.get('chamfer_rel')} "
          f"seconds={m['seconds']:.1f} out_dir={result.out_dir}")
    value = m.get("hausdorff_rel")
    return float("nan") if value is None else float(value)


def stopped_message(settings: MVRSettings, signum: int) -> str:
    """What a run stopped by ``signum`` says: after which level, and the command that resumes it
    (with out_dir named: the default one is new each time)."""
    how = "Ctrl+C" if signum == signal.SIGINT else signal.Signals(signum).name
    out = shlex.quote(f"out_dir={os.path.abspath(settings.out_dir)}")
    done, levels = finished_levels(settings.out_dir), stage_count(settings.schedule, settings.optim)
    if not done:
        return (f"stopped by {how} before level 1 of {levels} finished (nothing to resume); rerun the same "
                f"command with {out} to start again")
    resume = "" if settings.resume else " resume=true"
    return (f"stopped by {how} after level {done} of {levels}; rerun the same command with {out}{resume} "
            f"to resume after it")


def _prog() -> str:
    """The command's name in messages (configs/mvr.yaml's ``hydra.help.app_name``)."""
    return str(HydraConfig.get().help.app_name) if HydraConfig.initialized() else "sdfdiff-mvr"


main = hydra_entry("mvr", run)


if __name__ == "__main__":
    main()


__all__ = ["run", "main", "stopped_message"]
