"""Multi-view reconstruction benchmark, run as ``python -m benchmarks.mvr_accuracy_shapes [SHAPE ...]
[--extra OVERRIDE ...]``: the torus (the paper's 0.015637) and other shapes, each reconstructed with
the default settings of ``python -m mvr`` (configs/mvr.yaml). Each shape runs as
``python -m mvr target=<shape> out_dir=<work>/<shape>`` would, in this process
(``mvr.reconstruct_with_overrides``), one at a time (a finished run is reused: delete its folder to redo
it); the table goes to docs/mvr_shapes.md and each run's views.png to
docs/mvr_views_<shape>.png.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path

from benchmarks.common import atomic_write_text, machine_info
import mvr
from mvr import reconstruct_with_overrides

DEFAULT_SHAPES = ("torus", "double_torus", "blob", "rounded_box")
PAPER = {"torus": 0.015637}


def run_shape(shape: str, out_dir: Path, extra: list[str]) -> tuple[dict, float]:
    """Runs (or reuses) one reconstruction; returns its metrics and the load average."""
    metrics_file = out_dir / "metrics.json"
    load = os.getloadavg()[0]
    if not metrics_file.is_file():
        reconstruct_with_overrides(shape, out_dir, extra)
        load = (load + os.getloadavg()[0]) / 2
    return json.loads(metrics_file.read_text()), load


EXAMPLES = """\
examples:
  python -m benchmarks.mvr_accuracy_shapes                      # torus double_torus blob rounded_box
  python -m benchmarks.mvr_accuracy_shapes torus --extra optim.max_passes=8
"""


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, epilog=EXAMPLES,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("shapes", nargs="*", default=list(DEFAULT_SHAPES))
    ap.add_argument("--work", type=Path, default=Path("outputs/mvr_shapes"))
    ap.add_argument("--docs", type=Path, default=Path("docs"))
    ap.add_argument("--extra", nargs="*", default=[], help="hydra overrides passed to every run")
    args = ap.parse_args(argv)

    mvr.configure_runtime(threads=1)  # one thread, as docs/mvr_shapes.md was measured (the command: every core)
    rows = []
    for shape in args.shapes:
        t0 = time.perf_counter()
        m, load = run_shape(shape, args.work / shape, args.extra)
        print(f"{shape}: hausdorff_rel {m['hausdorff_rel']}, chamfer_rel {m['chamfer_rel']}, "
              f"{m['seconds']:.0f}s (this call {time.perf_counter() - t0:.0f}s)", flush=True)
        views = args.work / shape / "views.png"
        if views.is_file():
            args.docs.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(views, args.docs / f"mvr_views_{shape}.png")
        rows.append((shape, m, load))
    lines = [
        "# Multi-view reconstruction benchmark",
        "",
        "`python -m benchmarks.mvr_accuracy_shapes`: each shape is reconstructed with the settings of "
        "`python -m mvr target=<shape> out_dir=...`" + (f" with `{' '.join(args.extra)}`" if args.extra else "")
        + " (the defaults of `configs/mvr.yaml`: sphere at 8^3, levels 8/16/32/64, the paper's image "
        "rule, 26 views). Errors are relative to the target's bounding-box diagonal, from 50k surface "
        "samples per mesh; seconds cover the whole run (target, images, optimisation, evaluation) on "
        "2 CPU cores shared with other jobs (the load average during each run is given).",
        "",
        "| shape | hausdorff_rel | chamfer_rel | paper (Hausdorff) | seconds | load avg | genus (target / ours) "
        "| grids | images (px) | updates |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for shape, m, load in rows:
        h = m["hausdorff_rel"]
        lines.append(
            f"| {shape} | {h:.4f} | {m['chamfer_rel']:.5f} | {PAPER.get(shape, '')} | {m['seconds']:.0f} | "
            f"{load:.1f} | {m['target_genus']:g} / {m['mesh_genus']:g} | "
            f"{' '.join(str(r) for r in m['resolutions'])} | {' '.join(str(s) for s in m['image_sizes'])} | "
            f"{m['updates']} |" if h is not None else f"| {shape} | failed: {m.get('error')} |||||||||")
    lines += ["", "Views (rows: target, reconstruction rendered by our renderer, |difference|):", ""]
    lines += [f"![{shape}](mvr_views_{shape}.png)" for shape, _, _ in rows]
    lines += ["", "Machine:", "", machine_info({"torch threads used": 1}), ""]
    atomic_write_text(args.docs / "mvr_shapes.md", "\n".join(lines))
    print(f"wrote {args.docs / 'mvr_shapes.md'}")


if __name__ == "__main__":
    main()
