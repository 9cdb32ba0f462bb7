"""The mesh ray casters (Embree through embreex, and the numba grid fallback) against trimesh's
reference intersector, exact spheres and each other: first hits, and every hit along a ray."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from renderer import Cameras
from sdfcommon.numerics.raycast import EmbreeCaster, TriangleGrid, embree_available, mesh_caster


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
    hits = mesh_caster(mesh.vertices, mesh.faces, engine).first_hits(o, d)
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
    hits = mesh_caster(mesh.vertices, mesh.faces, engine).first_hits(o, d)
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
    hits = mesh_caster(mesh.vertices, mesh.faces, engine).first_hits(o, d)
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
        grid.first_hits(np.zeros((2, 3)), np.zeros((3, 3)))


@pytest.mark.skipif(not embree_available(), reason="embreex not installed")
def test_embree_and_grid_agree_on_a_bumpy_mesh():
    """The two engines on a mesh with many small triangles: the same hits, faces and depths."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.6)
    rng = np.random.default_rng(0)
    mesh.vertices *= 1.0 + 0.08 * rng.standard_normal((len(mesh.vertices), 1))
    o, d = _rays(32)
    a = TriangleGrid(mesh.vertices, mesh.faces).first_hits(o, d)
    b = EmbreeCaster(mesh.vertices, mesh.faces).first_hits(o, d)
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


@pytest.mark.parametrize("engine", ENGINES)
def test_all_hits_enter_and_leave_a_sphere(engine):
    """Every ray through a sphere meets it twice, sorted by ray then distance; the first of them is
    the ray's first hit."""
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=0.5)
    o, d = _rays(16)
    caster = mesh_caster(mesh.vertices, mesh.faces, engine)
    ray, face, t = caster.all_hits(o, d)
    assert ray.dtype == np.int64 and face.dtype == np.int64 and t.dtype == np.float64
    assert (np.diff(ray) >= 0).all() and (np.diff(t)[np.diff(ray) == 0] > 0).all()
    assert ((face >= 0) & (face < len(mesh.faces))).all()
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - 0.25)
    counts = np.bincount(ray, minlength=len(o))
    clear = disc > 1e-3  # away from the silhouette
    assert clear.sum() > len(o) // 10 and (counts[clear] == 2).all() and (counts[disc < -1e-3] == 0).all()
    start = np.searchsorted(ray, np.nonzero(clear)[0])
    root = np.sqrt(disc[clear])
    # Within the icosphere's chord error (as test_exact_sphere_depth).
    np.testing.assert_allclose(t[start], -b[clear] - root, atol=1e-3)
    np.testing.assert_allclose(t[start + 1], -b[clear] + root, atol=1e-3)
    first = caster.first_hits(o, d)
    np.testing.assert_array_equal(t[start], first.t[clear])
    np.testing.assert_array_equal(face[start], first.face[clear])


@pytest.mark.parametrize("engine", ENGINES)
def test_all_hits_of_rays_that_miss_are_empty(engine):
    mesh = trimesh.creation.box((1.0, 1.0, 1.0))
    ray, face, t = mesh_caster(mesh.vertices, mesh.faces, engine).all_hits(
        np.array([[2.0, 2.0, 2.0]]), np.array([[1.0, 0.0, 0.0]]))
    assert len(ray) == len(face) == len(t) == 0


@pytest.mark.skipif(not embree_available(), reason="embreex not installed")
def test_embree_and_grid_agree_on_every_hit_along_rays():
    """Up to four crossings per ray through a torus: the same number of hits and the same depths."""
    mesh = trimesh.creation.torus(0.5, 0.2, major_sections=24, minor_sections=12)
    o, d = _rays(24)
    a = TriangleGrid(mesh.vertices, mesh.faces).all_hits(o, d)
    b = EmbreeCaster(mesh.vertices, mesh.faces).all_hits(o, d)
    counts_a, counts_b = np.bincount(a[0], minlength=len(o)), np.bincount(b[0], minlength=len(o))
    assert counts_a.max() == 4 and (counts_a != counts_b).sum() <= max(2, len(o) // 500)
    same = (counts_a == counts_b)[a[0]]
    np.testing.assert_allclose(a[2][same], b[2][(counts_a == counts_b)[b[0]]], atol=2e-5)
