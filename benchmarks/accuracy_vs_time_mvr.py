"""The multi-view part of the accuracy-versus-time study, run by
``python -m benchmarks.accuracy_vs_time --parts mvr`` (``--docs DIR`` to keep docs/ as it is), which
runs ``python -m benchmarks.accuracy_vs_time_mvr [--quick]`` (the plot goes to
``<docs>/study_mvr.png``, the section to ``<work>/sections/mvr.md`` for the study's report):
reconstruction error against time for the schedule's settings (levels, start resolution, image
resolution, passes per level). Every run is ``python -m mvr target=torus`` (configs/mvr.yaml) with
hydra overrides, in this process (``mvr.reconstruct_with_overrides``, as
benchmarks/mvr_parameter_study.py runs its settings). The default
(configs/mvr.yaml as it is: 8^3 to 64^3 in 4 levels, the paper's image rule, at most 10 passes per
level) runs once; the sweeps change one setting of a cheaper base (8^3 to 32^3 in 3 levels, at most
4 passes per level) so that the whole part fits in minutes on 2 cores. Each run starts afresh
(``resume=false``) in ``<work>/mvr/<label>``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

from benchmarks.common import (Point, Setting, fmt_value, progress_log, run_study_part, study_folders,
                               study_part_parser, timed, tradeoff_section)
import mvr
from mvr import reconstruct_with_overrides

TARGET = "torus"
BASE = ("schedule.start=8", "schedule.end=32", "schedule.levels=3", "optim.max_passes=4")
EVAL_SAMPLES = "evaluation.samples=20000"
# Toy sizes for --quick: two tiny levels, small images, one short pass, few evaluation samples.
QUICK = ("schedule.resolutions=[8,12]", "schedule.image_size=24", "optim.max_passes=1", "optim.min_passes=1",
         "optim.hard_view_updates=2", "optim.easy_view_updates=1", "evaluation.samples=2000",
         "target_settings.mesh_resolution=48")


@dataclass(frozen=True)
class Change:
    """One run of a sweep: the setting varied (``dimension``), its value here, and the overrides
    that change the base to it (none: the base itself, which every sweep shares)."""

    dimension: str
    value: str
    overrides: tuple[str, ...] = ()

    @property
    def label(self) -> str:
        """The run's short name (it annotates the plot)."""
        return f"{self.dimension.split()[0]} {self.value}" if self.overrides else "base"


def sweeps(quick: bool = False) -> tuple[Change, ...]:
    """One-setting changes of the base, grouped by the setting they vary."""
    if quick:
        return (Change("image", "24"), Change("image", "16", ("schedule.image_size=16",)))
    return (
        Change("levels (8^3 to 32^3)", "1", ("schedule.levels=1",)),
        Change("levels (8^3 to 32^3)", "2", ("schedule.levels=2",)),
        Change("levels (8^3 to 32^3)", "3"),
        Change("levels (8^3 to 32^3)", "5", ("schedule.levels=5",)),
        Change("start resolution", "4", ("schedule.start=4",)),
        Change("start resolution", "8"),
        Change("start resolution", "16", ("schedule.start=16",)),
        Change("image side (px)", "32", ("schedule.image_size=32",)),
        Change("image side (px)", "64", ("schedule.image_size=64",)),
        Change("image side (px)", "rule"),
        Change("image side (px)", "128", ("schedule.image_size=128",)),
        Change("passes per level (at most)", "2", ("optim.max_passes=2",)),
        Change("passes per level (at most)", "4"),
        Change("passes per level (at most)", "8", ("optim.max_passes=8",)),
        Change("end resolution", "32"),
        Change("end resolution", "64", ("schedule.end=64", "schedule.levels=4")),
    )


def _merge(*groups: Sequence[str]) -> tuple[str, ...]:
    """Hydra overrides, a later ``key=value`` replacing an earlier one of the same key."""
    merged: dict[str, str] = {}
    for group in groups:
        for o in group:
            merged[o.split("=", 1)[0]] = o
    return tuple(merged.values())


def settings(quick: bool = False) -> tuple[Setting, ...]:
    """The runs: the default (configs/mvr.yaml as it is), the base, and each change of the base
    (with ``quick``, the toy base stands for the default)."""
    base = QUICK if quick else (*BASE, EVAL_SAMPLES)
    changes = {c.label: Setting(c.label, _merge(base, c.overrides)) for c in sweeps(quick) if c.overrides}
    if quick:
        return (Setting("base", base, default=True), *changes.values())
    default = Setting("mvr.yaml", ("optim.max_passes=10", EVAL_SAMPLES), default=True)
    return (default, Setting("base", base), *changes.values())


