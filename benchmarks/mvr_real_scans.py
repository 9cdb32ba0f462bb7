"""Multi-view reconstruction of real scanned meshes (accuracy, time and a picture of where the
error is), run as ``python -m benchmarks.mvr_real_scans MESH_FOLDER [options]``. MESH_FOLDER holds
the meshes (.off .obj .ply .stl .glb; README.md says how to get CGAL's scans from Debian's
``libcgal-demo`` package); nothing is downloaded. Every mesh (and each built-in shape of
``--shapes``, by default the torus) is reconstructed once per configuration of ``--configs``:
``default``, ``python -m mvr``'s defaults (configs/mvr.yaml), and ``paper``, the paper's settings
(``mvr/preset=paper``), the baseline measured in the same run. A mesh that is not watertight is
closed by ``trimesh.repair.fill_holes`` when it has at most ``--max-hole-edges`` boundary edges (the
repaired copy goes to ``OUT/meshes/``), and otherwise left out with the reason in the table. Each
run writes its usual folder ``OUT/<config>/<mesh>/`` (a finished one, with metrics.json, is reused
unless ``--fresh``) plus ``errors.png``: the target coloured by its distance to the reconstruction
and the reconstruction by its distance to the target (red: at least ``--error-scale`` of the
bounding-box diagonal), and ``grid_truth.json``: the target's own signed distance sampled on the
run's final grid, meshed and scored alike (what the resolution alone loses). The table (markdown,
CSV, JSON) goes to OUT, and a copy of the markdown with the command and the machine to
``DOCS/mvr_real_scans.md`` (with the default configuration's error pictures) unless ``--docs ''``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import trimesh

from benchmarks.common import load_average, machine_info
import mvr
from mvr import MESH_FORMATS, SHAPES, reconstruct_with_overrides
from mvr.error_map import error_picture
from mvr.metrics import one_sided_distances
from mvr.reconstruct import default_scene
from mvr.settings import compose_config, reconstruct_kwargs
from mvr.targets import boundary_edges, close_small_holes
from sdfcommon.tooling import outputs
from sdfcommon.tooling.outputs import ensure_output_dir
from sdfcommon.tooling.settings import build_settings

CONFIGS = {"default": (), "paper": ("mvr/preset=paper",), "visibility": ("scene.gradient=visibility",),
           "carve": ("optim.carve=true",), "l1": ("optim.image_loss=l1",),
           "l1_pyramid": ("optim.image_loss=l1", "optim.image_levels=4"), "fine": ("mvr/preset=fine",)}
# Paper section 5, symmetric Hausdorff relative to the bounding box (SPEC.md section 2).
PAPER = {"torus": 0.015637, "bunny": 0.026654, "dragon": 0.074723}
COLUMNS = ("mesh", "config", "hausdorff_rel", "hausdorff99_rel", "chamfer_rel", "seconds", "pass_seconds",
           "watertight", "genus", "target_genus", "faces", "truth_hausdorff_rel", "truth_genus", "note")
ERROR_VIEWS = (0, 2, 4, 7, 18, 21)  # rig views shown in errors.png: four faces and two corners


@dataclass(frozen=True)
class PreparedMesh:
    """A benchmark target: ``target`` is what ``python -m mvr target=`` gets (a file or a built-in
    shape), or None when the mesh is left out (``note`` says why)."""

    name: str
    target: Optional[str]
    note: str = ""


def paper_value(name: str) -> Optional[float]:
    """The paper's relative Hausdorff distance for a mesh whose name contains one of its shapes."""
    for key, value in PAPER.items():
        if key in name.lower():
            return value
    return None


