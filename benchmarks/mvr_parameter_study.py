"""The paper's parameter studies for multi-view reconstruction (section 5.3) at reduced scale, one
command per study, ``python -m benchmarks.mvr_parameter_study STUDY`` (``initial_resolution``,
``levels``, ``image_resolution``, ``noise`` or ``all``), each writing a markdown table (error and
time per setting) and a plot to docs/mvr_<study>.{md,png}. Every run uses the settings of
``python -m mvr`` (configs/mvr.yaml) with a few hydra overrides: the setting studied, and the
reduced scale that lets a study run in tens of minutes on 2 CPU cores (the torus, final grids of
32^3 or 48^3 instead of 64^3, at most ``--passes`` passes per level). Every run keeps its output
folder under ``--work`` and resumes from it, so that an interrupted study continues where it
stopped.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from benchmarks.common import Point, Setting, atomic_write_text, machine_info, markdown_table, plot_tradeoff
import mvr
from mvr import reconstruct_with_overrides

FINE32 = ("schedule.resolutions=[8,16,32]",)


@dataclass(frozen=True)
class Study:
    """A parameter study: what it varies, its settings, and what the paper found."""

    name: str
    title: str
    varies: str
    settings: tuple[Setting, ...]
    paper: str


def _studies() -> dict[str, Study]:
    return {s.name: s for s in (
        Study("initial_resolution", "Initial grid resolution", "initial resolution (3 levels up to 48^3)", (
            Setting("8", ("schedule.start=8", "schedule.end=48", "schedule.levels=3"), default=True),
            Setting("16", ("schedule.start=16", "schedule.end=48", "schedule.levels=3")),
            Setting("32", ("schedule.start=32", "schedule.end=48", "schedule.levels=3")),
        ), "a lower initial resolution reconstructs better: it captures the large-scale structure "
           "robustly (8, 16, 32, 48 tried)."),
        Study("levels", "Number of resolution levels", "levels from 8^3 to 48^3", (
            Setting("1", ("schedule.start=8", "schedule.end=48", "schedule.levels=1")),
            Setting("4", ("schedule.start=8", "schedule.end=48", "schedule.levels=4"), default=True),
            Setting("8", ("schedule.start=8", "schedule.end=48", "schedule.levels=8")),
        ), "more levels are better; a single level (optimising at the final resolution directly) "
           "fails (1, 4, 8, 15 tried)."),
        Study("image_resolution", "Image resolution", "fixed image side (grids 8, 16, 32)", (
            Setting("64", (*FINE32, "schedule.image_size=64")),
            Setting("128", (*FINE32, "schedule.image_size=128"), default=True),
            Setting("256", (*FINE32, "schedule.image_size=256")),
        ), "the image resolution has little effect (64 to 512 tried)."),
        Study("noise", "Noisy inputs", "noise (grids 8, 16, 32)", (
            Setting("none", (*FINE32, "mvr/noise=none"), default=True),
            Setting("image", (*FINE32, "mvr/noise=image")),
            Setting("camera", (*FINE32, "mvr/noise=camera")),
        ), "robust to Gaussian noise on the images (variance 0.03) and on the camera positions "
           "(variance 0.01)."),
    )}


def run_setting(target: str, setting: Setting, out_dir: Path, passes: int) -> dict:
    """Runs one reconstruction: configs/mvr.yaml + the reduced scale + the setting's overrides."""
    overrides = [f"optim.max_passes={passes}", "evaluation.samples=20000", *setting.overrides]
    return reconstruct_with_overrides(target, out_dir, overrides).metrics


