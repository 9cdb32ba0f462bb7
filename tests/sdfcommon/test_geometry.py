"""sdfcommon.numerics.meshing.sdf_to_mesh against analytic shapes: a sphere's mesh lies on the sphere (within
a voxel), encloses its volume with outward normals, and a shape cut by the box is closed there."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sdfcommon.numerics.meshing import sdf_to_mesh


def _grid(n: int, lo: float, hi: float) -> torch.Tensor:
    axis = torch.linspace(lo, hi, n, dtype=torch.float64)
    return torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)


def test_sphere_mesh_lies_on_the_sphere_with_outward_normals():
    n, r = 41, 0.6
    p = _grid(n, -1.0, 1.0) + torch.tensor([0.0123, 0.0, 0.0], dtype=torch.float64)  # off-centre, no sample exactly on it
    values = p.norm(dim=-1) - r
    mesh = sdf_to_mesh(values, -1.0, 1.0)
    voxel = 2.0 / (n - 1)
    radii = np.linalg.norm(mesh.vertices + [0.0123, 0.0, 0.0], axis=1)
    assert np.abs(radii - r).max() < 0.1 * voxel
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(4 / 3 * math.pi * r ** 3, rel=0.02)  # positive: outward normals


def test_a_shape_cut_by_the_box_is_closed_there_unless_asked_not_to():
    values = _grid(21, -0.5, 0.5)[..., 2] - 0.2345  # solid below the plane z = 0.2345 fills the box's bottom
    closed = sdf_to_mesh(values, -0.5, 0.5)
    # closed within a voxel (0.05) beyond the box's faces, where the padding's values meet the grid's
    assert closed.is_watertight and 0.7345 < closed.volume < 1.1 * 1.1 * 0.7845
    assert not sdf_to_mesh(values.numpy(), [-0.5] * 3, [0.5] * 3, close=False).is_watertight


def test_no_crossing_gives_an_empty_mesh_and_bad_grids_are_refused():
    assert len(sdf_to_mesh(torch.ones(4, 4, 4)).faces) == 0
    with pytest.raises(ValueError, match=r"values must have shape \(Nx, Ny, Nz\) with Nx, Ny, Nz >= 2"):
        sdf_to_mesh(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="NaN or Inf"):
        sdf_to_mesh(np.full((3, 3, 3), np.nan))
