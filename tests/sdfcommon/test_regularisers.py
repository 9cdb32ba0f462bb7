"""sdfcommon.numerics.regularisers: the eikonal and Laplacian terms against hand-computed values on tiny grids
and analytic fields, the narrow band's edge cases, every interior vertex (mu=None, what mvr uses),
finite-difference gradients, the fused CPU operation against the torch specification, bad input."""
from __future__ import annotations

import pytest
import torch

import renderer
from sdfcommon.numerics.regularisers import (band_regularisers, box_face_eikonal_sum, eikonal_loss, laplacian_loss,
                                             narrow_band)


def ramp_grid(values_along_x, ny: int = 3, nz: int = 3, dtype=torch.float64) -> torch.Tensor:
    """(1, Nx, ny, nz) grid whose value depends on the x index only."""
    c = torch.tensor(values_along_x, dtype=dtype)
    return c[None, :, None, None].expand(1, len(values_along_x), ny, nz).clone()


# ------------------------------------------------------------------------------------------------
# narrow band


def test_narrow_band_is_inclusive_at_mu_voxels():
    sdf = torch.tensor([0.0, 0.031, 0.032, -0.032, 0.0321, -0.5])
    got = narrow_band(sdf, voxel_size=0.02, mu=1.6)  # half-width 0.032
    assert got.tolist() == [True, True, True, True, False, False]


# ------------------------------------------------------------------------------------------------
# eikonal


def test_eikonal_hand_computed_two_vertices():
    # Along x: 0, 0.1, 0.3, 0.6 with h = 0.1; the interior vertices are x-index 1 and 2.
    # Central differences: (0.3 - 0.0) / 0.2 = 1.5 and (0.6 - 0.1) / 0.2 = 2.5 (y, z: 0).
    # Terms (1 - g^2)^2: (1 - 2.25)^2 = 1.5625 and (1 - 6.25)^2 = 27.5625.
    sdf = ramp_grid([0.0, 0.1, 0.3, 0.6])
    assert eikonal_loss(sdf, 0.1, mu=10.0).item() == pytest.approx((1.5625 + 27.5625) / 2)
    # mu = 1.5: the band is |f| <= 0.15, which holds vertex 1 (f = 0.1) but not vertex 2 (f = 0.3).
    assert eikonal_loss(sdf, 0.1, mu=1.5).item() == pytest.approx(1.5625)


def test_eikonal_is_zero_for_a_true_distance_field():
    h = 0.05
    x = torch.arange(6, dtype=torch.float64) * h - 0.12
    sdf = x[None, :, None, None].expand(2, 6, 4, 5).clone()  # f = x: |grad f| = 1
    assert eikonal_loss(sdf, h, mu=100.0).item() == pytest.approx(0.0, abs=1e-12)


def test_eikonal_gradient_matches_finite_differences():
    torch.manual_seed(0)
    sdf = (torch.randn(1, 4, 4, 4, dtype=torch.float64) * 0.05).requires_grad_(True)
    # A fixed band (mu large) keeps the function smooth for gradcheck.
    assert torch.autograd.gradcheck(lambda s: eikonal_loss(s, 0.1, mu=100.0), (sdf,))
    assert torch.autograd.gradcheck(lambda s: laplacian_loss(s, 0.1, mu=100.0), (sdf,))


# ------------------------------------------------------------------------------------------------
# Laplacian


def test_laplacian_hand_computed():
    # Along x: 0, 0.1, 0.3, 0.7 with h = 0.1. Second differences at x-index 1: 0.3 - 0.2 + 0 = 0.1,
    # at 2: 0.7 - 0.6 + 0.1 = 0.2 (y, z: 0). Terms (second / h)^2 = 1 and 4.
    sdf = ramp_grid([0.0, 0.1, 0.3, 0.7])
    assert laplacian_loss(sdf, 0.1, mu=10.0).item() == pytest.approx(2.5)
    assert laplacian_loss(sdf, 0.1, mu=1.5).item() == pytest.approx(1.0)  # only vertex 1 in the band


def test_laplacian_is_zero_for_a_plane_and_known_for_a_sphere():
    plane = renderer.SDFGrid.from_function(lambda p: p @ torch.tensor([0.6, 0.8, 0.0]), 9, -0.5, 0.5)
    assert laplacian_loss(plane.values, 1.0 / 8, mu=100.0).item() == pytest.approx(0.0, abs=1e-10)
    # A sphere of radius r: lap f = 2 / r, so the term is (2 h / r)^2 near the surface.
    n, r = 33, 0.3
    sphere = renderer.SDFGrid.from_function(lambda p: p.norm(dim=-1) - r, n, -0.5, 0.5, dtype=torch.float64)
    h = 1.0 / (n - 1)
    assert laplacian_loss(sphere.values, h, mu=1.0).item() == pytest.approx((2 * h / r) ** 2, rel=0.05)


