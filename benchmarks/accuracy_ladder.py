"""Where single-view accuracy is lost, run as ``python -m benchmarks.accuracy_ladder [--preset demo|bench]``:
rows scored on the same test images by the benchmark protocol, per category and on the mean over
categories, each with a 95% bootstrap interval over test objects: the ground-truth oracle (the voxel
protocol's ceiling), the network trained with 3D supervision (``loss=voxels``: the training voxels
instead of images, a diagnostic of what the architecture can read from one image, not the method),
the shipped recipe (image losses only, as the paper), the camera-free network (``model=small``, a
calibration without carving: it reads only the input image, as the methods published on NMR
ShapeNet, where the shipped recipe also reads the input camera), silhouette retrieval in the input's
view and in any view (camera-free), the lookup ceiling (best training object's voxels), the category
mean shape and the mean shape. Each trained row is
``python -m svr.demo`` with the preset's experiment into ``<work>/<row>`` (a stopped ladder resumes its
runs; a row whose folder holds a finished run's scores is reused, ``--rescore`` scores it again);
``--set`` passes hydra overrides to every trained row.
The gaps between rows say what limits accuracy (oracle to 3D-supervised: what one image and this
network cannot recover; 3D-supervised to shipped: what image-only supervision loses; shipped to
retrieval: whether the network beats a lookup). It writes docs/accuracy_ladder_<preset>.md, .json
and .png.
"""
from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from benchmarks.common import (all_voxels, atomic_write_text, bootstrap_means, lookup_ceiling, machine_info,
                               procedural_data, save_figure)
from svr.inference.calibration import Calibration

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = {"demo": "demo", "bench": "bench"}  # configs/experiment/<name>.yaml of each preset
# Row -> the overrides of its training run. voxels: the training voxels alone (the recipe's image
# terms, the hull term among them, off). camera_free: the image-only network (no pixel-aligned
# head, which projects into the input camera) and a level-only calibration (the carvings project
# into the input camera too).
TRAINED = {"shipped": (), "voxels": ("loss=voxels", "loss.weights.hull=0"),
           "camera_free": ("model=small", "calibrate_carving=false")}
# Row key -> (label, source): a trained run's per_object.csv column, or the lookup ceiling. A
# baseline's column (every one but iou_mean) is the same on every run of the same data, so where the
# named run lacks it (scored before the baseline existed) another run's is read.
ROWS = {
    "oracle": ("ground-truth oracle", ("shipped", "iou_oracle_mean")),
    "voxels": ("3D-supervised network (diagnostic)", ("voxels", "iou_mean")),
    "shipped": ("shipped recipe (image losses, reads the camera)", ("shipped", "iou_mean")),
    "camera_free": ("camera-free network (image only)", ("camera_free", "iou_mean")),
    "lookup": ("lookup ceiling", None),
    "retrieval": ("silhouette retrieval", ("shipped", "iou_retrieval_mean")),
    "retrieval_any_view": ("silhouette retrieval, any view", ("shipped", "iou_retrieval_any_view_mean")),
    "category_mean_shape": ("category mean shape", ("shipped", "iou_category_mean_shape_mean")),
    "mean_shape": ("mean shape", ("shipped", "iou_mean_shape_mean")),
}
# What each row reads at test time besides the input image (the input camera: its NMR view).
READS = {
    "oracle": "the exact shape",
    "voxels": "the input camera (as the shipped recipe)",
    "shipped": "the input camera (the pixel-aligned head, its shape prior's retrieval, the calibration's carving)",
    "camera_free": "nothing",
    "lookup": "the test object's voxels",
    "retrieval": "the input camera",
    "retrieval_any_view": "nothing",
    "category_mean_shape": "the category",
    "mean_shape": "nothing",
}


def read_per_object(path: Path) -> dict[tuple[str, int], dict[str, float]]:
    """A per_object.csv (``svr.evaluation.tables.write_report``) keyed by (category name, object index)."""
    with open(path, newline="") as f:
        return {(r["category"], int(r["object_index"])): {k: float(v) for k, v in r.items()
                                                          if k.startswith(("iou_", "side_iou_"))}
                for r in csv.DictReader(f)}


def lookup_per_object(preset: str, overrides: Sequence[str] = ()) -> tuple[dict[tuple[str, int], float], list[str]]:
    """The lookup ceiling of every test object (``benchmarks.common.lookup_ceiling``), keyed as
    ``read_per_object``, and the category names in the data's order."""
    dm = procedural_data(preset, overrides)
    test, train = dm.dataset("test"), dm.dataset("train")
    best = lookup_ceiling(all_voxels(test), all_voxels(train))
    names = [n for _, n in test.categories]
    out = {}
    for g in range(len(test)):
        c, o = test.locate(g)
        out[(names[c], o)] = float(best[g])
    return out, names