def glance(points: Sequence[Point], quick: bool = False) -> str:
    """A table: per setting varied, each value's error and CPU seconds (the base's value in bold)."""
    by_label = {p.label: p for p in points}
    rows = ["| setting varied | values: relative Hausdorff (CPU s) |", "|---|---|"]
    for dimension in dict.fromkeys(c.dimension for c in sweeps(quick)):
        cells = []
        for c in (c for c in sweeps(quick) if c.dimension == dimension):
            p = by_label[c.label]
            value = c.value if c.overrides else f"**{c.value}**"
            cells.append(f"{value}: {fmt_value(p.error)} ({fmt_value(p.seconds)})")
        rows.append(f"| {dimension} | " + " · ".join(cells) + " |")
    return "\n".join(rows)


COLUMNS = (("hausdorff_rel", "hausdorff_rel"), ("chamfer_rel", "chamfer_rel"), ("CPU s", "cpu_s"),
           ("wall s", "wall_s"), ("load", "load"), ("grids", "resolutions"), ("images (px)", "images"),
           ("updates", "updates"), ("genus", "genus"))


def measure(setting: Setting, work: Path) -> Point:
    """Runs one reconstruction afresh; a Point (seconds: CPU seconds of the whole run; error: the
    relative Hausdorff distance, nan where meshing failed)."""
    overrides = ("optim.max_passes=10", EVAL_SAMPLES, *setting.overrides, "resume=false")
    t = timed(lambda: reconstruct_with_overrides(TARGET, work / setting.label.replace(" ", "_"), overrides).metrics)
    m = t.result
    error = float(m["hausdorff_rel"]) if m.get("hausdorff_rel") is not None else float("nan")
    chamfer = float(m["chamfer_rel"]) if m.get("chamfer_rel") is not None else float("nan")
    return Point(setting.label, t.cpu, error, setting.default, extra={
        "hausdorff_rel": error, "chamfer_rel": chamfer, "cpu_s": t.cpu, "wall_s": t.wall, "load": t.load,
        "resolutions": " ".join(str(r) for r in m.get("resolutions", [])),
        "images": " ".join(str(s) for s in m.get("image_sizes", [])), "updates": m.get("updates", ""),
        "genus": m.get("mesh_genus", "")})


def run(out_dir: Path, work: Path, quick: bool = False, progress: bool = True,
        prefix: str = "study_mvr") -> str:
    """Runs every setting (each afresh under ``work``); writes ``<out_dir>/<prefix>.png``; returns
    the report's markdown section."""
    log = progress_log(progress)
    points = []
    for s in settings(quick):
        log(f"mvr: {s.label}")
        points.append(measure(s, work / "mvr"))
    base = " ".join(BASE)
    by_label = {p.label: p for p in points}
    d, b = by_label.get("mvr.yaml"), by_label["base"]
    intro = (
        f"`python -m mvr target={TARGET}` (26 views, sphere initialisation) per setting. *mvr.yaml* (the default): "
        f"`configs/mvr.yaml` as it is (8^3 to 64^3 in 4 levels, the paper's image rule, at most 10 passes per "
        f"level); *base*: the same with `{base}`, the cheaper schedule that every other row changes in one "
        f"setting. Errors: relative Hausdorff and Chamfer distances (relative to the target's bounding-box "
        f"diagonal, {EVAL_SAMPLES.split('=')[1]} surface samples per mesh). Time: CPU seconds of the whole run "
        f"(target images, optimisation, meshing, evaluation; 1 thread, so about the wall time on an idle core), "
        f"with the wall seconds and the load average during the run beside it.")
    changes = "; ".join(f"{c.label}: `{' '.join(c.overrides)}`" for c in sweeps(quick) if c.overrides)
    comparison = "" if d is None else (
        f"The default's extra 64^3 level and longer levels cost {fmt_value(d.seconds / b.seconds)}x the base's time "
        f"for a {fmt_value(b.error / d.error)}x smaller Hausdorff distance ({fmt_value(d.error)} against "
        f"{fmt_value(b.error)}).\n")
    section = tradeoff_section(
        points, COLUMNS, out_dir / f"{prefix}.png", title=f"Multi-view reconstruction ({TARGET}): error against time",
        setting_name="setting", xlabel="CPU seconds per reconstruction", ylabel="relative Hausdorff distance",
        unit="s", error_name="relative Hausdorff distance", logx=True, logy=True)
    return "\n".join(["## Multi-view reconstruction", "", intro, "", "### At a glance", "", glance(points, quick), "",
                      f"Changes of the base: {changes}.", "", comparison, section])


def main(argv: Optional[list[str]] = None) -> None:
    args = study_part_parser(__doc__).parse_args(argv)
    docs, work = study_folders(args.quick, args.docs, args.work)
    mvr.configure_runtime(threads=args.threads)
    run_study_part("mvr", lambda: run(docs, work, quick=args.quick, progress=not args.no_progress), work, args.quick)


if __name__ == "__main__":
    main()
