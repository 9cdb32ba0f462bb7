"""Ray casting against triangle meshes, for both applications: mvr's target images and error
pictures (first hits, shaded by barycentric normals) and svr's mesh-to-NMR builder (first hits for
the renders, every hit along a ray for the voxels' winding votes). ``RayCaster`` is the one
interface: each backend answers ``first_hits`` (face, barycentric weights, distance: ``RayHits``)
and ``all_hits`` is built on it once. ``EmbreeCaster`` is the backend (Intel Embree through the
``embreex`` package, wheels for x86_64: the well-kept library and the fastest here, timed in
docs/mvr_real_scans.md); ``TriangleGrid``, this project's own numba caster, is the second backend,
kept only as the fallback where ``embreex`` does not install (e.g. aarch64): a uniform grid of
cells over the mesh (3D DDA, Amanatides & Woo) whose binned triangles are tested by Moller-Trumbore
(two-sided), one ray per numba ``prange`` iteration. ``mesh_caster`` picks Embree wherever it
imports. trimesh's pure-Python intersector is no fallback: it ran out of memory on 26 x 40^2 rays
against a 75k-triangle scan (the 26-view rig casts about 10^6 rays). ``tests/sdfcommon/test_raycast.py``
checks both backends against trimesh's reference intersector and each other.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from sdfcommon.tooling.checks import check_shape

# Relative slack when binning triangles into cells and accepting hits at cell faces, so a hit
# exactly on a cell boundary is never lost to rounding.
_EPS = 1e-9
# How far past a hit the next search along the same ray starts (world units, normalised meshes):
# above float32 rounding at unit scale, below any feature the 32^3 or 64^3 grids resolve.
STEP_PAST_HIT = 1e-5
# At most this many hits are collected along one ray (a ray through more layers stops there).
MAX_HITS = 256


@dataclass(frozen=True)
class RayHits:
    """The first hit of R rays.

    Attributes:
        hit: (R,) bool.
        t: (R,) float64 distance along the (unit) ray direction; inf where no hit.
        face: (R,) int64 index of the triangle hit; -1 where no hit.
        barycentric: (R, 3) float64 weights of the face's three vertices at the hit; 0 where no hit.
    """

    hit: np.ndarray
    t: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray


class RayCaster:
    """A triangle mesh ready for ray queries; a backend implements ``first_hits``."""

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> RayHits:
        """The nearest hit of each ray (origins (R, 3), unit directions (R, 3), world)."""
        raise NotImplementedError

    def all_hits(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every hit along each ray (origins (R, 3), unit directions (R, 3), world): ``first_hits``
        again from ``STEP_PAST_HIT`` past each hit, at most ``MAX_HITS`` per ray (a surface met
        twice at one point counts once).

        Returns:
            ray: (K,) int64 ray index of each hit; face: (K,) int64 triangle; t: (K,) float64
            distance from the ray's origin along its unit direction. Hits are sorted by ray, then t.
        """
        o, d = _checked_rays(origins, directions)
        live = np.arange(len(o))
        start = np.zeros(len(o))
        rays, faces, ts = [], [], []
        for _ in range(MAX_HITS):
            if not len(live):
                break
            hits = self.first_hits(o[live] + start[live, None] * d[live], d[live])
            ok = hits.hit
            live, t = live[ok], start[live[ok]] + hits.t[ok]
            rays.append(live)
            faces.append(hits.face[ok])
            ts.append(t)
            start[live] = t + STEP_PAST_HIT
        if not rays:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
        ray, face, t = np.concatenate(rays), np.concatenate(faces), np.concatenate(ts)
        order = np.lexsort((t, ray))
        return ray[order].astype(np.int64), face[order], t[order]