def scored(folder: Path) -> bool:
    """Whether a row's folder holds the scores of a finished run (``timings.json``, which the demo
    writes last, and ``per_object.csv``)."""
    return (folder / "timings.json").is_file() and (folder / "per_object.csv").is_file()


def calibration_of(folder: Path) -> str:
    """How a scored row's last-stage checkpoint was calibrated, from its ``iou.json`` ("none" when it
    was scored raw or before calibration existed)."""
    path = folder / "iou.json"
    records = json.loads(path.read_text()).get("calibration_search") if path.is_file() else None
    if not records:
        return "none"
    return Calibration.from_dict(list(records.values())[0]["settings"], f"{path}: calibration").describe()


def train_row(row: str, preset: str, work: Path, extra: Sequence[str], quiet: bool, rescore: bool = False) -> Path:
    """Trains (or resumes, or only scores) one trained row with ``python -m svr.demo``; returns its folder.
    A row whose folder already holds the scores of a finished run (``scored``) is reused as it is
    unless ``rescore``."""
    out = work / row
    if not rescore and scored(out):
        print(f"[{row}] reusing the scores in {out} (--rescore scores the run again)", file=sys.stderr, flush=True)
        return out
    cmd = [sys.executable, "-m", "svr.demo", f"out={out}", f"experiment={EXPERIMENTS[preset]}",
           *TRAINED[row], *extra] + (["quiet=true"] if quiet else [])
    print(f"[{row}] {' '.join(cmd[1:])}", file=sys.stderr, flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)
    return out


def ladder(objects: dict[str, dict[tuple[str, int], dict[str, float]]], lookup: dict[tuple[str, int], float],
           categories: Sequence[str]) -> dict:
    """Per row: per-category and mean scores with intervals, over the objects every source scored.

    Args:
        objects: trained row -> ``read_per_object`` of its run.
        lookup: ``lookup_per_object``.
        categories: category names in table order.
    Returns:
        {"rows": {key: {"label", "categories": {name: {"iou", "interval", "objects"}}, "mean",
        "interval"}}, "objects": count}.
    """
    keys = sorted(set(lookup).intersection(*(set(v) for v in objects.values())))
    if not keys:
        raise ValueError("the runs and the lookup share no test object: were they made from the same data?")
    cat = np.array([categories.index(k[0]) for k in keys])
    rows = {}
    for key, (label, source) in ROWS.items():
        if source is None:
            values = np.array([lookup[k] for k in keys])
        else:
            run = _source_run(objects, source, keys[0])
            if run is None:
                continue
            values = np.array([objects[run][k][source[1]] for k in keys])
        per_cat, overall = bootstrap_means(values, cat)
        table = {name: {"iou": float(values[cat == c].mean()), "interval": per_cat[c], "objects": int((cat == c).sum())}
                 for c, name in enumerate(categories) if c in per_cat}
        rows[key] = {"label": label, "categories": table,
                     "mean": float(np.mean([r["iou"] for r in table.values()])), "interval": overall}
        # Side views where the run scored them: a network's own (side_iou_mean) or a baseline's
        # (side_iou_<baseline>_mean, svr.evaluation.baselines.SIDE_BASELINES).
        if source is not None and f"side_{source[1]}" in objects[run][keys[0]]:
            side = np.array([objects[run][k][f"side_{source[1]}"] for k in keys])
            _, side_interval = bootstrap_means(side, cat)
            rows[key]["side_views"] = {"mean": float(np.mean([side[cat == c].mean() for c in np.unique(cat)])),
                                       "interval": side_interval}
    return {"rows": rows, "objects": len(keys)}


def _source_run(objects: dict, source: tuple[str, str], key) -> Optional[str]:
    """The trained run to read a row's column from: the named one, else for a baseline's column any
    run that scored it (None: none did)."""
    run, column = source
    if run in objects and column in objects[run][key]:
        return run
    if column == "iou_mean":  # a network's own score: only its run has it
        return None
    return next((r for r in objects if column in objects[r][key]), None)


def reads_note(summary: dict) -> str:
    """What each measured row reads at test time besides the input image, as one line."""
    return ("What each row reads at test time besides the input image (methods published on NMR ShapeNet "
            "read the image only): " + "; ".join(f"{r['label']}: {READS[k]}" for k, r in summary["rows"].items())
            + ".\n")


