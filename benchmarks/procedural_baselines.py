"""The bar a model must clear on the procedural benchmark, run as
``python -m benchmarks.procedural_baselines [--preset demo|bench] [--split train|val|test]``: every
baseline of ``svr.evaluation.baselines`` (mean shape, category mean shape, retrieval, the oracle)
on a split of a procedural preset, per category, with no model needed (the oracle samples the exact
shapes on a 64^3 grid over [-0.6, 0.6]^3, the default models' grid). The dataset is generated
first if it is not in the cache (``data/make_procedural.py`` does the same), and the table goes to
docs/procedural_baselines_<preset>.md (``--out`` to change, ``--no-write`` to only print).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
from hydra.utils import instantiate

from benchmarks.report import atomic_write_text, machine_info
from sdfcommon.tooling.commands import compose
from svr.evaluation.baselines import BASELINES, LABELS, score_baselines
from svr.evaluation.metrics import iou_table
from svr.evaluation.tables import EvaluationResult

ROOT = Path(__file__).resolve().parents[1]
HALF_SIDE = 0.6        # configs/model/*.yaml: the SDF grid's box
GRID_RESOLUTION = 64   # the paper's 64^3 output grid


PRESETS = {"demo": "procedural", "bench": "procedural_bench"}  # configs/data/<name>.yaml


def baseline_table(preset: str = "bench", split: str = "test", cache_dir: Optional[Path] = None,
                   overrides: Sequence[str] = (), progress: bool = True) -> tuple[str, dict]:
    """Scores every baseline on every view of every object of a split.

    Args:
        preset: "demo" (data=procedural) or "bench" (data=procedural_bench).
        cache_dir: where the datasets are cached (default: the preset's, data/cache).
        overrides: hydra overrides of the data group (e.g. ["data.train=2"] for a toy run).
    Returns:
        (markdown table, {baseline: {"categories": {name: iou}, "mean": iou}}).
    """
    extra = [f"data.cache_dir={cache_dir}"] if cache_dir is not None else []
    cfg = compose("eval", [f"data={PRESETS[preset]}", f"data.progress={progress}", *extra, *overrides])
    dm = instantiate(cfg.data)  # the data module training uses: the same folder, generated if missing
    dm.prepare_data()
    settings = dm.settings
    objects, train = dm.dataset(split), dm.dataset("train")
    located = [objects.locate(g) for g in range(len(objects))]
    cat = np.repeat([c for c, _ in located], 24)
    obj = np.repeat([o for _, o in located], 24)
    view = np.tile(np.arange(24), len(located))
    result = EvaluationResult(split=split, dataset=str(dm.root), categories=tuple(objects.categories),
                              is_nmr_shapenet=False, checkpoint=None, stage="-", output="-", category=cat,
                              object_index=obj, view=view, iou=np.zeros(len(cat)))
    scores = score_baselines(BASELINES, result, objects, train, HALF_SIDE, GRID_RESOLUTION, progress=progress)
    names = [n for _, n in objects.categories]
    lines = ["| baseline | " + " | ".join(names) + " | mean |", "|---|" + "---:|" * (len(names) + 1)]
    summary = {}
    for name, iou in scores.items():
        table = iou_table(iou, cat, result.categories)
        summary[name] = {"categories": {r.name: r.iou for r in table.rows}, "mean": table.mean}
        lines.append(f"| {LABELS[name]} | " + " | ".join(f"{r.iou:.4f}" for r in table.rows)
                     + f" | **{table.mean:.4f}** |")
    sizes = ", ".join(f"{k} {v}" for k, v in settings.sizes().items())
    head = (f"Baselines on the procedural `{preset}` preset ({len(names)} categories; objects per category: "
            f"{sizes}), split `{split}`: {len(located)} objects x 24 views = {len(cat)} images, benchmark "
            f"protocol, `{settings.voxel_rule}` ground truth; oracle on a {GRID_RESOLUTION}^3 grid over "
            f"[-{HALF_SIDE}, {HALF_SIDE}]^3.")
    return head + "\n\n" + "\n".join(lines) + "\n", summary


EXAMPLES = """\
examples:
  python -m benchmarks.procedural_baselines                    # data=procedural_bench, test split
  python -m benchmarks.procedural_baselines --preset demo --split val
"""


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, epilog=EXAMPLES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", choices=("demo", "bench"), default="bench")
    parser.add_argument("--split", choices=("train", "val", "test"), default="test")
    parser.add_argument("--cache-dir", type=Path, default=None, help="default: data/cache")
    parser.add_argument("--out", type=Path, default=None, help="default: docs/procedural_baselines_<preset>.md")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    start = time.time()
    table, _ = baseline_table(args.preset, args.split, args.cache_dir)
    text = (f"# Procedural benchmark: baselines\n\nCommand: `python -m benchmarks.procedural_baselines --preset "
            f"{args.preset} --split {args.split}` ({time.time() - start:.0f} s, the dataset already generated "
            f"or not).\n\n{machine_info()}\n\n{table}")
    print(text)
    if not args.no_write:
        out = args.out or ROOT / "docs" / f"procedural_baselines_{args.preset}.md"
        atomic_write_text(out, text)
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
