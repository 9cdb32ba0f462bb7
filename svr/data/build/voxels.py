"""Solid voxels of imperfect meshes (holes, flipped or inconsistent faces, internal faces,
self-intersections) in the NMR voxel frame. ``winding_votes`` estimates the winding number at every
voxel centre from rays: voxel centres lie on lattice lines along 13 directions (the 3 axes, 6 face
diagonals, 4 body diagonals); one ray is cast along each whole line and every hit on it collected
(``RayCaster.all_hits``); the signed crossings (+1 entering, -1 leaving, by the face's orientation)
before a centre give the winding number seen from one end of the line, those after it the one seen
from the other end, so each centre gets 26 estimates at the cost of a few thousand rays. Each
estimate, clipped to [0, 1] (a doubled shell counts once, a flipped face cannot make a centre
"negatively" inside), votes; ``solid_voxels`` keeps the centres with at least half the votes and
unites them with the benchmark's surface voxels (``svr.nmr.voxels.mesh_surface_voxels``), as
the benchmark's protocol includes the surface. A hole is seen only by the rays that pass through it,
a flipped face only by the rays that cross it, so a few wrong votes do not change the result. The
fraction of votes that disagree with the decision, over the voxels off the surface that got any
inside vote, is the object's ``leak_score`` (0 for a closed, consistently oriented mesh; a ray that
slips through a shared edge adds a little, a hole or a tangle of faces much more).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from sdfcommon.numerics.raycast import RayCaster
from svr.nmr.voxels import mesh_surface_voxels, xyz_to_nmr_voxels

AXES = ((1, 0, 0), (0, 1, 0), (0, 0, 1))
FACE_DIAGONALS = ((1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1))
BODY_DIAGONALS = ((1, 1, 1), (1, 1, -1), (1, -1, 1), (-1, 1, 1))
DIRECTION_SETS = {3: AXES, 7: AXES + BODY_DIAGONALS, 13: AXES + FACE_DIAGONALS + BODY_DIAGONALS}
# Lines are shifted off the lattice by this much (world units, a fixed pseudo-random offset per
# line) so that no ray runs exactly along an edge or through a vertex of an axis-aligned mesh.
JITTER = 1e-4
# How far before its first voxel centre a line's ray starts (world units): outside the unit cube.
RAY_START = 1.5


@dataclass(frozen=True)
class VoxelResult:
    """Solid voxels of a mesh and how sure the votes were.

    Attributes:
        voxels: (R, R, R) bool in the NMR frame.
        votes: (R, R, R) float32 in the NMR frame, the fraction of inside votes per voxel centre.
        leak_score: see the module docstring; in [0, 0.5].
    """

    voxels: np.ndarray
    votes: np.ndarray
    leak_score: float


@dataclass(frozen=True)
class _LineSet:
    """The lattice lines along one direction through the centres of an R^3 grid ((x, y, z) index
    order, flat index ``a * R^2 + b * R + c``), and the ray cast along each.

    Attributes:
        line: (R^3,) int64 line of each centre. t: (R^3,) float64 distance of each centre from its
            line's ray origin. origins: (L, 3) float64 ray origins (jittered across the line, well
            before its first centre). unit: (3,) the unit direction.
    """

    line: np.ndarray
    t: np.ndarray
    origins: np.ndarray
    unit: np.ndarray


@functools.lru_cache(maxsize=32)
def _line_set(resolution: int, direction: tuple[int, int, int]) -> _LineSet:
    """The lines of one grid and direction (they depend on no mesh: made once per process)."""
    r = resolution
    size = 1.0 / (r - 1)
    a = np.stack(np.meshgrid(*[np.arange(r)] * 3, indexing="ij"), -1).reshape(-1, 3)
    d = np.asarray(direction, dtype=np.int64)
    _, line = np.unique(np.cross(a, d), axis=0, return_inverse=True)
    line = line.reshape(-1)
    offset = a @ d  # grows by |d|^2 per step along the line
    n_lines = int(line.max()) + 1
    first = np.full(n_lines, np.iinfo(np.int64).max)
    np.minimum.at(first, line, offset)
    anchor = np.zeros(n_lines, dtype=np.int64)
    is_first = offset == first[line]
    anchor[line[is_first]] = np.nonzero(is_first)[0]
    unit = d / np.linalg.norm(d)
    # A fixed stream per grid and direction: the same mesh always gives the same voxels.
    jitter = np.random.default_rng([r, *(int(x) + 1 for x in direction)]).uniform(-JITTER, JITTER, (n_lines, 3))
    jitter -= (jitter @ unit)[:, None] * unit  # across the line only
    origins = (a[anchor] - (r - 1) / 2.0) * size + jitter - RAY_START * unit
    t = RAY_START + (offset - first[line]) * size / float(np.linalg.norm(d))
    return _LineSet(line, t, origins, unit)


def winding_votes(caster: RayCaster, face_normals: np.ndarray, resolution: int,
                  directions: int = 13) -> tuple[np.ndarray, np.ndarray]:
    """Inside votes at the voxel centres (world ``(n - c) / (R - 1)`` per axis, ``c = (R - 1) / 2``).

    Args:
        caster: the mesh's ray caster. face_normals: (F, 3) its faces' normals (orientation from
            the winding order; zero for degenerate faces). resolution: R.
        directions: 3, 7 or 13 line directions (``DIRECTION_SETS``), each giving two estimates.
    Returns:
        inside: (R, R, R) int32 number of inside votes and total: the number of votes, both
        indexed (x, y, z) increasing.
    """
    r = resolution
    inside = np.zeros(r ** 3, dtype=np.int32)
    dirs = DIRECTION_SETS[directions]
    for direction in dirs:
        lines = _line_set(r, direction)
        n_lines = len(lines.origins)
        ray, face, t = caster.all_hits(lines.origins, np.tile(lines.unit, (n_lines, 1)))
        sign = -np.sign(face_normals[face] @ lines.unit).astype(np.int64)  # +1 entering, -1 leaving
        # Prefix sums of the signs, hits sorted by line then distance (keys line * 16 + t, t < 16).
        keys = ray * 16.0 + t
        cum = np.concatenate([[0], np.cumsum(sign)])
        line_start = np.searchsorted(keys, np.arange(n_lines) * 16.0)
        line_end = np.searchsorted(keys, np.arange(n_lines) * 16.0 + 15.9)
        before = cum[np.searchsorted(keys, lines.line * 16.0 + lines.t)] - cum[line_start[lines.line]]
        total = cum[line_end[lines.line]] - cum[line_start[lines.line]]
        from_start = before          # winding number seen along the ray from the line's start
        from_end = before - total    # ... and from its end (minus the signs of the crossings after it)
        inside += (np.clip(from_start, 0, 1) + np.clip(from_end, 0, 1)).astype(np.int32)
    return inside.reshape(r, r, r), np.full((r, r, r), 2 * len(dirs), dtype=np.int32)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of the faces by their winding order (zero for degenerate faces)."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def solid_voxels(caster: RayCaster, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray,
                 resolution: int = 32, directions: int = 13) -> VoxelResult:
    """Solid voxels of a (normalised) mesh: the centres with at least half the inside votes
    (``winding_votes``), united with its surface voxels by the benchmark's rule.

    Args:
        caster: the mesh's ray caster. vertices: (V, 3) world. faces: (F, 3). normals: (F, 3)
            ``face_normals``. resolution: R. directions: 3, 7 or 13.
    Returns:
        VoxelResult in the NMR frame.
    """
    inside, total = winding_votes(caster, normals, resolution, directions)
    votes = inside / total
    solid = votes >= 0.5
    surface = mesh_surface_voxels(vertices, faces, resolution)
    # Centres in surface voxels lie within a voxel of the surface (or on it): split votes there
    # are no sign of a leak.
    wrong = np.where(solid, 1.0 - votes, votes)
    counted = (votes > 0) & ~surface
    leak = float(wrong[counted].mean()) if counted.any() else 0.0
    solid |= surface
    return VoxelResult(np.ascontiguousarray(xyz_to_nmr_voxels(solid)),
                       np.ascontiguousarray(xyz_to_nmr_voxels(votes.astype(np.float32))), leak)


__all__ = ["VoxelResult", "DIRECTION_SETS", "winding_votes", "face_normals", "solid_voxels"]
