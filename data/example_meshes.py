"""Example meshes with a known answer, for the builder's checks, tests, benchmarks and a first try:

    python data/example_meshes.py outputs/example_meshes

writes ``write_example_meshes``'s folder, which ``python -m svr.data.build
input=outputs/example_meshes out=outputs/example_nmr`` builds. Made here: the analytic
solids (``SOLIDS``: sphere, torus, box, as CSG shapes whose exact inside is known), the procedural
categories' shapes, both exported as meshes by marching cubes of their exact SDF (``shape_mesh``),
the damage real CAD meshes carry (``damage``: a patch of faces removed, a few faces flipped, a
duplicated inner shell) and ``write_example_meshes``, a small flat-layout folder (3 categories of 5
meshes: enough for every split of each, see docs/data.md) of coloured OBJ files (with their MTL)
and the other formats the builder reads.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sdfcommon.numerics.meshing import sdf_to_mesh
from sdfcommon.tooling.outputs import write_mesh, write_text
from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.generator import make_shape, sample_near_surface

# The solids, normalised as NMR's objects are (centred, longest side 1).
SOLIDS: dict[str, Callable[[], CSGShape]] = {
    "sphere": lambda: CSGBuilder().sphere((0.0, 0.0, 0.0), 0.5).shape().normalized(),
    "torus": lambda: CSGBuilder().torus((0.0, 0.0, 0.0), 0.34, 0.16, rotation((1.0, 0.0, 0.0), 0.4))
    .shape().normalized(),
    "box": lambda: CSGBuilder().box((0.0, 0.0, 0.0), (0.5, 0.3, 0.2), rotation((0.0, 1.0, 0.0), 0.3))
    .shape().normalized(),
}
DAMAGES = ("clean", "hole", "flipped", "scrambled", "inner_shell", "all")
HOLE_RADIUS = 0.12         # world units (about 4 voxels): the patch removed around the point farthest
HOLE_DIRECTION = np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)  # ... along this direction
FLIPPED_FRACTION = 0.02    # of the faces, reversed at random
INNER_SHELL_OFFSET = 0.04  # world units: the duplicated shell, moved inwards along the vertex normals


def shape_mesh(shape: CSGShape, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """A watertight, outward-oriented mesh of a shape: marching cubes of its exact SDF sampled on a
    ``resolution``^3 grid over the NMR object box (a margin of two voxels around [-0.5, 0.5]^3).

    Returns:
        vertices (V, 3) float64 world, faces (F, 3) int64.
    """
    half = 0.5 + 2.0 / 31.0
    values = sample_near_surface(shape, np.linspace(-half, half, resolution))
    mesh = sdf_to_mesh(values, -half, half, close=True)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def procedural_mesh(category: str, seed: Sequence[int], resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """``shape_mesh`` of a procedural category's shape (``make_shape(category, seed)``)."""
    return shape_mesh(make_shape(category, list(seed)), resolution)


