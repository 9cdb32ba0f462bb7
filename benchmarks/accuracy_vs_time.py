"""What accuracy costs in time: the study behind docs/accuracy_vs_time.md in one command,
``python -m benchmarks.accuracy_vs_time [--parts renderer,mvr,svr] [--quick] [--report-only]``
(``--help`` shows examples). Three parts, the renderer's (benchmarks/accuracy_vs_time_renderer.py),
multi-view reconstruction's (benchmarks/accuracy_vs_time_mvr.py) and single-view training's
(benchmarks/accuracy_vs_time_svr.py), each give a table, a plot (Pareto front marked, default
highlighted) and a reading. Each part runs as its own command, ``python -m
benchmarks.accuracy_vs_time_<part>``, in a process of its own, and keeps its section in
``<work>/sections/<part>.md`` (with ``<part>.json``: when and how long it ran), so that ``--parts``
reruns some parts and the report is assembled from the latest of each; the plots go to
``<docs>/study_*.png`` and the report to ``<docs>/accuracy_vs_time.md``, except that a ``--quick``
run writes to outputs/study_quick/ unless ``--docs`` says otherwise, so that it never replaces the
real report.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Optional, Sequence

from benchmarks.common import (StudySection, atomic_write_text, machine_info, parse_steps, progress_log,
                               study_folders)
import mvr

ROOT = Path(__file__).resolve().parents[1]
PARTS = ("renderer", "mvr", "svr")
REPORT = "accuracy_vs_time.md"
TITLES = {"renderer": "Renderer", "mvr": "Multi-view reconstruction", "svr": "Single-view reconstruction"}
COMMANDS = {"renderer": "--parts renderer", "mvr": "--parts mvr", "svr": "--parts svr"}


def parse_parts(text: str) -> tuple[str, ...]:
    """``"renderer,mvr"`` -> ("renderer", "mvr"), in the study's order; ValueError names unknown parts."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    unknown = [p for p in parts if p not in PARTS]
    if unknown or not parts:
        raise ValueError(f"parts must be a comma-separated subset of {','.join(PARTS)}, got {text!r}")
    return tuple(p for p in PARTS if p in parts)


def part_command(part: str, docs: Path, work: Path, quick: bool = False, cuda: bool = True,
                 svr_steps: Optional[tuple[int, int]] = None, threads: int = 1, progress: bool = True) -> list[str]:
    """The command line that runs one part, ``python -m benchmarks.accuracy_vs_time_<part>``, with
    the study's options (those that concern it)."""
    if part not in PARTS:
        raise ValueError(f"part must be one of {PARTS}, got {part!r}")
    cmd = [sys.executable, "-m", f"benchmarks.accuracy_vs_time_{part}", "--docs", str(docs.resolve()),
           "--work", str(work.resolve()), "--threads", str(threads)]
    flags = {"--quick": quick, "--no-progress": not progress, "--no-cuda": part == "renderer" and not cuda}
    cmd += [flag for flag, on in flags.items() if on]
    if part == "svr" and svr_steps is not None:
        cmd += ["--steps", ",".join(map(str, svr_steps))]
    return cmd


def run_parts(parts: Sequence[str], docs: Path, work: Path, quick: bool = False, cuda: bool = True,
              svr_steps: Optional[tuple[int, int]] = None, progress: bool = True, threads: int = 1) -> Path:
    """Runs the given parts, one process each (each keeps its section and its timing under
    ``work/sections``), then writes the report from the latest section of every part. Returns the
    report's path; a part that fails raises ``subprocess.CalledProcessError``."""
    log = progress_log(progress, indent="")
    for part in parts:
        log(f"study: {part}")
        subprocess.run(part_command(part, docs, work, quick, cuda, svr_steps, threads, progress), cwd=ROOT,
                       check=True)
        section = StudySection.read(work, part)
        log(f"study: {part} took {section.wall_s:.0f} s wall, {section.cpu_s:.0f} s CPU")
    return write_report(docs, work)