# ------------------------------------------------------------------------------------------------
# band edge cases


@pytest.mark.parametrize("loss", [eikonal_loss, laplacian_loss])
def test_empty_band_gives_zero_and_zero_gradients(loss):
    sdf = torch.full((2, 5, 5, 5), 0.5, dtype=torch.float64, requires_grad=True)  # far from any surface
    value = loss(sdf, 0.1, mu=1.6)
    assert value.item() == 0.0
    value.backward()
    assert sdf.grad is not None and torch.count_nonzero(sdf.grad) == 0


def test_all_band_equals_the_plain_mean_over_interior_vertices():
    torch.manual_seed(1)
    h = 0.1
    sdf = torch.randn(2, 5, 6, 4, dtype=torch.float64) * 0.01  # every |f| <= 1.6 h
    assert narrow_band(sdf, h, 1.6).all()
    gx = (sdf[:, 2:, 1:-1, 1:-1] - sdf[:, :-2, 1:-1, 1:-1]) / (2 * h)
    gy = (sdf[:, 1:-1, 2:, 1:-1] - sdf[:, 1:-1, :-2, 1:-1]) / (2 * h)
    gz = (sdf[:, 1:-1, 1:-1, 2:] - sdf[:, 1:-1, 1:-1, :-2]) / (2 * h)
    expected_eik = ((1 - (gx ** 2 + gy ** 2 + gz ** 2)) ** 2).mean()
    c = sdf[:, 1:-1, 1:-1, 1:-1]
    lap = (sdf[:, 2:, 1:-1, 1:-1] + sdf[:, :-2, 1:-1, 1:-1] + sdf[:, 1:-1, 2:, 1:-1] + sdf[:, 1:-1, :-2, 1:-1]
           + sdf[:, 1:-1, 1:-1, 2:] + sdf[:, 1:-1, 1:-1, :-2] - 6 * c) / h
    assert eikonal_loss(sdf, h, 1.6).item() == pytest.approx(expected_eik.item())
    assert laplacian_loss(sdf, h, 1.6).item() == pytest.approx((lap ** 2).mean().item())


def test_band_edge_vertices_do_not_count():
    # Only boundary vertices are near the surface: the interior holds no band vertex -> 0.
    sdf = torch.full((1, 4, 4, 4), 1.0, dtype=torch.float64)
    sdf[:, 0] = 0.0
    assert eikonal_loss(sdf, 0.1).item() == 0.0
    assert laplacian_loss(sdf, 0.1).item() == 0.0


# ------------------------------------------------------------------------------------------------
# image losses


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_fused_band_regularisers_match_the_torch_specification(dtype):
    from sdfcommon.numerics import band_kernel

    if not band_kernel.available():
        pytest.skip("numba is not installed")
    torch.manual_seed(0)
    n, h = 14, 0.1
    axis = torch.linspace(-0.65, 0.65, n)
    pts = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)
    sdf = (pts.norm(dim=-1) - 0.4 + 0.02 * torch.randn(2, n, n, n)).to(dtype).requires_grad_(True)
    spec = band_regularisers(sdf, h, 1.6, fused=False)
    fused = band_regularisers(sdf, h, 1.6, fused=True)
    tol = dict(rtol=1e-5, atol=1e-6) if dtype == torch.float32 else dict(rtol=1e-10, atol=1e-12)
    for a, b in zip(spec, fused):
        torch.testing.assert_close(a, b, **tol)
    g_spec = torch.autograd.grad(0.3 * spec[0] + 0.7 * spec[1], sdf)[0]
    g_fused = torch.autograd.grad(0.3 * fused[0] + 0.7 * fused[1], sdf)[0]
    torch.testing.assert_close(g_spec, g_fused, **tol)
    assert g_fused.abs().max() > 0
    if dtype == torch.float64:
        small = sdf.detach()[:1, :6, :6, :6].clone().requires_grad_(True)
        assert torch.autograd.gradcheck(lambda s: band_regularisers(s, h, 10.0, fused=True), (small,))
    # No vertex in the band: zeros that still backpropagate.
    far = torch.full((1, 5, 5, 5), 3.0, dtype=dtype, requires_grad=True)
    eik, lap = band_regularisers(far, h, 1.6, fused=True)
    (eik + lap).backward()
    assert eik.item() == lap.item() == 0.0 and far.grad.abs().max() == 0


