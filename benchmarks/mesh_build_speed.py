"""Throughput of the mesh-to-NMR builder (``svr.data.build``) in meshes per minute, run as ``python -m
benchmarks.mesh_build_speed``. It makes its own input (nothing is downloaded): the 13 procedural NMR
categories' shapes, two seeds each, exported by marching cubes at the grid sizes that give about 3k,
15k and 50k triangles (the report gives the counts) as OBJ files with a two-material MTL in the flat
layout, repeated to ``--objects`` meshes; then it times whole builds at the default settings
(``configs/build.yaml``: 24 views of 64^2 at 3 x 3 samples, 32^3 voxels from 13 line directions,
all cores), wall clock from the call to the packed folder (pool start and packing included), and
reports the median of ``--repeats`` builds in docs/mesh_build_speed.md and .json.
"""
from __future__ import annotations

import argparse
import json
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from benchmarks.common import atomic_write_text, machine_info
from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.processes import default_workers
from sdfcommon.tooling.settings import build_settings
from svr.data.build.dataset import build_dataset
from data.example_meshes import procedural_mesh, write_obj
from svr.data.procedural.categories import NMR_PROCEDURAL_CATEGORIES

ROOT = Path(__file__).resolve().parents[1]
TARGETS = (3000, 15000, 50000)  # triangles of the three mesh sizes (reached to within ~15%)
PROBE_GRID = 64
SEEDS = (0, 1)
COLOURS = ((0.55, 0.35, 0.2), (0.2, 0.25, 0.3))


def make_meshes(folder: Path, objects: int) -> list[int]:
    """Writes ``objects`` OBJ meshes (``<category>/<name>.obj``) into ``folder``; returns their
    triangle counts. Unique meshes are made once and copied."""
    unique = []
    for cat in NMR_PROCEDURAL_CATEGORIES:
        for target in TARGETS:
            for seed in SEEDS:
                unique.append((cat.name, target, seed))
    counts = []
    made: dict[tuple, tuple[Path, int]] = {}
    for k in range(objects):
        name, target, seed = unique[k % len(unique)]
        path = folder / name / f"{name}_{target}_{seed}_{k:05d}.obj"
        if (name, target, seed) in made:
            src, n = made[(name, target, seed)]
            path.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, path)
            shutil.copyfile(src.with_suffix(".mtl"), path.with_suffix(".mtl"))
        else:
            # Triangles grow as the grid side squared: the side that gives about the target.
            v, f = procedural_mesh(name, (seed,), PROBE_GRID)
            grid = int(np.clip(round(PROBE_GRID * np.sqrt(target / len(f)) / 4) * 4, 16, 512))
            if grid != PROBE_GRID:
                v, f = procedural_mesh(name, (seed,), grid)
            write_obj(path, v, f, COLOURS)
            n = len(f)
            made[(name, target, seed)] = (path, n)
        counts.append(n)
    return counts


def measure(objects: int = 240, repeats: int = 3, workers: Optional[int] = None,
            mesh_dir: Optional[Path] = None) -> dict:
    """Builds the meshes ``repeats`` times; returns the figures (see the module docstring)."""
    with tempfile.TemporaryDirectory(prefix="mesh_build_speed_") as tmp:
        meshes = Path(mesh_dir) if mesh_dir is not None else Path(tmp) / "meshes"
        triangles = make_meshes(meshes, objects)
        rates, seconds = [], []
        for r in range(repeats):
            out = Path(tmp) / f"out{r}"
            overrides = [f"input={meshes}", f"out={out}", "progress=false"]
            if workers is not None:
                overrides.append(f"workers={workers}")
            settings = build_settings(compose("build", overrides))
            start = time.perf_counter()
            report = build_dataset(settings)
            elapsed = time.perf_counter() - start
            if report.built != objects:
                raise RuntimeError(f"built {report.built} of {objects} meshes: {report.skipped}")
            seconds.append(elapsed)
            rates.append(objects / elapsed * 60.0)
            shutil.rmtree(out)
    tri = np.asarray(triangles)
    return {
        "objects": objects, "repeats": repeats,
        "workers": workers if workers is not None else default_workers(),
        "triangles": {"min": int(tri.min()), "median": int(np.median(tri)), "mean": int(tri.mean()),
                      "max": int(tri.max()), "targets": list(TARGETS)},
        "seconds": [round(s, 2) for s in seconds],
        "meshes_per_minute": [round(x, 1) for x in rates],
        "median_meshes_per_minute": round(statistics.median(rates), 1),
    }


def markdown(result: dict, command: str) -> str:
    t = result["triangles"]
    rows = "\n".join(f"| {k + 1} | {s:.1f} | {r:.0f} |" for k, (s, r) in
                     enumerate(zip(result["seconds"], result["meshes_per_minute"])))
    return f"""# Mesh-to-NMR builder throughput

Made by `{command}` (benchmarks/mesh_build_speed.py; its docstring says what is timed).

**{result['median_meshes_per_minute']:.0f} meshes per minute** (median of {result['repeats']} builds of
{result['objects']} meshes, {result['workers']} worker processes, default settings of configs/build.yaml).

Meshes: the 13 procedural NMR categories' shapes (2 seeds) exported by marching cubes on the grid
that gives about {', '.join(str(x) for x in t['targets'])} triangles, repeated to {result['objects']};
triangles min {t['min']}, median {t['median']}, mean {t['mean']}, max {t['max']}; OBJ files with a
two-material MTL, flat layout.

| build | seconds | meshes / min |
| --- | --- | --- |
{rows}

Machine:

{machine_info()}
"""


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", type=int, default=240)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", type=int, default=None, help="default: one per core")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "mesh_build_speed",
                        help="writes <out>.md and <out>.json")
    args = parser.parse_args(argv)
    result = measure(args.objects, args.repeats, args.workers)
    command = "python -m benchmarks.mesh_build_speed" + (f" --objects {args.objects}" if args.objects != 240 else "")
    atomic_write_text(args.out.with_suffix(".json"), json.dumps(result, indent=2) + "\n")
    atomic_write_text(args.out.with_suffix(".md"), markdown(result, command))
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
