"""SDFGrid: layout, trilinear sampling, finite-difference gradients, resampling."""
from __future__ import annotations

import torch

from renderer import SDFGrid


def _linear(p):
    return 0.3 * p[..., 0] - 0.7 * p[..., 1] + 0.2 * p[..., 2] + 0.1


def test_layout_is_meshgrid_ij_with_samples_on_the_faces():
    grid = SDFGrid.from_function(lambda p: p[..., 0] + 10 * p[..., 1] + 100 * p[..., 2], (3, 4, 5),
                                 bbox_min=(0.0, -1.0, 2.0), bbox_max=(1.0, 2.0, 4.0), dtype=torch.float64)
    v = grid.values[0]
    assert v.shape == (3, 4, 5)
    assert v[0, 0, 0].item() == 0.0 + 10 * -1.0 + 100 * 2.0
    assert v[2, 3, 4].item() == 1.0 + 10 * 2.0 + 100 * 4.0
    torch.testing.assert_close(grid.voxel_size, torch.tensor([0.5, 1.0, 0.5], dtype=torch.float64))


def test_trilinear_sampling_is_exact_for_linear_functions_and_clamps_outside():
    grid = SDFGrid.from_function(_linear, (5, 6, 7), dtype=torch.float64)
    pts = torch.rand(200, 3, dtype=torch.float64) * 2 - 1
    torch.testing.assert_close(grid.sample(pts), _linear(pts))
    outside = torch.tensor([[3.0, 0.0, 0.0]], dtype=torch.float64)
    torch.testing.assert_close(grid.sample(outside), _linear(torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)))


def test_sample_gradient_is_exact_for_linear_functions_and_matches_vertex_gradient():
    grid = SDFGrid.from_function(_linear, 6, dtype=torch.float64)
    pts = torch.rand(50, 3, dtype=torch.float64) * 2 - 1
    expect = torch.tensor([0.3, -0.7, 0.2], dtype=torch.float64).expand(50, 3)
    torch.testing.assert_close(grid.sample_gradient(pts), expect)
    quad = SDFGrid.from_function(lambda p: (p**2).sum(-1), 9, dtype=torch.float64)
    vg = quad.vertex_gradient()[0]
    verts = quad.points().reshape(-1, 3)
    torch.testing.assert_close(quad.sample_gradient(verts), vg.reshape(-1, 3))


def test_batched_sampling_reads_each_grid():
    a = SDFGrid.from_function(_linear, 5).values
    grid = SDFGrid(torch.cat([a, a + 1.0]))
    pts = (torch.rand(1, 10, 3) * 2 - 1).expand(2, 10, 3)
    out = grid.sample(pts)
    torch.testing.assert_close(out[1] - out[0], torch.ones(10))


def test_resample_preserves_linear_functions():
    grid = SDFGrid.from_function(_linear, 4, dtype=torch.float64)
    fine = grid.resample(9)
    torch.testing.assert_close(fine.values, SDFGrid.from_function(_linear, 9, dtype=torch.float64).values)


def test_values_are_kept_without_copy():
    v = torch.zeros(4, 4, 4, requires_grad=True)
    grid = SDFGrid(v)
    assert grid.values.data_ptr() == v.data_ptr()


def test_detach_shares_values_and_box_without_autograd():
    v = torch.rand(2, 4, 5, 6, dtype=torch.float64, requires_grad=True)
    grid = SDFGrid(v * 1.0, [-1.0, -0.5, -2.0], [1.0, 0.5, 2.0])
    cut = grid.detach()
    assert isinstance(cut, SDFGrid) and not cut.values.requires_grad and cut.values.grad_fn is None
    assert cut.values.data_ptr() == grid.values.data_ptr()
    assert torch.equal(cut.bbox_min, grid.bbox_min) and torch.equal(cut.bbox_max, grid.bbox_max)
    p = torch.rand(7, 3, dtype=torch.float64) - 0.5
    b = torch.tensor([0, 1, 0, 1, 0, 1, 0])
    assert not cut.sample(p, b).requires_grad
    torch.testing.assert_close(cut.sample(p, b), grid.sample(p, b).detach())


def test_host_box_and_voxel_size_match_the_grids_own():
    """The host copies the kernels' parameters are made from (no wait for a GPU) equal the grid's
    box and voxel size, for a grid built, detached and made without the checks."""
    grid = SDFGrid(torch.zeros(2, 5, 7, 9, dtype=torch.float64), (-1.0, -0.5, 0.0), (1.0, 0.5, 2.0))
    for g in (grid, grid.detach(), SDFGrid._unchecked(grid.values, grid.bbox_min, grid.bbox_max)):
        lo, hi = g.host_box()
        assert lo.device.type == "cpu" and torch.equal(lo, grid.bbox_min) and torch.equal(hi, grid.bbox_max)
        assert torch.equal(g.host_voxel_size(), grid.voxel_size)
