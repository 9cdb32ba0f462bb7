"""One-time preparation of NMR ShapeNet data: compressed npz -> memory-mappable npy.

    python data/prepare_nmr.py /path/to/NMR [--out DIR] [--categories 02691156 chair ...]
                               [--splits train val test] [--overwrite]

Validates every ``{cid}_{split}_{images,voxels}.npz`` (present, readable, shapes and dtypes, equal
object counts; errors name the file), then writes ``{cid}_{split}_{images,voxels}.npy`` next to them
(or into --out) chunk by chunk through temporary files, so an interrupted run leaves no partial
array. The data module (``data=nmr``) then memory-maps them: every worker shares one copy.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from svr.nmr.format import SPLITS, prepare_nmr


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", help="folder holding {cid}_{split}_images.npz / _voxels.npz")
    parser.add_argument("--out", default=None, help="where the .npy files go (default: root)")
    parser.add_argument("--categories", nargs="*", default=None, help="ids or names (default: all 13)")
    parser.add_argument("--splits", nargs="*", default=list(SPLITS), choices=SPLITS)
    parser.add_argument("--overwrite", action="store_true", help="rewrite .npy files that already exist")
    args = parser.parse_args(argv)
    start = time.time()
    try:
        paths = prepare_nmr(args.root, args.out, args.categories, args.splits, overwrite=args.overwrite)
    except (FileNotFoundError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(f"{len(paths)} prepared arrays in {Path(args.out or args.root)} ({time.time() - start:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
