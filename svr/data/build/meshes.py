"""Mesh files as the builder uses them: ``load_mesh`` reads one file with trimesh (OBJ with its MTL,
OFF, PLY, STL, GLB/GLTF; a scene's parts are concatenated with their transforms applied), keeps a
colour per face (the material's diffuse colour, Kd of an MTL or a glTF base colour, face or vertex
colours of a PLY, else ``NEUTRAL_COLOUR``) and the textures trimesh reads with their per-vertex UVs,
and applies NMR's normalisation (bounding-box centre to the origin, longest side 1; SPEC 5b);
``analyse_mesh`` gives what the manifest records about its topology (triangles, watertight,
components, the fraction of edges whose two faces disagree in orientation).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numba
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from svr.data.procedural.appearance import NEUTRAL_COLOUR

MESH_SUFFIXES = (".obj", ".off", ".ply", ".stl", ".glb", ".gltf")
# A mesh with fewer triangles of non-zero area, or whose vertices all lie within this distance
# (a fraction of its longest side) of one plane, encloses no volume: no object to voxelise.
MIN_SOLID_TRIANGLES = 4  # a tetrahedron's
FLAT_TOLERANCE = 1e-5


class MeshError(ValueError):
    """A mesh file that cannot be built (unreadable, empty, degenerate); its message is one line."""


@dataclass(frozen=True)
class LoadedMesh:
    """A normalised triangle mesh with its appearance.

    Attributes:
        vertices: (V, 3) float64 world (y up), centred on the bounding box, longest side 1.
        faces: (F, 3) int32 vertex indices.
        face_colours: (F, 3) float64 albedo in [0, 1] of each face (textured faces: the factor that
            multiplies the texture).
        face_texture: (F,) int32 index into ``textures``, -1 for an untextured face.
        uv: (V, 2) float64 texture coordinates (0 where there are none).
        textures: (H, W, 3) float64 images in [0, 1], row 0 at the top.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_colours: np.ndarray
    face_texture: np.ndarray
    uv: np.ndarray
    textures: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class MeshStatistics:
    """What the manifest records about a mesh's topology (vertices merged where they coincide).

    Attributes:
        triangles: F. watertight: every edge is shared by exactly two faces.
        components: connected pieces (through shared vertices).
        inconsistent_edges: fraction of the edges shared by two faces that both faces traverse in
            the same direction (0 for a consistently oriented mesh).
    """

    triangles: int
    watertight: bool
    components: int
    inconsistent_edges: float


def _material_appearance(material, image_cache: dict) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """(colour (3,), texture image or None) of a trimesh material."""
    colour = None
    image = None
    for name in ("baseColorFactor", "diffuse", "main_color"):
        value = getattr(material, name, None)
        if value is not None:
            colour = np.asarray(value, dtype=np.float64).reshape(-1)[:3]
            colour = colour / 255.0 if colour.max() > 1.0 or np.asarray(value).dtype == np.uint8 else colour
            break
    for name in ("baseColorTexture", "image"):
        img = getattr(material, name, None)
        if img is not None:
            image = img
            break
    if image is not None:
        key = id(image)
        if key not in image_cache:
            arr = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
            image_cache[key] = arr if arr.ndim == 3 and arr.size else None
        image = image_cache[key]
        if getattr(material, "baseColorFactor", None) is None:
            colour = np.ones(3)  # an MTL's map_Kd replaces Kd (as Blender's importer uses it)
    if colour is None:
        colour = np.asarray(NEUTRAL_COLOUR, dtype=np.float64)
    return np.clip(colour, 0.0, 1.0), image


def _part_appearance(mesh, image_cache: dict) -> tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray]]:
    """(face colours (F, 3), texture or None, uv (V, 2) or None) of one trimesh.Trimesh."""
    n = len(mesh.faces)
    visual = mesh.visual
    kind = getattr(visual, "kind", None)
    if kind == "texture" and getattr(visual, "material", None) is not None:
        colour, image = _material_appearance(visual.material, image_cache)
        uv = getattr(visual, "uv", None)
        if image is not None and uv is not None and len(uv) == len(mesh.vertices):
            return np.tile(colour, (n, 1)), image, np.asarray(uv, dtype=np.float64)
        return np.tile(colour, (n, 1)), None, None
    if kind in ("face", "vertex"):
        fc = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0
        return fc, None, None
    return np.tile(np.asarray(NEUTRAL_COLOUR, dtype=np.float64), (n, 1)), None, None


