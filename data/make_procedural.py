"""Generates the procedural single-view dataset in the NMR ShapeNet layout.

    python data/make_procedural.py [--preset demo|bench] [--cache-dir data/cache | --out DIR]
                                   [--train N --val N --test N] [--categories chair mug ...] [--seed 0]
                                   [--supersample 3] [--voxel-rule protocol|centre] [--extra-views K]
                                   [--workers N]

``--preset`` takes the sizes and settings of ``data=procedural`` (demo, the default) or
``data=procedural_bench`` (configs/data/*.yaml); the other options override them. With --cache-dir
(the default, ``data/cache``) the dataset goes to ``<cache-dir>/procedural-<hash of the settings>``,
exactly where the data module of the same settings looks, and is reused if it exists; --out writes
a fresh folder. A killed generation continues where it stopped when the same command runs again.
Prints the folder, the time and the size on disk.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from sdfcommon.tooling.checks import check_int  # noqa: E402
from sdfcommon.tooling.commands import compose  # noqa: E402
from svr.data.procedural.generator import (ALL_CATEGORIES, VOXEL_RULES, ProceduralSettings, default_workers,  # noqa: E402
                                 ensure_procedural_dataset, generate_procedural_dataset)

PRESETS = {"demo": "procedural", "bench": "procedural_bench"}  # configs/data/<name>.yaml


def preset_settings(name: str) -> dict:
    """The dataset settings of a data preset, as hydra composes ``data=<preset>`` for training."""
    cfg = compose("eval", [f"data={PRESETS[name]}"]).data
    return {"categories": cfg.categories or (), "train": cfg.train, "val": cfg.val, "test": cfg.test,
            "seed": cfg.data_seed, "supersample": cfg.supersample, "voxel_rule": cfg.voxel_rule,
            "extra_views": cfg.extra_views}


def folder_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.iterdir() if f.is_file())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", choices=sorted(PRESETS), default="demo",
                        help="start from data=procedural (demo) or data=procedural_bench (bench)")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--cache-dir", default=str(REPO / "data" / "cache"))
    where.add_argument("--out", default=None, help="write into this new folder instead of the cache")
    parser.add_argument("--categories", nargs="*", default=None,
                        help=f"names or ids (default: the 13 NMR categories; all: {[c.name for c in ALL_CATEGORIES]})")
    parser.add_argument("--train", type=int, default=None, help="objects per category (default: the preset's)")
    parser.add_argument("--val", type=int, default=None)
    parser.add_argument("--test", type=int, default=None)
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--supersample", type=int, default=None, help="rays per pixel side")
    parser.add_argument("--voxel-rule", default=None, choices=VOXEL_RULES,
                        help="ground-truth voxels: the benchmark's voxelisation (protocol) or centre inside")
    parser.add_argument("--extra-views", type=int, default=None,
                        help="extra random views per training object (any azimuth, elevation 10-50 degrees)")
    parser.add_argument("--workers", type=int, default=default_workers(),
                        help="generating processes (default: one per core; 0: this process)")
    args = parser.parse_args(argv)
    values = preset_settings(args.preset)
    for key in ("train", "val", "test", "seed", "supersample", "voxel_rule", "extra_views"):
        if getattr(args, key) is not None:
            values[key] = getattr(args, key)
    if args.categories:
        values["categories"] = args.categories
    try:
        settings = ProceduralSettings(**{**values, "categories": tuple(values["categories"])})
        check_int(args.workers, "--workers", minimum=0)
    except ValueError as err:
        print(f"make_procedural: error: {err}", file=sys.stderr)
        return 2
    start = time.time()
    try:
        if args.out:
            path = generate_procedural_dataset(args.out, settings, workers=args.workers)
        else:
            path = ensure_procedural_dataset(args.cache_dir, settings, workers=args.workers)
    except (FileExistsError, OSError) as err:
        print(f"make_procedural: error: {err}", file=sys.stderr)
        return 1
    objects = sum(settings.sizes().values()) * len(settings.categories)
    print(f"{path}: {objects} objects, {folder_bytes(path) / 2**20:.0f} MiB, {time.time() - start:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
