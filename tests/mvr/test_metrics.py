"""Hausdorff and Chamfer distances against analytic answers."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from mvr import surface_distances
from mvr.metrics import faces_around_vertices


def _sphere(radius: float, centre=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    mesh = trimesh.creation.icosphere(subdivisions=5, radius=radius)
    mesh.apply_translation(centre)
    return mesh


# Chord error of a subdivision-5 icosphere: below 1e-3 of its radius.
TOL = 2e-3


@pytest.mark.parametrize("r_recon,r_target", [(0.5, 0.6), (0.7, 0.4)])
def test_concentric_spheres(r_recon, r_target):
    d = surface_distances(_sphere(r_recon), _sphere(r_target), samples=4000, seed=1)
    gap = abs(r_recon - r_target)
    assert d.hausdorff == pytest.approx(gap, abs=TOL)
    assert d.chamfer == pytest.approx(gap, abs=TOL)  # every point is exactly `gap` away
    diagonal = 2 * r_target * np.sqrt(3)
    assert d.diagonal == pytest.approx(diagonal, rel=1e-3)
    assert d.hausdorff_rel == pytest.approx(gap / diagonal, abs=TOL / diagonal)
    assert d.chamfer_rel == pytest.approx(d.chamfer / d.diagonal)
    assert "diagonal" in d.to_dict()["normalisation"]


def test_offset_spheres():
    """Equal spheres offset by s: the Hausdorff distance is s; the mean distance from one sphere to
    the other is the mean of | |p + s e| - r | over the sphere, computed here by quadrature."""
    r, s = 0.5, 0.1
    d = surface_distances(_sphere(r, (s, 0.0, 0.0)), _sphere(r), samples=6000, seed=2)
    assert d.hausdorff == pytest.approx(s, abs=TOL)
    cos = np.linspace(-1, 1, 200_001)  # the area element of a sphere is uniform in cos(theta)
    mean = np.mean(np.abs(np.sqrt(r * r + s * s + 2 * r * s * cos) - r))
    assert d.chamfer == pytest.approx(mean, rel=0.03)


def test_identical_meshes_are_close():
    m = _sphere(0.5)
    d = surface_distances(m, m.copy(), samples=3000)
    assert d.hausdorff < 1e-9 and d.chamfer < 1e-9


def test_bad_input():
    empty = trimesh.Trimesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), dtype=int))
    with pytest.raises(ValueError, match="recon"):
        surface_distances(empty, _sphere(0.5))
    with pytest.raises(ValueError, match="target"):
        surface_distances(_sphere(0.5), empty)
    with pytest.raises(TypeError, match="recon"):
        surface_distances("mesh.obj", _sphere(0.5))
    with pytest.raises(ValueError, match="samples"):
        surface_distances(_sphere(0.5), _sphere(0.5), samples=0)


def test_faces_around_vertices_match_trimesh_and_take_degenerate_faces():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    mine = faces_around_vertices(sphere.faces, len(sphere.vertices))
    theirs = np.asarray(sphere.vertex_faces)
    assert mine.shape == theirs.shape
    assert all(sorted(a[a >= 0]) == sorted(b[b >= 0]) for a, b in zip(mine, theirs))
    # a face naming vertex 1 twice, and a vertex in no face
    around = faces_around_vertices(np.array([[0, 1, 2], [2, 1, 1]]), 4)
    assert around.tolist() == [[0, -1, -1], [0, 1, 1], [0, 1, -1], [-1, -1, -1]]
