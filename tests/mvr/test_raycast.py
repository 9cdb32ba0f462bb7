"""The numba mesh ray caster against trimesh's reference intersector and exact spheres."""
from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from mvr.raycast import TriangleGrid
from renderer import Cameras


def _rays(image_size: int = 12, distance: float = 2.5):
    o, d = Cameras.cube_rig(distance, fov_deg=50, image_size=image_size).rays()
    return o.reshape(-1, 3).double().numpy(), d.reshape(-1, 3).double().numpy()


@pytest.mark.parametrize("mesh", [
    trimesh.creation.icosphere(subdivisions=2, radius=0.6),
    trimesh.creation.torus(0.5, 0.2, major_sections=24, minor_sections=12),
    trimesh.creation.box((1.0, 0.6, 0.3)),
], ids=["icosphere", "torus", "box"])
def test_matches_trimesh(mesh):
    o, d = _rays()
    hits = TriangleGrid(mesh.vertices, mesh.faces).cast(o, d)
    ref = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    loc, ray_idx, tri_idx = ref.intersects_location(o, d, multiple_hits=False)
    ref_hit = np.zeros(len(o), bool)
    ref_hit[ray_idx] = True
    # Rays through an edge may be called either way by two implementations: allow a handful.
    assert (ref_hit != hits.hit).sum() <= max(2, len(o) // 500)
    both = ref_hit[ray_idx] & hits.hit[ray_idx]
    t_ref = np.linalg.norm(loc - o[ray_idx], axis=1)
    np.testing.assert_allclose(hits.t[ray_idx][both], t_ref[both], atol=1e-6)
    # The hit point rebuilt from the face and barycentric weights lies on the ray.
    k = np.nonzero(hits.hit)[0]
    p_bary = (hits.barycentric[k, :, None] * mesh.vertices[mesh.faces[hits.face[k]]]).sum(axis=1)
    np.testing.assert_allclose(p_bary, o[k] + hits.t[k, None] * d[k], atol=1e-9)


def test_exact_sphere_depth():
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    o, d = _rays(24)
    hits = TriangleGrid(mesh.vertices, mesh.faces).cast(o, d)
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - 0.25)
    inside = disc > 1e-3  # away from the silhouette
    assert hits.hit[inside].all()
    t_exact = -b[inside] - np.sqrt(disc[inside])
    # Within the icosphere's chord error (about radius * (1 - cos(edge angle / 2)) = 6e-4).
    np.testing.assert_allclose(hits.t[inside], t_exact, atol=1e-3)
    assert (hits.t[inside] >= t_exact - 1e-9).all()  # the inscribed polyhedron is hit later
    assert not hits.hit[disc < -1e-3].any()


def test_axis_parallel_and_inside_rays():
    mesh = trimesh.creation.box((1.0, 1.0, 1.0))
    o = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 0.0], [2.0, 2.0, 2.0], [0.5, 0.5, 3.0]])
    d = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    hits = TriangleGrid(mesh.vertices, mesh.faces).cast(o, d)
    assert hits.hit.tolist() == [True, True, False, True]
    np.testing.assert_allclose(hits.t[:2], [2.5, 0.5], atol=1e-12)
    assert hits.face[2] == -1 and np.isinf(hits.t[2])


def test_bad_input():
    with pytest.raises(ValueError, match="faces"):
        TriangleGrid(np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(ValueError, match="vertices"):
        TriangleGrid(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="index"):
        TriangleGrid(np.zeros((3, 3)), np.array([[0, 1, 5]]))
    grid = TriangleGrid(np.eye(3), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="origins"):
        grid.cast(np.zeros((2, 3)), np.zeros((3, 3)))