def markdown_table(summary: dict) -> str:
    """Rows of the ladder as table rows, categories as columns, the mean last."""
    names = list(next(iter(summary["rows"].values()))["categories"])
    lines = ["| row | " + " | ".join(names) + " | **mean** | side views |", "|---|" + "---:|" * (len(names) + 2)]
    for r in summary["rows"].values():
        cells = [f"{r['categories'][n]['iou']:.3f}" for n in names]
        lo, hi = r["interval"]
        side = r.get("side_views")
        side_cell = f"{side['mean']:.3f} [{side['interval'][0]:.3f}, {side['interval'][1]:.3f}]" if side else ""
        lines.append(f"| {r['label']} | " + " | ".join(cells) + f" | **{r['mean']:.3f}** [{lo:.3f}, {hi:.3f}] | "
                     f"{side_cell} |")
    return "\n".join(lines) + "\n"


def reading(summary: dict) -> str:
    """The gaps between rows, in words (only those whose rows were measured)."""
    m = {k: r["mean"] for k, r in summary["rows"].items()}
    out = []
    pairs = (("oracle", "voxels", "what one image and this network cannot recover, even with 3D targets"),
             ("voxels", "shipped", "what training from images alone loses against 3D targets"),
             ("shipped", "retrieval", "the network's margin over a silhouette lookup (negative: lookup wins)"),
             ("shipped", "category_mean_shape", "the network's margin over knowing only the category"),
             ("shipped", "camera_free", "what reading the input camera (pixel-aligned head, carving) adds"),
             ("camera_free", "retrieval_any_view", "the image-only network's margin over a camera-free lookup"))
    for a, b, what in pairs:
        if a in m and b in m:
            out.append(f"- {summary['rows'][a]['label']} - {summary['rows'][b]['label']}: "
                       f"**{m[a] - m[b]:+.3f}**: {what}.")
    side = {k: r["side_views"]["mean"] for k, r in summary["rows"].items() if "side_views" in r}
    for a, b, what in (("shipped", "retrieval", "the network's depth against a retrieved training object's"),
                       ("camera_free", "retrieval_any_view", "the image-only network's depth against a "
                                                             "camera-free lookup's")):
        if a in side and b in side:
            out.append(f"- side views, {summary['rows'][a]['label']} - {summary['rows'][b]['label']}: "
                       f"**{side[a] - side[b]:+.3f}**: {what}.")
    if "voxels" in m and "shipped" in m and m["voxels"] < m["shipped"]:
        out.append("- the 3D-supervised row is below the shipped recipe: its loss (`svr.losses.voxel_loss`) trains "
                   "this network worse than the silhouettes do, so the row does not yet measure what the "
                   "architecture can read from one image.")
    if "shipped" in summary["rows"] and "category_mean_shape" in summary["rows"]:
        below = [n for n, r in summary["rows"]["shipped"]["categories"].items()
                 if r["iou"] < summary["rows"]["category_mean_shape"]["categories"][n]["iou"]]
        out.append(f"- categories where the shipped recipe is below the category mean shape: "
                   f"{', '.join(below) if below else 'none'}.")
    return "\n".join(out) + "\n"


def plot(summary: dict, path: Path) -> None:
    """Per category, each row's mean with its interval (one colour per row), the means at the right."""
    import matplotlib  # heavy: only the plot needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: as above

    rows = summary["rows"]
    names = list(next(iter(rows.values()))["categories"]) + ["mean"]
    fig, ax = plt.subplots(figsize=(11, 4.2), dpi=110)
    width = 0.8 / len(rows)
    for i, r in enumerate(rows.values()):
        ys = [r["categories"][n]["iou"] for n in names[:-1]] + [r["mean"]]
        ivs = [r["categories"][n]["interval"] for n in names[:-1]] + [r["interval"]]
        xs = np.arange(len(names)) + (i - (len(rows) - 1) / 2) * width
        err = np.array([[y - lo for y, (lo, _) in zip(ys, ivs)], [hi - y for y, (_, hi) in zip(ys, ivs)]])
        ax.errorbar(xs, ys, yerr=err, fmt="o", ms=3, lw=1, capsize=1.5, label=r["label"])
    ax.set_xticks(np.arange(len(names)), names, rotation=30, ha="right", fontsize=8)
    ax.set_ylabel("voxel IoU (test split, 95% interval)")
    ax.set_ylim(0, 1.02)
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(fontsize=7, ncol=4, loc="lower left")
    fig.tight_layout()
    save_figure(fig, path)