class EmbreeCaster(RayCaster):
    """Embree's BVH of one triangle mesh (needs the ``embreex`` package).

    Embree intersects in single precision (float32 rays, vertices, distances and weights, widened
    to ``RayHits``' float64): hit distances agree with the double-precision ``TriangleGrid`` to
    about 1e-6 of the scene's size, far below a pixel's footprint or a voxel.

    Args:
        vertices: (V, 3) float array (world); faces: (F, 3) int array of vertex indices.
    Raises:
        ImportError: ``embreex`` is not installed (see ``embree_available``).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from embreex import mesh_construction, rtcore_scene  # heavy and optional: x86_64 wheels only

        v, f = _checked_mesh(vertices, faces)
        self._scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self._scene, v.astype(np.float32), f.astype(np.int32))

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> RayHits:
        """The nearest hit of each ray (origins (R, 3), unit directions (R, 3), world)."""
        o, d = _checked_rays(origins, directions)
        out = self._scene.run(o.astype(np.float32), d.astype(np.float32), output=1)
        face = np.where(out["geomID"] >= 0, out["primID"], -1).astype(np.int64)
        return _ray_hits(face, out["tfar"], out["u"], out["v"])


class TriangleGrid(RayCaster):
    """Triangles binned into a uniform grid of cells over their bounding box, ready for ray casting
    in double precision (the fallback backend where Embree does not install).

    Args:
        vertices: (V, 3) float array (world).
        faces: (F, 3) int array of vertex indices.
        cells_per_face: about how many cells to make per triangle (the grid gets roughly
            ``cells_per_face * F`` cells, at most ``max_cells_per_axis`` along each axis).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, cells_per_face: float = 2.0,
                 max_cells_per_axis: int = 256):
        v, f = _checked_mesh(vertices, faces)
        self.triangles = np.ascontiguousarray(v[f])  # (F, 3, 3)
        lo = self.triangles.reshape(-1, 3).min(axis=0)
        hi = self.triangles.reshape(-1, 3).max(axis=0)
        span = np.maximum(hi - lo, 1e-12)
        pad = 1e-6 * float(span.max())
        self.lo, self.hi = lo - pad, hi + pad
        span = self.hi - self.lo
        # Cells as close to cubes as the box allows, about cells_per_face * F of them.
        target = max(1.0, cells_per_face * len(f))
        side = (float(np.prod(span)) / target) ** (1.0 / 3.0)
        dims = np.clip(np.ceil(span / max(side, 1e-12)), 1, max_cells_per_axis).astype(np.int64)
        self.dims = dims
        self.cell = span / dims
        self.offsets, self.items = _bin_triangles(self.triangles, self.lo, self.cell, dims)

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> RayHits:
        """The nearest hit of each ray (origins (R, 3), unit directions (R, 3), world)."""
        o, d = _checked_rays(origins, directions)
        t, face, u, w = _cast(o, d, self.triangles, self.lo, self.cell, self.dims, self.offsets, self.items)
        return _ray_hits(face, t, u, w)


def embree_available() -> bool:
    """Whether Embree can be used (``embreex`` imports)."""
    try:
        from embreex import rtcore_scene  # noqa: F401  # optional: x86_64 wheels only
    except ImportError:
        return False
    return True


CASTERS = ("auto", "embree", "grid")


def mesh_caster(vertices: np.ndarray, faces: np.ndarray, engine: str = "auto") -> RayCaster:
    """A ray caster for a triangle mesh: ``"embree"`` (EmbreeCaster), ``"grid"`` (this project's
    numba TriangleGrid) or ``"auto"``: Embree where it imports, else the grid."""
    if engine not in CASTERS:
        raise ValueError(f"ray caster engine must be one of {CASTERS}, got {engine!r}")
    if engine == "embree" or (engine == "auto" and embree_available()):
        return EmbreeCaster(vertices, faces)
    return TriangleGrid(vertices, faces)


def _ray_hits(face: np.ndarray, t: np.ndarray, u: np.ndarray, w: np.ndarray) -> RayHits:
    """``RayHits`` from a backend's (R,) face (-1: no hit), distance and weights of the face's 2nd
    and 3rd vertex (any float dtype, widened to float64)."""
    hit = face >= 0
    u, w = np.asarray(u, dtype=np.float64), np.asarray(w, dtype=np.float64)
    bary = np.zeros((len(face), 3))
    bary[hit, 0] = 1.0 - u[hit] - w[hit]
    bary[hit, 1] = u[hit]
    bary[hit, 2] = w[hit]
    return RayHits(hit=hit, t=np.where(hit, np.asarray(t, dtype=np.float64), np.inf), face=face, barycentric=bary)


