"""sdfcommon.numerics.redistance: a sphere's and a box's SDF, scaled and disturbed away from the
surface, come back to their distances; the interface and the signs are kept; the edge cases."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from sdfcommon.numerics.redistance import interface_mask, redistance


def _lattice(n: int):
    x = torch.linspace(-1, 1, n, dtype=torch.float64)
    return torch.meshgrid(x, x, x, indexing="ij"), 2.0 / (n - 1)


def _sphere(n: int, r: float = 0.6):
    (x, y, z), h = _lattice(n)
    return (x * x + y * y + z * z).sqrt() - r, h


def _box(n: int, half: float = 0.5):
    (x, y, z), h = _lattice(n)
    q = torch.stack([x.abs(), y.abs(), z.abs()]) - half
    return q.clamp(min=0).norm(dim=0) + q.max(0).values.clamp(max=0), h


def test_interface_mask_by_hand():
    inside = np.zeros((4, 4, 4), bool)
    inside[0, 0, 0] = True  # one inside corner: the one cell it belongs to is mixed
    mask = interface_mask(inside)
    assert mask.sum() == 8
    assert mask[:2, :2, :2].all()
    assert not interface_mask(np.zeros((3, 3, 3), bool)).any()
    assert not interface_mask(np.ones((3, 3, 3), bool)).any()


@pytest.mark.parametrize("shape", [_sphere, _box])
def test_a_scaled_and_disturbed_sdf_comes_back_to_its_distances(shape):
    true, h = shape(48)
    (x, _, _), _ = _lattice(48)
    # three times too steep everywhere (the zero set of the trilinear field unchanged), and wavy
    # away from the surface
    bad = 3 * true + 0.05 * torch.sin(7 * x) * (true.abs() > 0.2)
    out = redistance(bad.float(), h)
    assert out.dtype == torch.float32 and out.shape == bad.shape
    interface = torch.from_numpy(interface_mask((bad < 0).numpy()))
    assert torch.equal(out[interface], bad.float()[interface])   # the surface does not move
    assert torch.equal(out < 0, bad < 0)                           # nor any sign
    err = (out.double() - true).abs() / h
    d = true.abs() / h
    near = ~interface & (d < 4)
    assert float(err[near].max()) < 0.2         # voxels, within the exact band
    assert float((err[~interface] / d[~interface]).max()) < 0.1  # relative, everywhere else
    before = (bad.double() - true).abs() / h
    assert float(before[~interface].max()) > 10  # what it repaired


def test_without_a_surface_the_grid_is_returned_unchanged():
    v = torch.full((5, 5, 5), 0.3)
    assert torch.equal(redistance(v, 0.1), v)
    assert torch.equal(redistance(-v, 0.1), -v)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="voxel_size"):
        redistance(torch.zeros(4, 4, 4), 0.0)
    with pytest.raises((ValueError, TypeError), match="values"):
        redistance(torch.zeros(4, 4), 0.1)