def damage(vertices: np.ndarray, faces: np.ndarray, kind: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A damaged copy of a closed mesh.

    Args:
        kind: "clean" (unchanged), "hole" (the faces whose centroid lies within ``HOLE_RADIUS`` of
            the vertex farthest along ``HOLE_DIRECTION`` removed), "flipped" (``FLIPPED_FRACTION`` of the faces,
            at least one, reversed), "scrambled" (every face reversed with probability 1/2: no
            orientation at all, as many CAD exports), "inner_shell" (a copy moved ``INNER_SHELL_OFFSET`` inwards along
            the vertex normals added, same orientation: every point inside it is inside twice) or
            "all" (the three at once).
    Returns:
        vertices, faces.
    """
    if kind not in DAMAGES:
        raise ValueError(f"kind must be one of {DAMAGES}, got {kind!r}")
    v, f = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    if kind in ("hole", "all"):
        tip = v[np.argmax(v @ HOLE_DIRECTION)]
        f = f[np.linalg.norm(v[f].mean(1) - tip, axis=1) > HOLE_RADIUS]
        used, f = np.unique(f, return_inverse=True)  # the hole's vertices go too
        v, f, faces = v[used], f.reshape(-1, 3), f.reshape(-1, 3)
    if kind in ("flipped", "scrambled", "all"):
        rng = np.random.default_rng(seed)
        if kind == "scrambled":
            pick = np.nonzero(rng.random(len(f)) < 0.5)[0]
        else:
            pick = rng.choice(len(f), max(1, int(round(FLIPPED_FRACTION * len(f)))), replace=False)
        f = f.copy()
        f[pick] = f[pick][:, ::-1]
    if kind in ("inner_shell", "all"):
        tri = v[faces]
        area_normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # of the closed mesh
        normals = np.zeros_like(v)
        for corner in range(3):
            np.add.at(normals, faces[:, corner], area_normals)
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        f = np.concatenate([f, f + len(v)])
        v = np.concatenate([v, v - INNER_SHELL_OFFSET * normals])
    return v, f


def write_obj(path: Path, vertices: np.ndarray, faces: np.ndarray, colours: Sequence[Sequence[float]]) -> None:
    """An OBJ with an MTL beside it: the faces split into ``len(colours)`` consecutive groups, each
    with its material's Kd."""
    mtl = path.with_suffix(".mtl")
    write_text(mtl, "".join(f"newmtl m{k}\nKa 0 0 0\nKd {c[0]:.4f} {c[1]:.4f} {c[2]:.4f}\n"
                            for k, c in enumerate(colours)))
    lines = [f"mtllib {mtl.name}"] + [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    groups = np.array_split(np.arange(len(faces)), len(colours))
    for k, group in enumerate(groups):
        lines.append(f"usemtl m{k}")
        lines.extend(f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces[group])
    write_text(path, "\n".join(lines) + "\n")


EXAMPLE_CATEGORIES = ("chair", "sofa", "table")
# The table's meshes take these formats in turn (OBJ with its MTL; PLY and GLB with face colours).
TABLE_FORMATS = ("stl", "off", "glb", "obj", "ply")


def write_example_meshes(folder: Path, resolution: int = 40, per_category: int = 5) -> list[Path]:
    """A small flat-layout input (``<category>/<name>.<ext>``): three NMR categories by name,
    ``per_category`` procedural shapes each (seeds 1, 2, ...): chairs in two colours (OBJ + MTL),
    sofas (PLY with face colours) and tables in the formats of ``TABLE_FORMATS`` in turn. With 3
    or more per category the builder's default split_ratios give every split of each an object.
    Returns the files."""
    import trimesh  # heavy: only the example needs it

    folder = Path(folder)
    made = []
    for k in range(per_category):
        v, f = procedural_mesh("chair", (1 + k,), resolution)
        path = folder / "chair" / f"chair_{k}.obj"
        write_obj(path, v, f, [(0.6, 0.3, 0.1), (0.15, 0.15, 0.15)])
        made.append(path)
        v, f = procedural_mesh("sofa", (1 + k,), resolution)
        sofa = trimesh.Trimesh(v, f, process=False)
        sofa.visual.face_colors = np.tile([40, 90, 160, 255], (len(f), 1))
        made.append(write_mesh(folder / "sofa" / f"sofa_{k}.ply", sofa))
        v, f = procedural_mesh("table", (1 + k,), resolution)
        ext = TABLE_FORMATS[k % len(TABLE_FORMATS)]
        path = folder / "table" / f"table_{k}.{ext}"
        if ext == "obj":
            write_obj(path, v, f, [(0.8, 0.8, 0.75)])
        else:
            table = trimesh.Trimesh(v, f, process=False)
            table.visual.face_colors = np.tile([200, 200, 190, 255], (len(f), 1))
            write_mesh(path, table)
        made.append(path)
    return sorted(made)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Writes the example meshes (3 categories, 5 meshes each).")
    parser.add_argument("out", help="the folder to write (<category>/<name>.<ext>)")
    parser.add_argument("--per-category", type=int, default=5, help="meshes per category (default 5)")
    args = parser.parse_args(argv)
    if args.per_category < 1:
        parser.error(f"--per-category must be an integer >= 1, got {args.per_category}")
    made = write_example_meshes(Path(args.out), per_category=args.per_category)
    print(f"wrote {len(made)} meshes ({len(EXAMPLE_CATEGORIES)} categories x {args.per_category}) into {args.out}")
    return 0


__all__ = ["SOLIDS", "DAMAGES", "EXAMPLE_CATEGORIES", "TABLE_FORMATS", "shape_mesh", "procedural_mesh", "damage",
           "write_obj", "write_example_meshes"]


if __name__ == "__main__":
    sys.exit(main())
