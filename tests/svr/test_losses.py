"""svr.losses: each loss against a hand-computed value on a tiny grid, the narrow band's edge cases,
the image loss against the renderer, and bad input."""
from __future__ import annotations

import pytest
import torch

import renderer
from svr.losses import (LossWeights, band_regularisers, eikonal_loss, image_loss, laplacian_loss, narrow_band,
                        render_views, resize_images, silhouette_loss, shading_loss, total_loss)


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


def test_silhouette_losses_hand_computed():
    pred = torch.tensor([[1.0, 0.0], [0.5, 0.0]])
    target = torch.tensor([[1.0, 1.0], [0.0, 0.0]])
    assert silhouette_loss(pred, target, "mse").item() == pytest.approx((0 + 1 + 0.25 + 0) / 4)
    # soft IoU: intersection 1, union (1) + (1) + (0.5) = 2.5 -> 1 - 0.4
    assert silhouette_loss(pred, target, "iou").item() == pytest.approx(0.6)


def test_shading_loss_hand_computed():
    pred = torch.zeros(1, 3, 1, 2)
    target = torch.tensor([[[[1.0, 0.0]], [[0.5, 0.0]], [[0.0, 0.0]]]])
    assert shading_loss(pred, target).item() == pytest.approx((1 + 0.25) / 6)


def test_resize_images_averages_blocks():
    img = torch.arange(16, dtype=torch.float32).reshape(1, 1, 1, 4, 4).expand(1, 1, 4, 4, 4)
    small = resize_images(img, 2)
    assert small.shape == (1, 1, 4, 2, 2)
    assert small[0, 0, 0].tolist() == [[2.5, 4.5], [10.5, 12.5]]
    assert resize_images(img, 4) is img


def _sphere(n: int = 32, r: float = 0.3, batch: int = 2) -> torch.Tensor:
    g = renderer.SDFGrid.from_function(lambda p: p.norm(dim=-1) - r, n, -0.6, 0.6)
    return g.values.expand(batch, n, n, n).clone()


def test_image_loss_matches_the_renderer_and_follows_the_scene():
    sdf = _sphere()
    views = torch.tensor([[0, 5], [12, 20]])
    images = torch.rand(2, 2, 4, 32, 32)
    sil_scene = renderer.Scene(effects=("silhouette",))
    out = image_loss(sdf, 0.6, images, views, sil_scene, render_size=32)
    assert out.shading is None and out.colours is None  # silhouette-only data pays for no shading
    ref = renderer.render(renderer.SDFGrid(sdf, -0.6, 0.6), renderer.Cameras.nmr(views.reshape(-1), image_size=32),
                          sil_scene)
    expected = ((ref.silhouette.reshape(2, 2, 32, 32) - images[:, :, 3]) ** 2).mean()
    assert out.silhouette.item() == pytest.approx(expected.item(), rel=1e-5)

    shade_scene = renderer.Scene(effects=("silhouette", "shading"), background=(1.0, 1.0, 1.0))
    out2 = image_loss(sdf, 0.6, images, views, shade_scene, render_size=32)
    ref2 = renderer.render(renderer.SDFGrid(sdf, -0.6, 0.6), renderer.Cameras.nmr(views.reshape(-1), image_size=32),
                           shade_scene)
    colours = ref2.image.reshape(2, 2, 32, 32, 3).permute(0, 1, 4, 2, 3)
    assert out2.shading.item() == pytest.approx(((colours - images[:, :, :3]) ** 2).mean().item(), rel=1e-5)


def test_image_loss_of_own_render_is_small_and_has_gradients():
    sdf = _sphere(batch=1)
    views = torch.tensor([[3, 9]])
    sil, _ = render_views(sdf, 0.6, views, renderer.Scene(effects=("silhouette",)), 32)
    images = torch.zeros(1, 2, 4, 32, 32)
    images[:, :, 3] = sil.detach()
    wrong = _sphere(r=0.2, batch=1).requires_grad_(True)
    loss = image_loss(wrong, 0.6, images, views, renderer.Scene(effects=("silhouette",)), 32).silhouette
    assert image_loss(sdf, 0.6, images, views, renderer.Scene(effects=("silhouette",)), 32).silhouette.item() < 1e-10
    loss.backward()
    # Too small a sphere: the loss falls as the SDF falls (the sphere grows): a positive gradient,
    # so gradient descent lowers the SDF.
    assert wrong.grad.sum().item() > 0


def test_total_loss_weights_the_terms():
    sdf = _sphere(batch=1).double()
    images = torch.rand(1, 1, 4, 32, 32, dtype=torch.float64)
    views = torch.tensor([[0]])
    scene = renderer.Scene(effects=("silhouette", "shading"))
    img = image_loss(sdf, 0.6, images, views, scene, 32)
    w = LossWeights(silhouette=2.0, shading=0.5, eikonal=0.1, laplacian=0.3, band_mu=1.6)
    terms = total_loss(img, sdf, 1.2 / 31, w)
    expected = 2.0 * img.silhouette + 0.5 * img.shading + 0.1 * terms.eikonal + 0.3 * terms.laplacian
    assert terms.total.item() == pytest.approx(expected.item())
    assert set(terms.as_dict()) == {"total", "silhouette", "shading", "eikonal", "laplacian"}


# ------------------------------------------------------------------------------------------------
# bad input


def test_bad_input_names_the_argument():
    sdf = torch.zeros(1, 4, 4, 4)
    with pytest.raises(ValueError, match="voxel_size"):
        eikonal_loss(sdf, 0.0)
    with pytest.raises(ValueError, match="mu"):
        laplacian_loss(sdf, 0.1, mu=-1)
    with pytest.raises(ValueError, match="sdf"):
        eikonal_loss(torch.zeros(4, 4, 4), 0.1)
    with pytest.raises(ValueError, match="kind"):
        silhouette_loss(torch.zeros(2, 2), torch.zeros(2, 2), "l1")
    with pytest.raises(ValueError, match="size"):
        resize_images(torch.zeros(1, 1, 4, 64, 64), 48)
    with pytest.raises(ValueError, match="view_ids"):
        image_loss(_sphere(batch=1), 0.6, torch.zeros(1, 2, 4, 32, 32), torch.tensor([[0]]),
                   renderer.Scene(effects=("silhouette",)), 32)
    with pytest.raises(ValueError, match="eikonal"):
        LossWeights(eikonal=-0.1)
    with pytest.raises(ValueError, match="silhouette_kind"):
        LossWeights(silhouette_kind="l1")


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_fused_band_regularisers_match_the_torch_specification(dtype):
    from svr import band_kernel

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