def prepare_meshes(folder: Path, names: Sequence[str], work: Path, max_hole_edges: int) -> list[PreparedMesh]:
    """The meshes of ``folder`` (all supported files, or those whose stem is in ``names``), each
    checked: watertight ones as they are; ones with at most ``max_hole_edges`` boundary edges closed
    (``mvr.targets.close_small_holes``, as ``target_settings.max_hole_edges`` does for a run) into
    ``work/<stem>.ply``; the rest left out with the reason."""
    if not folder.is_dir():
        raise ValueError(f"mesh folder {str(folder)!r} is not a folder")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in MESH_FORMATS and p.is_file())
    if names:
        by_stem = {p.stem: p for p in files}
        missing = [n for n in names if n not in by_stem]
        if missing:
            raise ValueError(f"mesh folder {str(folder)!r} has no mesh named {', '.join(missing)} "
                             f"(it has: {', '.join(sorted(by_stem)) or 'none'})")
        files = [by_stem[n] for n in names]
    if not files:
        raise ValueError(f"mesh folder {str(folder)!r} holds no mesh file ({', '.join(MESH_FORMATS)})")
    prepared = []
    for path in files:
        try:
            mesh = trimesh.load(str(path), force="mesh", process=True)
        except Exception as exc:  # trimesh raises many types for malformed files
            prepared.append(PreparedMesh(path.stem, None, f"left out: unreadable ({type(exc).__name__})"))
            continue
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            prepared.append(PreparedMesh(path.stem, None, "left out: no triangles"))
            continue
        if mesh.is_watertight:
            prepared.append(PreparedMesh(path.stem, str(path)))
            continue
        open_edges = boundary_edges(mesh)
        if open_edges > max_hole_edges:
            prepared.append(PreparedMesh(path.stem, None, f"left out: {open_edges} boundary edges "
                                                           f"(> --max-hole-edges {max_hole_edges})"))
            continue
        try:
            close_small_holes(mesh, max_hole_edges, str(path))
        except ValueError:
            prepared.append(PreparedMesh(path.stem, None, f"left out: still open after filling its "
                                                           f"{open_edges} boundary edges"))
            continue
        repaired = work / f"{path.stem}.ply"
        outputs.write_mesh(repaired, mesh)
        prepared.append(PreparedMesh(path.stem, str(repaired), f"{open_edges} boundary edges closed (fill_holes)"))
    return prepared


def percentile_distance_rel(recon_file: Path, target_file: Path, samples: int = 20_000, q: float = 99.0,
                            seed: int = 0) -> float:
    """The ``q``-th percentile of the symmetric surface distance (both sides' samples pooled),
    divided by the target's bounding-box diagonal: how far the worst 1% lie, less sensitive to a
    single stray point than the Hausdorff distance."""
    recon = trimesh.load(str(recon_file), force="mesh", process=False)
    target = trimesh.load(str(target_file), force="mesh", process=False)
    a, _ = trimesh.sample.sample_surface(recon, samples, seed=seed)
    b, _ = trimesh.sample.sample_surface(target, samples, seed=seed + 1)
    d = np.concatenate([one_sided_distances(a, target), one_sided_distances(b, recon)])
    lo, hi = target.bounds
    return float(np.percentile(d, q) / np.linalg.norm(hi - lo))


def write_error_picture(run_dir: Path, overrides: Sequence[str], error_scale: float, image_size: int = 320) -> Path:
    """``run_dir/errors.png`` from the run's mesh.ply and target.ply (``mvr.error_map``), seen by the
    rig of the run's configuration; red marks distances of ``error_scale`` bbox diagonals or more."""
    kw = reconstruct_kwargs(compose_config(["target=unused", "out_dir=unused", *overrides]))
    recon = trimesh.load(str(run_dir / "mesh.ply"), force="mesh", process=False)
    target = trimesh.load(str(run_dir / "target.ply"), force="mesh", process=False)
    lo, hi = target.bounds
    vmax = error_scale * float(np.linalg.norm(hi - lo))
    cams = kw["rig"].cameras(image_size)[list(ERROR_VIEWS)]
    picture = error_picture(target, recon, cams, kw["scene"] or default_scene(), vmax,
                            [f"view {v}" for v in ERROR_VIEWS])
    return outputs.write_png(run_dir / "errors.png", picture)