def run_study(study: Study, target: str, work: Path, docs: Path, passes: int,
              log: Callable[[str], None] = print) -> Path:
    """Runs every setting of ``study`` and writes docs/mvr_<name>.md and .png."""
    points = []
    for setting in study.settings:
        t0 = time.perf_counter()
        m = run_setting(target, setting, work / study.name / setting.label, passes)
        log(f"[{study.name}] {setting.label}: hausdorff_rel {m['hausdorff_rel']}, chamfer_rel "
            f"{m['chamfer_rel']}, {m['seconds']:.0f}s (ran {time.perf_counter() - t0:.0f}s)")
        error = m["hausdorff_rel"] if m["hausdorff_rel"] is not None else float("nan")
        points.append(Point(setting.label, float(m["seconds"]), float(error), setting.default, extra={
            "hausdorff_rel": error, "chamfer_rel": m["chamfer_rel"], "seconds": float(m["seconds"]),
            "resolutions": " ".join(str(r) for r in m["resolutions"]),
            "images": " ".join(str(s) for s in m["image_sizes"]), "updates": m["updates"],
            "genus": m["mesh_genus"], "components": m["mesh_components"]}))
    png = docs / f"mvr_{study.name}.png"
    plot_tradeoff(points, png, f"{study.title} ({target}): error vs time", "seconds (2 shared CPU cores)",
                  "relative Hausdorff distance", logx=False, logy=False)
    table = markdown_table(points, [("hausdorff_rel", "hausdorff_rel"), ("chamfer_rel", "chamfer_rel"),
                                    ("seconds", "seconds"), ("grids", "resolutions"), ("images (px)", "images"),
                                    ("updates", "updates"), ("genus", "genus"), ("components", "components")],
                           setting_name=study.varies)
    md = "\n".join([
        f"# Multi-view reconstruction study: {study.title.lower()}",
        "",
        f"`python -m benchmarks.mvr_parameter_study {study.name}`: target `{target}`, the defaults of "
        f"`configs/mvr.yaml` except the setting varied and at most {passes} passes per level (reduced "
        f"scale). Errors are relative to the target's bounding-box diagonal (20k surface samples per "
        f"mesh); times include making the target images and the evaluation, on 2 CPU cores shared "
        f"with other jobs, so they are noisy.",
        "",
        "Overrides per setting: " + "; ".join(f"{s.label}: `{' '.join(s.overrides)}`" for s in study.settings),
        "",
        table,
        "",
        f"The paper (section 5.3): {study.paper}",
        "",
        f"![{study.title}](mvr_{study.name}.png)",
        "",
        "Machine:",
        "",
        machine_info({"torch threads used": 1}),
        "",
    ])
    path = docs / f"mvr_{study.name}.md"
    atomic_write_text(path, md)
    log(f"wrote {path} and {png}")
    return path


EXAMPLES = """\
examples:
  python -m benchmarks.mvr_parameter_study initial_resolution   # docs/mvr_initial_resolution.{md,png}
  python -m benchmarks.mvr_parameter_study levels               # docs/mvr_levels.{md,png}
  python -m benchmarks.mvr_parameter_study image_resolution     # docs/mvr_image_resolution.{md,png}
  python -m benchmarks.mvr_parameter_study noise                # docs/mvr_noise.{md,png}
  python -m benchmarks.mvr_parameter_study all
"""


def main(argv: list[str] | None = None) -> None:
    studies = _studies()
    ap = argparse.ArgumentParser(description=__doc__, epilog=EXAMPLES,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("study", choices=[*studies, "all"])
    ap.add_argument("--target", default="torus", help="built-in shape or mesh file (default: torus)")
    ap.add_argument("--passes", type=int, default=6, help="passes per level at most (default: 6)")
    ap.add_argument("--work", type=Path, default=Path("outputs/mvr_study"), help="run folders (resumable)")
    ap.add_argument("--docs", type=Path, default=Path("docs"), help="where the tables and plots go")
    args = ap.parse_args(argv)

    mvr.configure_runtime(threads=1)
    for name in (studies if args.study == "all" else [args.study]):
        run_study(studies[name], args.target, args.work, args.docs, args.passes)


if __name__ == "__main__":
    main()
