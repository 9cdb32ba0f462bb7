"""The mesh-to-NMR builder, ``python -m svr.data.build input=MESHES out=DATA`` / ``sdfdiff-build``
(configs/build.yaml, whose comments show the command lines): turns a folder of meshes (ShapeNetCore
v1 or v2, or ``<category>/<name>.obj|off|ply|stl|glb``) into the NMR format that ``svr.nmr.format``
reads, with a manifest row per mesh (``svr.data.build.dataset.build_dataset``), and prints the
objects per category and split. A mistake in the settings or files is one line ``sdfdiff-build:
error: ...`` with exit status 2; a mesh that cannot be built is a skipped row, counted at the end. A
build stopped by Ctrl+C or SIGTERM says so in one line (exit status 130 or 143) and a rerun of the
same command continues it. What it prints is also in ``DATA/build.log``."""
from __future__ import annotations

import logging
import sys
from pathlib import Path

from sdfcommon.tooling.commands import hydra_entry
from sdfcommon.tooling.stopping import sigterm_as_interrupt, stop_name, stop_signal
from svr.data.build.dataset import MANIFEST_FILE, BuildReport, build_dataset, build_progress
from svr.data.build.settings import BuildSettings
from svr.nmr.format import SPLITS

log = logging.getLogger("svr.data.build")


def _say(line: str, err: bool = False) -> None:
    """A line for the console and the build's log (hydra's file handler; configs/build.yaml keeps
    the console handler to warnings, so the line is not printed twice)."""
    print(line, file=sys.stderr if err else sys.stdout, flush=True)
    log.info(line)


def _print_report(report: BuildReport) -> None:
    names = dict(report.categories)
    width = max([len(f"{cid} ({names[cid]})") for cid in report.sizes] + [len("category")])
    _say(f"  {'category':<{width}}" + "".join(f"{split:>7}" for split in SPLITS))
    for cid, counts in report.sizes.items():
        _say(f"  {f'{cid} ({names[cid]})':<{width}}" + "".join(f"{counts[split]:>7}" for split in SPLITS))
    for warning in report.warnings:
        _say(f"warning: {warning}", err=True)


def run(settings: BuildSettings) -> BuildReport:
    """Builds the folder and prints what it made (see the module docstring).

    Raises:
        SystemExit: 128 + the signal's number when Ctrl+C or SIGTERM stopped the build.
    """
    try:
        with sigterm_as_interrupt():
            report = build_dataset(settings)
    except KeyboardInterrupt as stop:  # Ctrl+C, or SIGTERM (sdfcommon.tooling.stopping.Terminated)
        signum = stop_signal(stop)
        out = Path(settings.out).expanduser()
        done, planned = build_progress(out)
        where = f"after {done} of {planned} objects (kept in {out}/.build)" if planned else "before its first object"
        _say(f"build stopped by {stop_name(signum)} {where}; rerunning the same command continues it", err=True)
        raise SystemExit(128 + signum) from None
    if report.already_built:
        _say(f"{report.out} already holds this build ({report.built} objects); nothing to do")
        _print_report(report)
        return report
    n_skipped = sum(report.skipped.values())
    _say(f"built {report.built} objects, skipped {n_skipped}, left out {report.left_out} -> {report.out}")
    _print_report(report)
    for reason, count in sorted(report.skipped.items(), key=lambda kv: -kv[1])[:5]:
        _say(f"  skipped {count}: {reason}")
    if n_skipped or report.left_out:
        _say(f"  every mesh's row: {report.out / MANIFEST_FILE}")
    return report


main = hydra_entry("build", run)


if __name__ == "__main__":
    main()


__all__ = ["run", "main"]