def grid_truth(run_dir: Path, samples: int = 50_000, seed: int = 0) -> dict:
    """The target's own signed distance sampled on the run's final grid (its resolution and box,
    ``grid.npz``; exact within three samples of the surface), meshed and scored as the run's grid is:
    what sampling at that resolution alone loses. A reference, not a bound: sampling drops a part
    thinner than a sample spacing and bridges a slot narrower than one, where a fit may keep the part
    thickened or open the slot widened. Cached in ``run_dir/grid_truth.json``.

    Returns:
        {"hausdorff_rel", "chamfer_rel", "genus", "resolution"}.
    """
    cache = run_dir / "grid_truth.json"
    if cache.is_file():
        return json.loads(cache.read_text())
    from scipy.spatial import cKDTree  # heavy: only this column needs these
    from sdfcommon.numerics.meshing import sdf_to_mesh
    from mvr.metrics import surface_distances

    grid = np.load(run_dir / "grid.npz")
    values, lo, hi = grid["values"], grid["bbox_min"].astype(np.float64), grid["bbox_max"].astype(np.float64)
    target = trimesh.load(run_dir / "target.ply", force="mesh", process=False)
    axes = [np.linspace(lo[i], hi[i], values.shape[i]) for i in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    # Marching cubes reads the values only in cells the surface crosses, whose corners lie within a
    # cell's diagonal of it: exact distances there, the distance to dense surface samples elsewhere.
    dense, _ = trimesh.sample.sample_surface(target, 200_000, seed=seed)
    distance, _ = cKDTree(np.vstack([dense, target.vertices])).query(points)
    near = distance < 3.0 * float(np.max((hi - lo) / (np.array(values.shape) - 1)))
    distance[near] = one_sided_distances(points[near], target)
    inside = target.contains(points)
    sdf = np.where(inside, -distance, distance).reshape(values.shape).astype(np.float32)
    mesh = sdf_to_mesh(sdf, lo, hi)
    dist = surface_distances(mesh, target, samples, seed)
    euler = mesh.euler_number if len(mesh.faces) else None
    result = {"hausdorff_rel": dist.hausdorff_rel, "chamfer_rel": dist.chamfer_rel,
              "genus": None if euler is None else (2 - euler) / 2, "resolution": int(values.shape[0])}
    outputs.write_json(cache, result)
    return result


def finest_pass_seconds(levels: Sequence[dict]) -> Optional[float]:
    """Mean seconds of a pass at the finest level, from a run's levels.json (its per-pass history)."""
    if not levels or not levels[-1].get("history"):
        return None
    return float(np.mean([h["seconds"] for h in levels[-1]["history"]]))


def result_row(mesh: PreparedMesh, config: str, metrics: Optional[dict], hausdorff99: Optional[float],
               pass_seconds: Optional[float] = None, truth: Optional[dict] = None) -> dict:
    """One table row (the COLUMNS) from a run's metrics (None: the mesh was left out) and its grid's
    sampled truth (``grid_truth``; None: not computed)."""
    if metrics is None or metrics.get("hausdorff_rel") is None:
        note = mesh.note if metrics is None else (metrics.get("error") or "failed")
        return {"mesh": mesh.name, "config": config, "note": note}
    return {"mesh": mesh.name, "config": config, "hausdorff_rel": metrics["hausdorff_rel"],
            "hausdorff99_rel": hausdorff99, "chamfer_rel": metrics["chamfer_rel"], "seconds": metrics["seconds"],
            "pass_seconds": pass_seconds,
            "watertight": metrics["mesh_watertight"], "genus": metrics["mesh_genus"],
            "target_genus": metrics["target_genus"], "faces": metrics["mesh_faces"],
            "truth_hausdorff_rel": None if truth is None else truth["hausdorff_rel"],
            "truth_genus": None if truth is None else truth["genus"], "note": mesh.note}


def _cell(row: dict, key: str) -> str:
    value = row.get(key)
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if key == "seconds":
            return f"{value:.0f}"
        if key == "pass_seconds":
            return f"{value:.1f}"
        if key in ("genus", "target_genus", "truth_genus"):
            return f"{value:g}"
        return f"{value:.4f}" if key != "chamfer_rel" else f"{value:.5f}"
    return str(value)


def markdown_table(rows: Sequence[dict], configs: Sequence[str]) -> str:
    """One line per mesh: for each configuration its relative Hausdorff (and 99th percentile),
    relative Chamfer, seconds, watertightness and genus (ours / target) and the Hausdorff distance of
    the truth on its grid, then the paper's value and the note."""
    by_mesh: dict[str, dict[str, dict]] = {}
    for row in rows:
        by_mesh.setdefault(row["mesh"], {})[row["config"]] = row
    head = ["mesh"]
    for c in configs:
        head += [f"{c}: H", f"{c}: H99", f"{c}: C", f"{c}: s", f"{c}: s/pass", f"{c}: watertight, genus",
                 f"{c}: truth on grid: H"]
    head += ["paper H", "note"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for mesh, runs in by_mesh.items():
        cells = [mesh]
        note = ""
        for c in configs:
            r = runs.get(c, {})
            note = note or r.get("note", "")
            topo = (f"{_cell(r, 'watertight')}, {_cell(r, 'genus')} / {_cell(r, 'target_genus')}"
                    if r.get("hausdorff_rel") is not None else "")
            cells += [_cell(r, "hausdorff_rel"), _cell(r, "hausdorff99_rel"), _cell(r, "chamfer_rel"),
                      _cell(r, "seconds"), _cell(r, "pass_seconds"), topo, _cell(r, "truth_hausdorff_rel")]
        paper = paper_value(mesh)
        cells += ["" if paper is None else f"{paper:g}", note]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def summary(rows: Sequence[dict], configs: Sequence[str], goal: float) -> str:
    """Per configuration: the worst relative Hausdorff distance, how many runs meet ``goal`` and
    the longest run."""
    out = []
    for c in configs:
        done = [r for r in rows if r["config"] == c and r.get("hausdorff_rel") is not None]
        if not done:
            continue
        worst = max(done, key=lambda r: r["hausdorff_rel"])
        slowest = max(done, key=lambda r: r["seconds"])
        met = sum(r["hausdorff_rel"] <= goal for r in done)
        truths = [r["truth_hausdorff_rel"] for r in done if r.get("truth_hausdorff_rel") is not None]
        truth = (f"; the truth on the same grids: {sum(t <= goal for t in truths)} of {len(truths)} at most "
                 f"{goal:g}, worst {max(truths):.4f}" if truths else "")
        out.append(f"- `{c}`: worst relative Hausdorff {worst['hausdorff_rel']:.4f} ({worst['mesh']}); "
                   f"{met} of {len(done)} at most {goal:g}; median Chamfer "
                   f"{float(np.median([r['chamfer_rel'] for r in done])):.5f}; longest run "
                   f"{slowest['seconds']:.0f} s ({slowest['mesh']}){truth}.")
    return "\n".join(out)


def run_one(mesh: PreparedMesh, config: str, out: Path, fresh: bool, error_scale: float,
            extra: Sequence[str]) -> dict:
    """Reconstructs one mesh with one configuration (or reuses the finished run), draws its error
    picture and returns its table row."""
    if mesh.target is None:
        return result_row(mesh, config, None, None)
    run_dir = out / config / mesh.name
    overrides = [*CONFIGS[config], *extra]
    metrics_file = run_dir / "metrics.json"
    if fresh or not metrics_file.is_file():
        if run_dir.exists():
            shutil.rmtree(run_dir)
        load_before = os.getloadavg()[0]
        reconstruct_with_overrides(mesh.target, run_dir, overrides)
        print(f"  load average {load_before:.1f} -> {os.getloadavg()[0]:.1f}", flush=True)
    metrics = json.loads(metrics_file.read_text())
    h99 = truth = None
    if metrics.get("hausdorff_rel") is not None:
        write_error_picture(run_dir, overrides, error_scale)
        h99 = percentile_distance_rel(run_dir / "mesh.ply", run_dir / "target.ply")
        truth = grid_truth(run_dir)
    levels = json.loads((run_dir / "levels.json").read_text())
    return result_row(mesh, config, metrics, h99, finest_pass_seconds(levels), truth)


def write_tables(rows: Sequence[dict], configs: Sequence[str], out: Path, docs: Optional[Path], command: str,
                 goal: float, error_scale: float, seed: str = "0") -> None:
    """OUT/table.md, table.csv, results.json; and DOCS/mvr_real_scans.md with the default
    configuration's error pictures copied beside it (``seed``: the runs' seed, as ``--extra`` set it)."""
    table = markdown_table(rows, configs)
    outputs.write_csv(out / "table.csv", list(rows), COLUMNS)
    outputs.write_json(out / "results.json", {"command": command, "configs": {c: list(CONFIGS[c]) for c in configs},
                                              "rows": list(rows)})
    text = "\n".join([
        "# Multi-view reconstruction of real scanned meshes",
        "",
        f"`{command}`",
        "",
        "The mesh folder holds CGAL's scans from Debian's `libcgal-demo` package (README.md, multi-view "
        f"section, gives the commands); each mesh is reconstructed once per configuration (seed {seed}).",
        "",
        "H: symmetric Hausdorff distance, H99: its 99th percentile (both sides' samples pooled), C: "
        "Chamfer distance, all relative to the target's bounding-box diagonal (50k samples per surface; "
        "H99 from 20k); s: seconds of the whole run (target, images, optimisation, evaluation); s/pass: "
        "mean seconds of a pass (26 views) at the finest level; "
        "watertight, genus: the reconstruction's mesh, then the target's genus; truth on grid: H: the "
        "target's own signed distance sampled on the run's final grid and meshed as the run's is (what "
        "sampling at that resolution loses; not a bound: a fit can keep a part thinner than a sample "
        "spacing, thickened, that sampling drops). Configurations: "
        + "; ".join(f"`{c}` = `python -m mvr {' '.join(CONFIGS[c]) or '(defaults)'}`" for c in configs) + ".",
        "",
        table,
        "",
        summary(rows, configs, goal),
        "",
        f"Error pictures (`errors.png` in each run's folder): red where the distance is at least "
        f"{error_scale:g} of the bounding-box diagonal. Where the error comes from: "
        "[mvr_method.md](mvr_method.md#real-scanned-meshes-where-the-error-is-issue-20).",
        "",
    ])
    outputs.write_text(out / "table.md", text + "\nMachine:\n\n" + machine_info() + "\n")
    if docs is None:
        return
    pictures = []
    for row in rows:
        src = out / "default" / row["mesh"] / "errors.png"
        if row["config"] == "default" and src.is_file():
            dst = docs / f"mvr_errors_{row['mesh']}.png"
            with outputs.atomic_path(dst) as tmp:  # the docs copy is written whole or not at all
                shutil.copyfile(src, tmp)
            pictures.append(f"![{row['mesh']}]({dst.name})")
    outputs.write_text(docs / "mvr_real_scans.md", text + "\n" + "\n\n".join(pictures)
                      + "\n\nMachine:\n\n" + machine_info() + "\n")


EXAMPLES = """\
examples:
  python -m benchmarks.mvr_real_scans MESH_FOLDER                      # every mesh in the folder
  python -m benchmarks.mvr_real_scans MESH_FOLDER --meshes elephant cow --configs default
  python -m benchmarks.mvr_real_scans MESH_FOLDER --out outputs/mvr_real_scans --docs docs
"""


def main(argv: Optional[list[str]] = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, epilog=EXAMPLES,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mesh_folder", type=Path, help="folder of meshes (never downloaded: see README.md)")
    ap.add_argument("--meshes", nargs="*", default=[], help="file stems to run (default: every mesh)")
    ap.add_argument("--shapes", nargs="*", default=["torus"], help="built-in shapes to add (default: torus)")
    ap.add_argument("--configs", nargs="*", default=["default", "paper"], choices=list(CONFIGS),
                    help="default and paper unless named; visibility: scene.gradient=visibility")
    ap.add_argument("--out", type=Path, default=Path("outputs/mvr_real_scans"))
    ap.add_argument("--docs", default="docs", help="folder for mvr_real_scans.md ('' for none)")
    ap.add_argument("--fresh", action="store_true", help="redo finished runs")
    ap.add_argument("--max-hole-edges", type=int, default=64)
    ap.add_argument("--error-scale", type=float, default=0.02, help="distance shown red (bbox diagonals)")
    ap.add_argument("--goal", type=float, default=0.02, help="relative Hausdorff the summary counts against")
    ap.add_argument("--extra", nargs="*", default=[], help="hydra overrides for every run")
    ap.add_argument("--table-only", action="store_true", help="only rebuild the table from finished runs")
    args = ap.parse_args(argv)

    try:
        unknown = [s for s in args.shapes if s not in SHAPES]
        if unknown:
            raise ValueError(f"--shapes: unknown shape {', '.join(unknown)} (built-in: {', '.join(SHAPES)})")
        if not args.error_scale > 0:
            raise ValueError(f"--error-scale must be positive, got {args.error_scale}")
        out = ensure_output_dir(args.out, "--out")
        docs = Path(args.docs) if args.docs else None
        if docs is not None:
            ensure_output_dir(docs, "--docs")
        meshes = prepare_meshes(args.mesh_folder, args.meshes, out / "meshes", args.max_hole_edges)
    except (ValueError, FileNotFoundError) as exc:
        sys.exit(f"mvr_real_scans: error: {exc}")
    meshes += [PreparedMesh(s, s) for s in args.shapes]
    threads = build_settings(compose_config(["target=unused", "out_dir=unused"])).runtime.threads
    mvr.configure_runtime(threads=threads)  # configs/mvr.yaml's runtime, as the command sets it
    command = "python -m benchmarks.mvr_real_scans " + " ".join(sys.argv[1:] if argv is None else argv)
    rows = []
    for mesh in meshes:
        for config in args.configs:
            if args.table_only and not (out / config / mesh.name / "metrics.json").is_file():
                continue
            t0 = time.perf_counter()
            print(f"{mesh.name} [{config}] ...", flush=True)
            row = run_one(mesh, config, out, args.fresh, args.error_scale, args.extra)
            rows.append(row)
            print(f"{mesh.name} [{config}]: H {row.get('hausdorff_rel')} C {row.get('chamfer_rel')} "
                  f"{row.get('seconds')} s ({time.perf_counter() - t0:.0f} s this call, load {load_average()}) "
                  f"{row.get('note', '')}", flush=True)
    seed = next((e.split("=", 1)[1] for e in args.extra if e.startswith("seed=")), "0")  # configs/mvr.yaml: 0
    write_tables(rows, args.configs, out, docs, command, args.goal, args.error_scale, seed)
    print(f"wrote {out / 'table.md'}" + (f" and {docs / 'mvr_real_scans.md'}" if docs else ""))
    if any(r.get("hausdorff_rel") is not None and not math.isfinite(r["hausdorff_rel"]) for r in rows):
        sys.exit(1)


if __name__ == "__main__":
    main()
