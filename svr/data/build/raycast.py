"""Ray casting on triangle meshes through Intel Embree (the ``embreex`` package, trimesh's fast ray
caster): ``RayCaster`` holds one mesh's BVH and answers first hits (triangle, barycentric
coordinates, distance) for the renders and every hit along a ray for the voxels. Embree works in
float32; the builder's meshes are normalised into the unit cube, where that is about 1e-7.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# How far past a hit the next search along the same ray starts (world units, normalised meshes):
# above float32 rounding at unit scale, below any feature the 32^3 or 64^3 grids resolve.
STEP_PAST_HIT = 1e-5
# At most this many hits are collected along one ray (a ray through more layers stops there).
MAX_HITS = 256


@dataclass(frozen=True)
class Hits:
    """First hits of R rays.

    Attributes:
        face: (R,) int32 triangle index, -1 where the ray misses.
        u, v: (R,) float32 barycentric weights of the triangle's 2nd and 3rd vertex.
        t: (R,) float32 distance along the (unit) ray direction.
    """

    face: np.ndarray
    u: np.ndarray
    v: np.ndarray
    t: np.ndarray


class RayCaster:
    """Embree's BVH of one triangle mesh.

    Args:
        vertices: (V, 3) float world coordinates. faces: (F, 3) int vertex indices.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        from embreex import mesh_construction, rtcore_scene  # heavy and optional: x86_64 wheels only

        self.scene = rtcore_scene.EmbreeScene()
        mesh_construction.TriangleMesh(self.scene, np.ascontiguousarray(vertices, dtype=np.float32),
                                       np.ascontiguousarray(faces, dtype=np.int32))

    def first_hits(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """The nearest hit of each ray (origins, unit directions: (R, 3))."""
        out = self.scene.run(np.ascontiguousarray(origins, dtype=np.float32),
                             np.ascontiguousarray(directions, dtype=np.float32), output=1)
        face = np.where(out["geomID"] >= 0, out["primID"], -1).astype(np.int32)
        return Hits(face, out["u"], out["v"], out["tfar"])

    def all_hits(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every hit along each ray (a surface met twice at one point counts once).

        Returns:
            ray: (K,) int64 ray index of each hit; face: (K,) int32 triangle; t: (K,) float64
            distance from the ray's origin along its unit direction. Hits are sorted by ray, then t.
        """
        o = np.ascontiguousarray(origins, dtype=np.float64)
        d = np.ascontiguousarray(directions, dtype=np.float64)
        live = np.arange(len(o))
        start = np.zeros(len(o))
        rays, faces, ts = [], [], []
        for _ in range(MAX_HITS):
            if not len(live):
                break
            hits = self.first_hits(o[live] + start[live, None] * d[live], d[live])
            ok = hits.face >= 0
            live, t = live[ok], start[live[ok]] + hits.t[ok]
            rays.append(live)
            faces.append(hits.face[ok])
            ts.append(t)
            start[live] = t + STEP_PAST_HIT
        if not rays:
            return np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0)
        ray, face, t = np.concatenate(rays), np.concatenate(faces), np.concatenate(ts)
        order = np.lexsort((t, ray))
        return ray[order].astype(np.int64), face[order], t[order]


__all__ = ["RayCaster", "Hits", "STEP_PAST_HIT", "MAX_HITS"]