EXAMPLES = """\
examples:
  python -m benchmarks.accuracy_ladder                          # demo preset: three demo trainings
  python -m benchmarks.accuracy_ladder --rows shipped            # only the shipped recipe's run
  python -m benchmarks.accuracy_ladder --rows shipped camera_free  # the shipped and the camera-free runs
  python -m benchmarks.accuracy_ladder --preset bench --set stage.coarse.max_time=00:01:00:00
"""


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, epilog=EXAMPLES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", choices=tuple(EXPERIMENTS), default="demo")
    parser.add_argument("--rows", nargs="+", choices=tuple(TRAINED), default=list(TRAINED),
                        help="the trained rows to run (default: all); the shipped run also scores the baselines")
    parser.add_argument("--work", type=Path, default=None, help="run folders (default: outputs/ladder_<preset>)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="a hydra override for every trained row (repeatable)")
    parser.add_argument("--out", type=Path, default=None,
                        help="stem of the .md/.json/.png outputs (default: docs/accuracy_ladder_<preset>)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    parser.add_argument("--rescore", action="store_true",
                        help="score a row's finished run again even where its folder holds its scores")
    args = parser.parse_args(argv)
    if "shipped" not in args.rows:
        parser.error("--rows must include shipped: its run scores the oracle and the baselines")
    work = (args.work or ROOT / "outputs" / f"ladder_{args.preset}").resolve()
    start = time.time()
    reused = [row for row in args.rows if not args.rescore and scored(work / row)]
    objects = {row: read_per_object(train_row(row, args.preset, work, args.overrides, args.quiet,
                                              args.rescore) / "per_object.csv")
               for row in args.rows}
    data = [o for o in args.overrides if o.startswith("data.")]
    lookup, categories = lookup_per_object(args.preset, data)
    timings = {row: json.loads((work / row / "timings.json").read_text()) for row in args.rows}
    calibrations = {row: calibration_of(work / row) for row in args.rows}
    summary = ladder(objects, lookup, categories)
    seconds = time.time() - start
    command = "python -m benchmarks.accuracy_ladder " + " ".join(argv if argv is not None else sys.argv[1:])
    trained = ", ".join(f"{row} {timings[row]['train_seconds'] / 60:.1f} min" for row in args.rows
                        if timings[row].get("train_seconds") is not None)
    stem = args.out or ROOT / "docs" / f"accuracy_ladder_{args.preset}"
    camera_free = (" (+ `model=small calibrate_carving=false` for the camera-free one)"
                   if "camera_free" in args.rows else "")
    text = (f"# Accuracy ladder: where single-view accuracy is lost ({args.preset} preset)\n\n"
            f"Command: `{command.strip()}` ({seconds / 60:.1f} min this time; training: {trained}).\n\n"
            f"{machine_info()}\n\nTest split, {summary['objects']} objects, all 24 views each, scored by the "
            f"benchmark protocol; the interval is a 95% bootstrap over test objects (resampled within each "
            f"category). Side views: the silhouette IoU from the views 90 degrees either side of the "
            f"input (`svr.nmr.side_views`; mean over categories, interval as above), of the trained rows and of the "
            f"baselines whose evaluation scored them (`svr.evaluation.baselines.SIDE_BASELINES`). Trained rows: `python -m svr.demo experiment={EXPERIMENTS[args.preset]}`"
            f"{' (+ `' + ' '.join(TRAINED['voxels']) + '` for the 3D-supervised one)' if 'voxels' in args.rows else ''}"
            f"{camera_free}"
            f"{' with ' + ' '.join(args.overrides) if args.overrides else ''}."
            f"{'' if 'voxels' in args.rows else ' The 3D-supervised row was not run (not in `--rows`).'}"
            f"{' Scores reused from an earlier scoring of their run: ' + ', '.join(reused) + '.' if reused else ''}"
            f" Calibration of each trained row's scored checkpoint (chosen on the validation split, "
            f"docs/svr_evaluation.md#calibration): "
            f"{'; '.join(f'{row}: {text}' for row, text in calibrations.items())}."
            f"\n\n{markdown_table(summary)}\n{reads_note(summary)}\n## Reading\n\n{reading(summary)}\n"
            f"![ladder]({stem.name}.png)\n")
    print(text)
    atomic_write_text(stem.with_suffix(".md"), text)
    atomic_write_text(stem.with_suffix(".json"), json.dumps({**summary, "seconds": seconds, "timings": timings,
                                                             "command": command.strip()}, indent=1) + "\n")
    plot(summary, stem.with_suffix(".png"))
    print(f"wrote {stem}.md, .json and .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
