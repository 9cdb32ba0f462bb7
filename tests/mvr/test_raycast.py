"""The mesh ray casters (Embree through trimesh, and the numba grid fallback) against trimesh's
reference intersector, exact spheres and each other."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from mvr.raycast import EmbreeCaster, TriangleGrid, embree_available, mesh_caster
from renderer import Cameras


ENGINES = [pytest.param("grid", id="grid"),
           pytest.param("embree", id="embree", marks=pytest.mark.skipif(not embree_available(),
                                                                          reason="embreex not installed"))]
# Embree intersects in single precision.
T_TOL = {"grid": 1e-6, "embree": 2e-5}


def _rays(image_size: int = 12, distance: float = 2.5):
    o, d = Cameras.cube_rig(distance, fov_deg=50, image_size=image_size).rays()
    return o.reshape(-1, 3).double().numpy(), d.reshape(-1, 3).double().numpy()


@pytest.mark.parametrize("mesh", [
    trimesh.creation.icosphere(subdivisions=2, radius=0.6),
    trimesh.creation.torus(0.5, 0.2, major_sections=24, minor_sections=12),
    trimesh.creation.box((1.0, 0.6, 0.3)),
], ids=["icosphere", "torus", "box"])
@pytest.mark.parametrize("engine", ENGINES)
def test_matches_trimesh(mesh, engine):
    o, d = _rays()
    hits = mesh_caster(mesh.vertices, mesh.faces, engine).cast(o, d)
    ref = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    loc, ray_idx, tri_idx = ref.intersects_location(o, d, multiple_hits=False)
    ref_hit = np.zeros(len(o), bool)
    ref_hit[ray_idx] = True
    # Rays through an edge may be called either way by two implementations: allow a handful.
    assert (ref_hit != hits.hit).sum() <= max(2, len(o) // 500)
    both = ref_hit[ray_idx] & hits.hit[ray_idx]
    t_ref = np.linalg.norm(loc - o[ray_idx], axis=1)
    np.testing.assert_allclose(hits.t[ray_idx][both], t_ref[both], atol=T_TOL[engine])
    # The hit point rebuilt from the face and barycentric weights lies on the ray.
    k = np.nonzero(hits.hit)[0]
    p_bary = (hits.barycentric[k, :, None] * mesh.vertices[mesh.faces[hits.face[k]]]).sum(axis=1)
    np.testing.assert_allclose(p_bary, o[k] + hits.t[k, None] * d[k], atol=1e-9 if engine == "grid" else 2e-5)


@pytest.mark.parametrize("engine", ENGINES)
def test_exact_sphere_depth(engine):
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    o, d = _rays(24)
    hits = mesh_caster(mesh.vertices, mesh.faces, engine).cast(o, d)
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - 0.25)
    inside = disc > 1e-3  # away from the silhouette
    assert hits.hit[inside].all()
    t_exact = -b[inside] - np.sqrt(disc[inside])
    # Within the icosphere's chord error (about radius * (1 - cos(edge angle / 2)) = 6e-4).
    np.testing.assert_allclose(hits.t[inside], t_exact, atol=1e-3)
    assert (hits.t[inside] >= t_exact - T_TOL[engine]).all()  # the inscribed polyhedron is hit later
    assert not hits.hit[disc < -1e-3].any()


@pytest.mark.parametrize("engine", ENGINES)
def test_axis_parallel_and_inside_rays(engine):
    mesh = trimesh.creation.box((1.0, 1.0, 1.0))
    o = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 0.0], [2.0, 2.0, 2.0], [0.5, 0.5, 3.0]])
    d = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    hits = mesh_caster(mesh.vertices, mesh.faces, engine).cast(o, d)
    assert hits.hit.tolist() == [True, True, False, True]
    np.testing.assert_allclose(hits.t[:2], [2.5, 0.5], atol=1e-12 if engine == "grid" else 1e-6)
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


@pytest.mark.skipif(not embree_available(), reason="embreex not installed")
def test_embree_and_grid_agree_on_a_bumpy_mesh():
    """The two engines on a mesh with many small triangles: the same hits, faces and depths."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.6)
    rng = np.random.default_rng(0)
    mesh.vertices *= 1.0 + 0.08 * rng.standard_normal((len(mesh.vertices), 1))
    o, d = _rays(32)
    a = TriangleGrid(mesh.vertices, mesh.faces).cast(o, d)
    b = EmbreeCaster(mesh.vertices, mesh.faces).cast(o, d)
    assert a.hit.sum() > len(o) // 10
    assert (a.hit != b.hit).sum() <= max(2, len(o) // 1000)
    both = a.hit & b.hit
    assert (a.face[both] != b.face[both]).mean() < 0.002
    np.testing.assert_allclose(a.t[both], b.t[both], atol=2e-5)
    same = both & (a.face == b.face)
    np.testing.assert_allclose(a.barycentric[same], b.barycentric[same], atol=1e-3)


def test_engine_choice():
    mesh = trimesh.creation.box((1.0, 1.0, 1.0))
    auto = mesh_caster(mesh.vertices, mesh.faces)
    assert isinstance(auto, EmbreeCaster if embree_available() else TriangleGrid)
    assert isinstance(mesh_caster(mesh.vertices, mesh.faces, "grid"), TriangleGrid)
    with pytest.raises(ValueError, match="engine"):
        mesh_caster(mesh.vertices, mesh.faces, "optix")