def write_report(docs: Path, work: Path) -> Path:
    """Assembles ``docs/accuracy_vs_time.md`` from the sections kept under ``work/sections`` (a
    banner says so when any of them comes from a ``--quick`` run)."""
    rows, bodies, quick = [], [], False
    for part in PARTS:
        section = StudySection.read(work, part)
        if section is not None:
            quick = quick or section.quick
            rows.append(f"| {TITLES[part]} | {section.finished} | {section.wall_s:.0f} | {section.cpu_s:.0f} | "
                        f"{section.load_before} | {section.load_after} |")
            bodies.append(section.markdown)
        else:
            rows.append(f"| {TITLES[part]} | not run | | | | |")
            bodies.append(f"## {TITLES[part]}\n\nNot run yet: `python -m benchmarks.accuracy_vs_time {COMMANDS[part]}`.\n")
    text = "\n".join([
        "# Accuracy against time",
        "",
        "What each setting costs and what it buys, measured on one machine: the renderer's march and "
        "intersection settings, resolutions and effects; the multi-view reconstruction schedule; the "
        "single-view network, refiner and supervision. Regenerate with "
        "`python -m benchmarks.accuracy_vs_time` (all parts, about 25 minutes on 2 CPU cores) or some parts with "
        "`--parts renderer,mvr,svr` (the report keeps the other parts' latest results).",
        "",
        *(["**This holds `--quick` results: toy sizes that only check the code paths; their numbers mean "
            "nothing.**", ""] if quick else []),
        "How to read it: each section has a table (one row per setting; *Pareto* marks the settings that no "
        "other setting beats in both time and error), a plot of error against time (the Pareto front joined in "
        "blue, the default as a red star) and a reading computed from the numbers (so it stays true when the "
        "study is rerun). Times are CPU seconds of a single-threaded process (torch and numba at 1 thread), "
        "which on an idle core equals the wall time; the wall times are listed too. The machine is shared "
        "with other jobs (the load averages below, on 2 cores), so wall times are noisy and even CPU times "
        "carry some noise (cache and memory contention): treat differences under ~20 % as noise.",
        "",
        "Contents: [Renderer](#renderer), [Multi-view reconstruction](#multi-view-reconstruction), "
        "[Single-view reconstruction](#single-view-reconstruction), [Machine](#machine).",
        "",
        "| part | finished | wall s | CPU s | load before (1 / 5 / 15 min) | load after |",
        "|---|---|---|---|---|---|",
        *rows,
        "",
        *bodies,
        "## Machine",
        "",
        machine_info(),
        "",
    ])
    path = docs / REPORT
    atomic_write_text(path, text)
    return path


EXAMPLES = """\
examples:
  python -m benchmarks.accuracy_vs_time                          # all parts, ~25 min on 2 CPU cores
  python -m benchmarks.accuracy_vs_time --parts mvr,svr          # rerun some parts; the others' last results stay
  python -m benchmarks.accuracy_vs_time --quick                  # toy sizes (a minute): checks the code paths
  python -m benchmarks.accuracy_vs_time --parts svr --svr-steps 2000,500   # a longer training budget
  python -m benchmarks.accuracy_vs_time --report-only            # reassemble the report from the kept sections

parts:
  renderer  hit threshold, maximum steps, intersection mode, grid and image resolution, effects:
            image error against a high-accuracy render, and time per frame, on the fused CPU
            kernel (and on CUDA where it runs: a second section)
  mvr       multi-view reconstruction error against time for the schedule
  svr       validation IoU (with a 95% interval over objects) against training time for the
            model, the refiner, the supervised views, the render size and the head resolution
"""


def main(argv: Optional[list[str]] = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, epilog=EXAMPLES,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated subset of {','.join(PARTS)}")
    ap.add_argument("--quick", action="store_true", help="toy sizes: checks the code paths in about a minute")
    ap.add_argument("--docs", type=Path, default=None,
                    help="where the report and plots go (default: docs; with --quick: outputs/study_quick)")
    ap.add_argument("--work", type=Path, default=None,
                    help="run folders, dataset cache, kept sections (default: outputs/study[_quick]/work)")
    ap.add_argument("--no-cuda", action="store_true",
                    help="renderer part on the CPU only (default: also on CUDA where its kernel runs)")
    ap.add_argument("--svr-steps", default=None, help="coarse,refine training steps per run (default: the "
                    "svr part's, which `python -m benchmarks.accuracy_vs_time_svr --help` gives)")
    ap.add_argument("--threads", type=int, default=1, help="torch and numba threads (default 1)")
    ap.add_argument("--report-only", action="store_true",
                    help="run nothing: rewrite the report from the sections kept under --work")
    args = ap.parse_args(argv)
    try:
        parts = parse_parts(args.parts)

        svr_steps = parse_steps(args.svr_steps)
    except ValueError as exc:
        ap.error(str(exc))
    docs, work = study_folders(args.quick, args.docs, args.work)
    if args.report_only:
        print(f"wrote {write_report(docs, work)}")
        return

    mvr.configure_runtime(threads=args.threads)  # as in each part: the report's machine section names it
    try:
        path = run_parts(parts, docs, work, args.quick, not args.no_cuda, svr_steps, threads=args.threads)
    except subprocess.CalledProcessError as exc:
        raise SystemExit(f"accuracy_vs_time: error: a part failed (exit status {exc.returncode}): "
                         f"{' '.join(map(str, exc.cmd[1:]))}") from None
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