def _checked_mesh(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices and (F, 3) int64 faces, checked."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    check_shape(v, "vertices", "V, 3")
    check_shape(f, "faces", "F, 3", at_least={"F": 1})
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError("faces index vertices that do not exist")
    return v, f


def _checked_rays(origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, 3) float64 origins and directions, checked."""
    o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape:
        raise ValueError(f"directions must have the shape of origins {o.shape}, got {d.shape}")
    return o, d


@numba.njit(cache=True)
def _triangle_cells(tri, lo, cell, dims):
    """Flat indices of the cells overlapped by a triangle's bounding box (with a little slack)."""
    tmin = np.minimum(np.minimum(tri[0], tri[1]), tri[2])
    tmax = np.maximum(np.maximum(tri[0], tri[1]), tri[2])
    i0 = np.empty(3, np.int64)
    i1 = np.empty(3, np.int64)
    for a in range(3):
        slack = _EPS * cell[a]
        i0[a] = min(max(int(np.floor((tmin[a] - slack - lo[a]) / cell[a])), 0), dims[a] - 1)
        i1[a] = min(max(int(np.floor((tmax[a] + slack - lo[a]) / cell[a])), 0), dims[a] - 1)
    out = np.empty((i1[0] - i0[0] + 1) * (i1[1] - i0[1] + 1) * (i1[2] - i0[2] + 1), np.int64)
    n = 0
    for i in range(i0[0], i1[0] + 1):
        for j in range(i0[1], i1[1] + 1):
            for k in range(i0[2], i1[2] + 1):
                out[n] = (i * dims[1] + j) * dims[2] + k
                n += 1
    return out


@numba.njit(cache=True)
def _bin_triangles(tris, lo, cell, dims):
    """CSR lists of the triangles whose bounding box overlaps each cell: (offsets, items)."""
    counts = np.zeros(dims[0] * dims[1] * dims[2] + 1, np.int64)
    for f in range(tris.shape[0]):
        for c in _triangle_cells(tris[f], lo, cell, dims):
            counts[c + 1] += 1
    offsets = np.cumsum(counts)
    items = np.empty(offsets[-1], np.int64)
    fill = offsets[:-1].copy()
    for f in range(tris.shape[0]):
        for c in _triangle_cells(tris[f], lo, cell, dims):
            items[fill[c]] = f
            fill[c] += 1
    return offsets, items


@numba.njit(cache=True)
def _intersect(o, d, tri):
    """Moller-Trumbore, two-sided: (t, u, v) of the hit, t = inf if none."""
    e1x, e1y, e1z = tri[1, 0] - tri[0, 0], tri[1, 1] - tri[0, 1], tri[1, 2] - tri[0, 2]
    e2x, e2y, e2z = tri[2, 0] - tri[0, 0], tri[2, 1] - tri[0, 1], tri[2, 2] - tri[0, 2]
    px, py, pz = d[1] * e2z - d[2] * e2y, d[2] * e2x - d[0] * e2z, d[0] * e2y - d[1] * e2x
    det = e1x * px + e1y * py + e1z * pz
    scale = abs(e1x) + abs(e1y) + abs(e1z) + abs(e2x) + abs(e2y) + abs(e2z)
    if abs(det) <= 1e-14 * scale * scale:
        return np.inf, 0.0, 0.0
    inv = 1.0 / det
    sx, sy, sz = o[0] - tri[0, 0], o[1] - tri[0, 1], o[2] - tri[0, 2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -1e-12 or u > 1.0 + 1e-12:
        return np.inf, 0.0, 0.0
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
    if v < -1e-12 or u + v > 1.0 + 1e-12:
        return np.inf, 0.0, 0.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if t <= 0.0:
        return np.inf, 0.0, 0.0
    return t, u, v


@numba.njit(parallel=True, cache=True)
def _cast(o, d, tris, lo, cell, dims, offsets, items):
    r = o.shape[0]
    t_out = np.full(r, np.inf)
    face_out = np.full(r, -1, np.int64)
    u_out = np.zeros(r)
    v_out = np.zeros(r)
    hi = lo + cell * dims
    for ray in numba.prange(r):
        # Slab test against the grid's box.
        t0, t1 = 0.0, np.inf
        inv = np.empty(3)
        for a in range(3):
            da = d[ray, a]
            if abs(da) < 1e-300:
                da = 1e-300 if da >= 0 else -1e-300
            inv[a] = 1.0 / da
            ta = (lo[a] - o[ray, a]) * inv[a]
            tb = (hi[a] - o[ray, a]) * inv[a]
            t0 = max(t0, min(ta, tb))
            t1 = min(t1, max(ta, tb))
        if t0 > t1:
            continue
        idx = np.empty(3, np.int64)
        step = np.empty(3, np.int64)
        t_next = np.empty(3)
        t_delta = np.empty(3)
        for a in range(3):
            p = o[ray, a] + t0 * d[ray, a]
            idx[a] = min(max(int(np.floor((p - lo[a]) / cell[a])), 0), dims[a] - 1)
            if d[ray, a] >= 0:  # the same sign rule as the slab test's safe direction
                step[a] = 1
                t_next[a] = (lo[a] + (idx[a] + 1) * cell[a] - o[ray, a]) * inv[a]
                t_delta[a] = cell[a] * inv[a]
            else:
                step[a] = -1
                t_next[a] = (lo[a] + idx[a] * cell[a] - o[ray, a]) * inv[a]
                t_delta[a] = -cell[a] * inv[a]
        best_t, best_f, best_u, best_v = np.inf, -1, 0.0, 0.0
        while True:
            c = (idx[0] * dims[1] + idx[1]) * dims[2] + idx[2]
            for n in range(offsets[c], offsets[c + 1]):
                f = items[n]
                t, u, v = _intersect(o[ray], d[ray], tris[f])
                if t < best_t:
                    best_t, best_f, best_u, best_v = t, f, u, v
            exit_t = min(t_next[0], min(t_next[1], t_next[2]))
            # A hit inside this cell (or on its far faces) is the first one: later cells are farther.
            if best_t <= exit_t * (1.0 + _EPS) + _EPS or exit_t > t1:
                break
            a = 0
            if t_next[1] < t_next[a]:
                a = 1
            if t_next[2] < t_next[a]:
                a = 2
            idx[a] += step[a]
            if idx[a] < 0 or idx[a] >= dims[a]:
                break
            t_next[a] += t_delta[a]
        if best_f >= 0:
            t_out[ray] = best_t
            face_out[ray] = best_f
            u_out[ray] = best_u
            v_out[ray] = best_v
    return t_out, face_out, u_out, v_out


__all__ = ["RayCaster", "EmbreeCaster", "TriangleGrid", "RayHits", "mesh_caster", "embree_available", "CASTERS",
           "STEP_PAST_HIT", "MAX_HITS"]
