"""The benchmark's voxels (svr/nmr/voxels.py): the NMR frame and its voxel orders, the mesh voxelisation
rules worked by hand, the compiled rasteriser against its Python source, and the fill of enclosed
space (6-connected)."""
from __future__ import annotations

import numpy as np
import torch
import trimesh

from svr.nmr import voxels as geometry
from svr.nmr.voxels import fill_enclosed, nmr_voxel_centres, voxelize_mesh_nmr

R = 32


def world_of_voxel_units(u: np.ndarray) -> np.ndarray:
    """The benchmark's scaling inverted: voxel units u = 31 v + 16 -> world v."""
    return (np.asarray(u, float) - R / 2) / (R - 1)


# ------------------------------------------------------------------------------------ frame


def test_voxel_centres_follow_the_spec_frame():
    c = nmr_voxel_centres().numpy()
    i, j, k = 3, 20, 7
    np.testing.assert_allclose(c[i, j, k], [(j - 15.5) / 31, (i - 15.5) / 31, (15.5 - k) / 31], atol=1e-7)
    np.testing.assert_allclose(c[0, 0, 0], [-0.5, -0.5, 0.5], atol=1e-7)
    np.testing.assert_allclose(c[31, 31, 31], [0.5, 0.5, -0.5], atol=1e-7)


def test_xyz_and_nmr_orders_are_inverse_and_match_the_centres():
    rng = np.random.default_rng(0)
    vox = rng.random((R, R, R)) < 0.3
    xyz = geometry.nmr_to_xyz_voxels(vox)
    np.testing.assert_array_equal(geometry.xyz_to_nmr_voxels(xyz), vox)
    np.testing.assert_array_equal(geometry.xyz_to_nmr_voxels(torch.from_numpy(xyz.copy())).numpy(), vox)
    # xyz[a, b, c] sits at x increasing with a, y with b, z with c
    cx = geometry.nmr_to_xyz_voxels(nmr_voxel_centres().numpy().transpose(3, 0, 1, 2)[0])
    cy = geometry.nmr_to_xyz_voxels(nmr_voxel_centres().numpy().transpose(3, 0, 1, 2)[1])
    cz = geometry.nmr_to_xyz_voxels(nmr_voxel_centres().numpy().transpose(3, 0, 1, 2)[2])
    assert np.all(np.diff(cx, axis=0) > 0) and np.all(np.diff(cy, axis=1) > 0) and np.all(np.diff(cz, axis=2) > 0)


def test_a_box_lands_where_the_frame_says():
    centre = np.array([0.2, -0.1, 0.3])
    mesh = trimesh.creation.box(extents=(0.13, 0.13, 0.13))
    mesh.apply_translation(centre)
    vox = voxelize_mesh_nmr(mesh.vertices, mesh.faces)
    idx = np.argwhere(vox).mean(0)
    expect = [centre[1] * 31 + 15.5, centre[0] * 31 + 15.5, 15.5 - centre[2] * 31]
    np.testing.assert_allclose(idx, expect, atol=0.6)
    assert vox.sum() >= 4 ** 3  # solid: the fill closes the inside


# ------------------------------------------------------------------------------------ rules


def test_one_triangle_marks_its_lattice_hits_their_neighbours_and_its_vertices():
    """Worked by hand: a triangle in the plane z_u = 10.3 (voxel units) meets the z lattice lines
    (6, 6), (6, 7) (on its edge) and (7, 6); each marks the four voxels around it at z index 10;
    the vertices mark theirs; the triangle is edge-on to the x and y projections."""
    tri_u = np.array([[5.5, 5.5, 10.3], [7.5, 5.5, 10.3], [5.5, 7.5, 10.3]])
    vox = voxelize_mesh_nmr(world_of_voxel_units(tri_u), np.array([[0, 1, 2]]))
    expect_xy = {(5, 5), (5, 6), (6, 5), (6, 6), (5, 7), (6, 7), (7, 5), (7, 6)}
    got = {(int(j), int(i)) for i, j, k in np.argwhere(vox)}
    assert got == expect_xy
    assert set(np.argwhere(vox)[:, 2].tolist()) == {31 - 10}


def test_vertex_voxels_alone_mark_a_tiny_triangle():
    tri_u = np.array([[3.2, 4.2, 5.2], [3.3, 4.3, 5.25], [3.25, 4.2, 5.3]])
    vox = voxelize_mesh_nmr(world_of_voxel_units(tri_u), np.array([[0, 1, 2]]))
    assert np.argwhere(vox).tolist() == [[4, 3, 31 - 5]]


def test_compiled_rasteriser_matches_its_python_source():
    rng = np.random.default_rng(1)
    tri = rng.uniform(-2, 34, size=(300, 3, 3))
    tri[:100] = tri[:100, :1] + rng.normal(scale=1.5, size=(100, 3, 3))  # small triangles
    a = np.zeros((R, R, R), np.uint8)
    b = np.zeros((R, R, R), np.uint8)
    geometry._rasterize_triangles_py(tri, a)
    geometry._rasterizer()(tri, b)
    np.testing.assert_array_equal(a, b)
    assert a.sum() > 100


def test_geometry_outside_the_grid_is_dropped():
    mesh = trimesh.creation.icosphere(radius=0.1)
    mesh.apply_translation([2.0, 0.0, 0.0])
    assert not voxelize_mesh_nmr(mesh.vertices, mesh.faces).any()
    assert not voxelize_mesh_nmr(np.zeros((0, 3)), np.zeros((0, 3), int)).any()


def _shell(hole: str = "") -> np.ndarray:
    v = np.zeros((R, R, R), bool)
    v[8:24, 8:24, 8:24] = True
    v[9:23, 9:23, 9:23] = False
    if hole == "face":
        v[15, 15, 8] = False  # a 6-connected opening
    return v


def test_fill_closes_a_shell_and_leaves_a_shell_with_a_hole_hollow():
    closed = fill_enclosed(_shell())
    assert closed[9:23, 9:23, 9:23].all()
    opened = fill_enclosed(_shell("face"))
    assert not opened[9:23, 9:23, 9:23].any()
    np.testing.assert_array_equal(opened, _shell("face"))


def test_fill_uses_six_connectivity():
    v = np.zeros((R, R, R), bool)
    v[8:24, 8:24, 8:24] = True
    v[9:23, 9:23, 9:23] = False
    v[8, 12, 12] = False          # a hole in the wall at x index 8 ...
    v[9, 12, 12] = True           # ... blocked behind by a voxel,
    v[9, 13, 12] = False          # the cavity is diagonal to the hole only (touches along an edge)
    out = fill_enclosed(v)
    assert out[12, 12, 12]        # the cavity is filled: the edge contact does not connect it
    assert not out[8, 12, 12]     # the hole itself reaches the border, so it stays empty


def test_mesh_voxelisation_fills_a_closed_mesh_but_not_an_open_one():
    closed = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    vox = voxelize_mesh_nmr(closed.vertices, closed.faces)
    assert vox[15:17, 15:17, 15:17].all()
    opened = closed.copy()
    keep = opened.triangles_center[:, 1] < 0.2  # cut a cap off the top
    opened.update_faces(keep)
    vox_open = voxelize_mesh_nmr(opened.vertices, opened.faces)
    assert not vox_open[15:17, 15:17, 15:17].any()
