"""How much a lookup of training shapes can score on a procedural preset, against how varied its
shapes are, run as ``python -m benchmarks.procedural_dispersion [--preset demo|bench]``. Per category
and on the mean over categories, on the test split: the lookup ceiling (for each test object, the
voxel IoU of its most similar training object of any category: the best any lookup can do),
silhouette retrieval, the category mean shape, the mean shape and the ground-truth oracle (``svr.evaluation
.baselines``, scored over all 24 views as a model is), and diversity (the mean pairwise voxel IoU
of the category's training objects; lower is more varied), with a 95% bootstrap interval over test
objects for the lookup ceiling and retrieval. It writes docs/procedural_dispersion_<preset>.md and
.json and a contact sheet of 12 random test objects per category (.png beside them).
``--categories``, ``--train`` and ``--test`` make a quick probe of a few categories at another size
(printed only, unless ``--out`` is given); the dataset is generated first if it is not in the cache.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from benchmarks.common import (DATA_PRESETS, all_voxels, atomic_write_text, bootstrap_interval, iou_matrix,
                               lookup_ceiling, machine_info, procedural_data)
from sdfcommon.tooling.outputs import write_png
from sdfcommon.tooling.pictures import labelled_grid
from svr.evaluation.baselines import LABELS, score_baselines
from svr.evaluation.tables import EvaluationResult

ROOT = Path(__file__).resolve().parents[1]
HALF_SIDE = 0.6        # configs/model/*.yaml: the SDF grid's box (for the oracle)
GRID_RESOLUTION = 64
SHEET_OBJECTS = 12     # objects per category on the contact sheet
SHEET_VIEW = 3         # azimuth -45 degrees: front and side at once
DIVERSITY_SAMPLE = 200  # training objects per category in the pairwise diversity figure
COLUMNS = ("lookup", "retrieval", "category_mean_shape", "mean_shape", "oracle", "diversity")
COLUMN_LABELS = {"lookup": "lookup ceiling", "retrieval": LABELS["retrieval"], "mean_shape": LABELS["mean_shape"],
                 "category_mean_shape": LABELS["category_mean_shape"], "oracle": LABELS["oracle"],
                 "diversity": "diversity (mean pairwise IoU)"}


def mean_pairwise_iou(voxels: np.ndarray) -> float:
    """The mean voxel IoU over all pairs of distinct objects (needs two or more)."""
    if len(voxels) < 2:
        raise ValueError(f"voxels must hold at least 2 objects, got {len(voxels)}")
    m = iou_matrix(voxels, voxels)
    return float((m.sum() - np.trace(m)) / (len(m) * (len(m) - 1)))


def dispersion(preset: str = "bench", cache_dir: Optional[Path] = None, overrides: Sequence[str] = (),
               oracle_objects: Optional[int] = None, progress: bool = True) -> tuple[dict, object]:
    """Every figure of the module docstring on the test split of a preset.

    Args:
        overrides: hydra overrides of the data group (e.g. ``data.categories=[chair]``).
        oracle_objects: score the oracle on the first this many test objects of each category
            (None: all).
    Returns:
        ({"categories": {name: {column: value, ...}}, "mean": {...}, "sizes": ..., "dataset": ...},
        the test split's dataset).
    """
    extra = [f"data.cache_dir={cache_dir}"] if cache_dir is not None else []
    dm = procedural_data(preset, [f"data.progress={progress}", *extra, *overrides])
    test, train = dm.dataset("test"), dm.dataset("train")
    names = [n for _, n in test.categories]
    test_vox, train_vox = all_voxels(test), all_voxels(train)
    best = lookup_ceiling(test_vox, train_vox)
    located = [test.locate(g) for g in range(len(test))]
    obj_cat = np.array([c for c, _ in located])
    keep = np.ones(len(test), dtype=bool)
    if oracle_objects is not None:
        keep = np.array([o < oracle_objects for _, o in located])
    cat = np.repeat(obj_cat, 24)
    obj = np.repeat([o for _, o in located], 24)
    view = np.tile(np.arange(24), len(located))

    def images(mask: np.ndarray) -> EvaluationResult:  # the (object, view) images the baselines score
        return EvaluationResult(split="test", dataset=str(dm.root), categories=tuple(test.categories),
                                is_nmr_shapenet=False, checkpoint=None, stage="-", output="-", category=cat[mask],
                                object_index=obj[mask], view=view[mask], iou=np.zeros(int(mask.sum())))

    every = np.ones(len(cat), dtype=bool)
    scores = score_baselines(("retrieval", "category_mean_shape", "mean_shape"), images(every), test, train,
                             HALF_SIDE, GRID_RESOLUTION, progress=progress)
    sub = np.repeat(keep, 24)
    oracle = score_baselines(("oracle",), images(sub), test, train, HALF_SIDE, GRID_RESOLUTION, progress=progress)
    rng = np.random.default_rng(0)
    train_cat = np.array([train.locate(g)[0] for g in range(len(train))])
    table: dict[str, dict] = {}
    for c, name in enumerate(names):
        row: dict = {}
        on = obj_cat == c
        row["lookup"] = float(best[on].mean())
        row["lookup_interval"] = bootstrap_interval(best[on])
        retr = scores["retrieval"][cat == c].reshape(-1, 24).mean(1)  # per object, over its views
        row["retrieval"] = float(retr.mean())
        row["retrieval_interval"] = bootstrap_interval(retr)
        for key in ("category_mean_shape", "mean_shape"):
            row[key] = float(scores[key][cat == c].mean())
        row["oracle"] = float(oracle["oracle"][cat[sub] == c].mean()) if "oracle" in oracle else float("nan")
        pool = np.flatnonzero(train_cat == c)
        pick = rng.choice(pool, size=min(DIVERSITY_SAMPLE, len(pool)), replace=False)
        row["diversity"] = mean_pairwise_iou(train_vox[pick])
        table[name] = row
    mean = {k: float(np.mean([table[n][k] for n in names])) for k in COLUMNS}
    summary = {"categories": table, "mean": mean, "sizes": dm.settings.sizes(), "dataset": str(dm.root),
               "oracle_objects_per_category": oracle_objects}
    return summary, test


def markdown_table(summary: dict) -> str:
    """The summary as a markdown table: one row per category, then the mean."""
    cols = " | ".join(COLUMN_LABELS[k] for k in COLUMNS)
    lines = [f"| category | {cols} |", "|---|" + "---:|" * len(COLUMNS)]
    for name, row in summary["categories"].items():
        cells = []
        for k in COLUMNS:
            cell = f"{row[k]:.4f}"
            if f"{k}_interval" in row:
                lo, hi = row[f"{k}_interval"]
                cell += f" [{lo:.2f}, {hi:.2f}]"
            cells.append(cell)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("| **mean** | " + " | ".join(f"**{summary['mean'][k]:.4f}**" for k in COLUMNS) + " |")
    return "\n".join(lines) + "\n"


def contact_sheet(test, path: Path, per_category: int = SHEET_OBJECTS, view: int = SHEET_VIEW, seed: int = 0) -> Path:
    """A PNG of ``per_category`` random test objects per category (rows), in one view, as the
    dataset stores them."""
    rng = np.random.default_rng(seed)
    tiles, labels = [], []
    for c, (_, name) in enumerate(test.categories):
        count = int(test.counts[c])
        pick = np.sort(rng.choice(count, size=min(per_category, count), replace=False))
        row = [test.images_uint8(int(test.offsets[c] + o), [view])[0, :3].transpose(1, 2, 0) / 255.0 for o in pick]
        row += [np.ones_like(row[0])] * (per_category - len(row))
        tiles.append(row)
        labels.append(name)
    grid = labelled_grid(np.asarray(tiles), labels, [""] * per_category, min_tile=64)
    write_png(path, grid)
    return path


EXAMPLES = """\
examples:
  python -m benchmarks.procedural_dispersion                    # data=procedural_bench, writes docs/
  python -m benchmarks.procedural_dispersion --preset demo
  python -m benchmarks.procedural_dispersion --preset demo --categories chair table --train 200 --test 40 \\
      --cache-dir /tmp/probe                                    # a quick probe, printed only
"""


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, epilog=EXAMPLES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", choices=tuple(DATA_PRESETS), default="bench")
    parser.add_argument("--categories", nargs="+", default=None, help="names or ids (default: the preset's)")
    parser.add_argument("--train", type=int, default=None, help="training objects per category (default: preset's)")
    parser.add_argument("--test", type=int, default=None, help="test objects per category (default: preset's)")
    parser.add_argument("--oracle-objects", type=int, default=None,
                        help="oracle on the first N test objects per category (default: all)")
    parser.add_argument("--cache-dir", type=Path, default=None,
                        help="default: paths.data_dir (data/cache in the checkout)")
    parser.add_argument("--out", type=Path, default=None,
                        help="stem of the .md/.json/.png outputs (default: docs/procedural_dispersion_<preset>; "
                             "a probe writes only when given)")
    args = parser.parse_args(argv)
    overrides = []
    if args.categories:
        overrides.append("data.categories=[" + ",".join(args.categories) + "]")
    if args.train is not None:
        overrides.append(f"data.train={args.train}")
    if args.test is not None:
        overrides += [f"data.test={args.test}", "data.val=0"]
    probe = bool(overrides)
    start = time.time()
    summary, test = dispersion(args.preset, args.cache_dir, overrides, args.oracle_objects)
    seconds = time.time() - start
    command = "python -m benchmarks.procedural_dispersion " + " ".join(argv if argv is not None else sys.argv[1:])
    sizes = ", ".join(f"{k} {v}" for k, v in summary["sizes"].items())
    text = (f"# Procedural benchmark: dispersion and lookup\n\nCommand: `{command.strip()}` ({seconds:.0f} s, "
            f"the dataset already generated or not).\n\n{machine_info()}\n\nPreset `{args.preset}` (objects per "
            f"category: {sizes}), test split, `{Path(summary['dataset']).name}`. Lookup ceiling: per test object "
            f"the best voxel IoU of any training object; retrieval: the training object with the most similar "
            f"silhouette in the same view, over all 24 views; both with a 95% bootstrap interval over test "
            f"objects. Diversity: mean pairwise voxel IoU of up to {DIVERSITY_SAMPLE} training objects of the "
            f"category (lower is more varied).\n\n{markdown_table(summary)}")
    print(text)
    if probe and args.out is None:
        return 0
    stem = args.out or ROOT / "docs" / f"procedural_dispersion_{args.preset}"
    atomic_write_text(stem.with_suffix(".md"), text + f"\n![contact sheet]({stem.name}.png)\n")
    atomic_write_text(stem.with_suffix(".json"), json.dumps({**summary, "seconds": seconds}, indent=1) + "\n")
    contact_sheet(test, stem.with_suffix(".png"))
    print(f"wrote {stem}.md, .json and .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