def test_every_interior_vertex_with_mu_none():
    """mu=None (multi-view reconstruction): the plain means over the interior vertices, whatever the
    values; a plane of gradient (1, 0.5, 0) gives (1 - 1.25)^2 and no Laplacian, a bowl |p|^2 the
    Laplacian 6, in voxel units 6 h."""
    plane = renderer.SDFGrid.from_function(lambda p: p[..., 0] + 0.5 * p[..., 1], 16)
    h = 2.0 / 15
    assert float(eikonal_loss(plane.values, h, mu=None)) == pytest.approx(0.0625, rel=1e-4)
    assert float(laplacian_loss(plane.values, h, mu=None)) == pytest.approx(0.0, abs=1e-8)
    far = plane.values + 100.0  # no vertex near the surface: mu=None still takes them all
    assert float(eikonal_loss(far, h, mu=None)) == pytest.approx(0.0625, rel=1e-4)
    assert float(eikonal_loss(far, h, mu=1.6)) == 0.0
    sphere = renderer.SDFGrid.from_function(lambda p: p.norm(dim=-1) - 0.5, 32)
    assert float(eikonal_loss(sphere.values, 2.0 / 31, mu=None)) < 0.01  # only the kink at the centre deviates
    bowl = renderer.SDFGrid.from_function(lambda p: (p * p).sum(-1), 16)
    assert float(laplacian_loss(bowl.values, h, mu=None)) == pytest.approx((6 * h) ** 2, rel=1e-4)
    fused = band_regularisers(bowl.values, h, mu=None, fused=True)
    spec = band_regularisers(bowl.values, h, mu=None, fused=False)
    for a, b in zip(fused, spec):
        torch.testing.assert_close(a, b)


def test_bad_input_names_the_argument():
    sdf = torch.zeros(1, 4, 4, 4)
    with pytest.raises(ValueError, match="voxel_size"):
        eikonal_loss(sdf, 0.0)
    with pytest.raises(ValueError, match="mu"):
        laplacian_loss(sdf, 0.1, mu=-1)
    with pytest.raises(ValueError, match="sdf"):
        eikonal_loss(torch.zeros(4, 4, 4), 0.1)


def test_every_interior_vertex_is_listed_once_and_cached():
    """band_vertices(mu=None): the interior vertices in order, the same tensor for the same shape."""
    from sdfcommon.numerics.regularisers import band_vertices

    sdf = torch.randn(2, 5, 6, 7)
    got, _ = band_vertices(sdf, 0.1, None)
    b, i, j, k = torch.meshgrid(*(torch.arange(n) for n in (2, 5, 6, 7)), indexing="ij")
    inner = (i > 0) & (i < 4) & (j > 0) & (j < 5) & (k > 0) & (k < 6)
    assert torch.equal(got, inner.reshape(-1).nonzero().squeeze(1))
    assert band_vertices(torch.zeros(2, 5, 6, 7), 0.2, None)[0] is got


def test_box_faces_complete_the_eikonal_of_every_vertex():
    """Interior (band_regularisers, mu=None) plus the box faces is the mean over all vertices of the
    residual of SDFGrid.vertex_gradient (one-sided on the faces): each face vertex counted once."""
    torch.manual_seed(0)
    for n in (3, 7):
        axis = torch.linspace(-1.0, 1.0, n)
        p = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), dim=-1)
        v = (p.norm(dim=-1) - 0.5)[None].repeat(2, 1, 1, 1) + 0.05 * torch.randn(2, n, n, n)
        v.requires_grad_(True)
        g = renderer.SDFGrid(v, -1.0, 1.0).vertex_gradient()
        want = ((1.0 - (g * g).sum(-1)) ** 2).mean()
        eik, _ = band_regularisers(v, 2.0 / (n - 1), mu=None)
        got = (eik * (2 * (n - 2) ** 3) + box_face_eikonal_sum(v, 2.0 / (n - 1))) / (2 * n ** 3)
        assert got.item() == pytest.approx(want.item(), rel=1e-5)
        g_got, = torch.autograd.grad(got, v)
        g_want, = torch.autograd.grad(want, v)
        assert torch.allclose(g_got, g_want, atol=1e-6)
    # A plane at unit slope is a distance field: no residual on its faces either.
    axis = torch.linspace(0.0, 1.0, 5)
    x = torch.meshgrid(axis, axis, axis, indexing="ij")[0][None]
    assert box_face_eikonal_sum(x - 0.3, 0.25).item() == pytest.approx(0.0, abs=1e-10)
