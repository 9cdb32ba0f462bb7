"""Generates the procedural single-view dataset in the NMR ShapeNet layout.

    python data/make_procedural.py [--cache-dir data/cache | --out DIR] [--train 32 --val 4 --test 6]
                                   [--categories chair mug ...] [--seed 0] [--supersample 4]
                                   [--voxel-rule centre|protocol]

With --cache-dir (the default, ``data/cache``) the dataset goes to
``<cache-dir>/procedural-<hash of the settings>`` and is reused if it exists, exactly as the
``data=procedural`` data module does on first use; --out writes a fresh folder. Prints the folder.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from svr.data.procedural import (PROCEDURAL_CATEGORIES, ProceduralSettings,  # noqa: E402
                                 ensure_procedural_dataset, generate_procedural_dataset)


def main(argv: list[str] | None = None) -> int:
    defaults = ProceduralSettings()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--cache-dir", default=str(REPO / "data" / "cache"))
    where.add_argument("--out", default=None, help="write into this new folder instead of the cache")
    parser.add_argument("--categories", nargs="*", default=None,
                        help=f"names or ids (default: all of {[c.name for c in PROCEDURAL_CATEGORIES]})")
    parser.add_argument("--train", type=int, default=defaults.train, help="objects per category")
    parser.add_argument("--val", type=int, default=defaults.val)
    parser.add_argument("--test", type=int, default=defaults.test)
    parser.add_argument("--seed", type=int, default=defaults.seed)
    parser.add_argument("--supersample", type=int, default=defaults.supersample, help="rays per pixel side")
    parser.add_argument("--voxel-rule", default=defaults.voxel_rule, choices=("centre", "protocol"),
                        help="ground-truth voxels: centre inside (SPEC) or the benchmark's voxelisation")
    args = parser.parse_args(argv)
    try:
        settings = ProceduralSettings(tuple(args.categories or ()), args.train, args.val, args.test, args.seed,
                                      args.supersample, args.voxel_rule)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    start = time.time()
    if args.out:
        path = generate_procedural_dataset(args.out, settings)
    else:
        path = ensure_procedural_dataset(args.cache_dir, settings)
    print(f"{path} ({time.time() - start:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