def load_mesh(path: Path) -> LoadedMesh:
    """Reads, colours and normalises one mesh file (see the module docstring).

    Raises:
        MeshError naming the problem in one line (unreadable file, no triangles, NaN coordinates,
        a degenerate mesh: no extent, too few triangles, flat).
    """
    import trimesh  # heavy: only loading needs it

    try:
        loaded = trimesh.load(str(path), process=False)
    except Exception as err:  # trimesh raises many types for unreadable files
        text = " ".join(str(err).split()) or type(err).__name__
        raise MeshError(f"unreadable mesh ({type(err).__name__}: {text[:200]})") from None
    if isinstance(loaded, trimesh.Scene):
        parts = [g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
    elif isinstance(loaded, trimesh.Trimesh):
        parts = [loaded]
    else:
        parts = []
    parts = [p for p in parts if len(p.faces) and len(p.vertices)]
    if not parts:
        raise MeshError("no triangles in the file")
    images: dict = {}
    vertices, faces, colours, tex_index, uvs, textures = [], [], [], [], [], []
    offset = 0
    for part in parts:
        colour, image, uv = _part_appearance(part, images)
        vertices.append(np.asarray(part.vertices, dtype=np.float64))
        faces.append(np.asarray(part.faces, dtype=np.int64) + offset)
        colours.append(colour)
        if image is not None:
            tex_index.append(np.full(len(part.faces), len(textures), dtype=np.int32))
            textures.append(image)
            uvs.append(uv)
        else:
            tex_index.append(np.full(len(part.faces), -1, dtype=np.int32))
            uvs.append(np.zeros((len(part.vertices), 2)))
        offset += len(part.vertices)
    return normalised_mesh(np.concatenate(vertices), np.concatenate(faces), np.concatenate(colours),
                           np.concatenate(tex_index), np.concatenate(uvs), tuple(textures))


def normalised_mesh(vertices: np.ndarray, faces: np.ndarray, face_colours: Optional[np.ndarray] = None,
                    face_texture: Optional[np.ndarray] = None, uv: Optional[np.ndarray] = None,
                    textures: tuple[np.ndarray, ...] = ()) -> LoadedMesh:
    """A ``LoadedMesh`` of arrays, with NMR's normalisation: the bounding box of the vertices the
    faces use is centred on the origin and its longest side scaled to 1.

    Args:
        vertices: (V, 3) float. faces: (F, 3) int. face_colours: (F, 3) in [0, 1] (None: every
        face ``NEUTRAL_COLOUR``). face_texture, uv, textures: as ``LoadedMesh`` (None: untextured).
    Raises:
        MeshError for NaN coordinates, a bounding box with no extent or a mesh that encloses no
        volume (fewer than ``MIN_SOLID_TRIANGLES`` triangles of non-zero area, or flat).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if not len(f):
        raise MeshError("no triangles in the file")
    if not np.isfinite(v).all():
        raise MeshError("vertex coordinates contain NaN or Inf")
    used = v[np.unique(f)]
    lo, hi = used.min(0), used.max(0)
    size = float((hi - lo).max())
    if not size > 0:
        raise MeshError("degenerate mesh (its bounding box has no extent)")
    v = (v - (lo + hi) / 2.0) / size
    _check_solid(v, f)
    if face_colours is None:
        face_colours = np.tile(np.asarray(NEUTRAL_COLOUR, dtype=np.float64), (len(f), 1))
    if face_texture is None:
        face_texture, uv = np.full(len(f), -1, dtype=np.int32), np.zeros((len(v), 2))
    return LoadedMesh(v, f.astype(np.int32), np.asarray(face_colours, dtype=np.float64),
                      np.asarray(face_texture, dtype=np.int32), np.asarray(uv, dtype=np.float64), tuple(textures))


def _check_solid(vertices: np.ndarray, faces: np.ndarray) -> None:
    """Refuses a normalised mesh that cannot enclose a volume (see ``MIN_SOLID_TRIANGLES``)."""
    tri = vertices[faces]
    doubled_areas = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    n_real = int((doubled_areas > FLAT_TOLERANCE ** 2).sum())
    if n_real < MIN_SOLID_TRIANGLES:
        raise MeshError(f"degenerate mesh: {n_real} triangle(s) with non-zero area, a solid needs at least "
                        f"{MIN_SOLID_TRIANGLES}")
    used = vertices[np.unique(faces)]
    centred = used - used.mean(0)
    normal = np.linalg.eigh(centred.T @ centred)[1][:, 0]  # of the best-fitting plane
    if not np.abs(centred @ normal).max() > FLAT_TOLERANCE:
        raise MeshError("degenerate mesh: flat (all its vertices lie in one plane), it encloses no volume")


def merged_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) faces re-indexed so that coinciding vertices (equal coordinates) share one index."""
    rows = np.ascontiguousarray(vertices, dtype=np.float64).view(np.dtype((np.void, 24))).reshape(-1)
    _, inverse = np.unique(rows, return_inverse=True)
    return inverse.reshape(-1)[faces]


@numba.njit(cache=True)
def _orientation_parity(n_faces, first, second, opposite):  # pragma: no cover - compiled
    """Union-find with parity: faces joined by an edge must keep (``opposite`` False) or swap
    (True) their relative orientation. Returns (root, parity to the root) per face; an edge that
    contradicts the ones before it (a non-orientable or tangled piece) is ignored."""
    parent = np.arange(n_faces)
    parity = np.zeros(n_faces, dtype=np.uint8)
    for e in range(len(first)):
        roots = np.zeros(2, dtype=np.int64)
        pars = np.zeros(2, dtype=np.uint8)
        for side in range(2):
            x = first[e] if side == 0 else second[e]
            r, p = x, np.uint8(0)
            while parent[r] != r:
                p ^= parity[r]
                r = parent[r]
            y, q = x, p
            while parent[y] != y:  # path compression, keeping each node's parity to the root
                nxt, old = parent[y], parity[y]
                parent[y], parity[y] = r, q
                q ^= old
                y = nxt
            roots[side], pars[side] = r, p
        if roots[0] != roots[1]:
            parent[roots[1]] = roots[0]
            parity[roots[1]] = pars[0] ^ pars[1] ^ np.uint8(opposite[e])
    out_root = np.empty(n_faces, dtype=np.int64)
    out_par = np.empty(n_faces, dtype=np.uint8)
    for f in range(n_faces):
        r, p = f, np.uint8(0)
        while parent[r] != r:
            p ^= parity[r]
            r = parent[r]
        out_root[f], out_par[f] = r, p
    return out_root, out_par


def analyse_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[MeshStatistics, np.ndarray]:
    """Topology of a mesh (``MeshStatistics``, coinciding vertices merged) and its faces oriented
    consistently: within each piece of faces joined by manifold edges (two faces per edge) every
    face takes its neighbours' orientation, and a piece whose signed volume is negative (inside
    out) is turned over as a whole, so that the winding number of a closed piece is 1 inside.

    Returns:
        (statistics, (F, 3) faces with some rows reversed).
    """
    f = merged_faces(vertices, faces).astype(np.int64)
    n_faces = len(f)
    start = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    end = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    owner = np.tile(np.arange(n_faces), 3)
    real = start != end
    start, end, owner = start[real], end[real], owner[real]
    n = int(f.max()) + 1 if f.size else 1
    key = np.minimum(start, end) * n + np.maximum(start, end)
    order = np.argsort(key, kind="stable")
    key, start, owner = key[order], start[order], owner[order]
    _, index, counts = np.unique(key, return_index=True, return_counts=True)
    watertight = bool(len(counts)) and bool((counts == 2).all())
    pair = index[counts == 2]
    opposite = start[pair] == start[pair + 1]  # same direction: one face must turn over
    inconsistent = float(opposite.mean()) if len(pair) else 0.0
    root, parity = _orientation_parity(n_faces, owner[pair], owner[pair + 1], opposite)
    tri = np.asarray(vertices, dtype=np.float64)[faces]
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))
    sign = np.where(parity == 1, -1.0, 1.0)
    piece_volume = np.bincount(root, weights=volume * sign, minlength=n_faces)
    turn = (parity == 1) ^ (piece_volume[root] < 0)
    oriented = np.where(turn[:, None], np.asarray(faces)[:, ::-1], faces)
    graph = coo_matrix((np.ones(len(start)), (start, end[order])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    components = int(len(np.unique(labels[np.unique(f)])))
    return MeshStatistics(n_faces, watertight, components, inconsistent), np.ascontiguousarray(oriented)


__all__ = ["MESH_SUFFIXES", "MIN_SOLID_TRIANGLES", "FLAT_TOLERANCE", "MeshError", "LoadedMesh", "MeshStatistics", "load_mesh", "normalised_mesh", "merged_faces",
           "analyse_mesh"]
