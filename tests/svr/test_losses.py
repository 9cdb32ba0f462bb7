"""svr.losses: the image losses against hand-computed values and the renderer, the weighted total,
and bad input (the regularisers are sdfcommon's: tests/sdfcommon/test_regularisers.py)."""
from __future__ import annotations

import pytest
import torch

import renderer
import math

from svr.losses import (LossWeights, hull_loss, image_loss, resize_images, silhouette_loss, shading_loss,
                        total_loss, voxel_distances, voxel_loss)
from svr.nmr.views import render_views
from svr.nmr.metrics import iou_direct
from svr.nmr.voxels import nmr_voxel_centres


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


def _own_silhouettes(sdf: torch.Tensor, views: torch.Tensor, size: int = 64) -> torch.Tensor:
    sil, _ = render_views(sdf, 0.6, views, renderer.Scene(effects=("silhouette",)), size)
    return sil.detach()


def test_hull_loss_of_the_shape_itself_is_near_zero_and_grows_with_overfill():
    """A sphere inside its own views' visual hull costs (almost) nothing: the cone's field bounds an
    SDF from below; a sphere fatter than those silhouettes costs about the excess depth, beyond the
    tolerance."""
    sdf = _sphere(n=32, r=0.3, batch=1)
    voxel = 1.2 / 31
    views = torch.tensor([[0, 6, 12, 18]])
    alpha = _own_silhouettes(sdf, views)
    own = hull_loss(sdf, 0.6, alpha, views, tolerance=0.0, stride=1).item()
    fat = [hull_loss(sdf - d * voxel, 0.6, alpha, views, tolerance=0.0, stride=1).item() for d in (1, 2)]
    assert own < 0.01  # pixel-sized errors of the cone at the outline only
    assert fat[0] > 5 * max(own, 1e-4) and fat[1] > 1.5 * fat[0]
    # With the default tolerance of a voxel, a voxel too fat is forgiven, three are not.
    assert hull_loss(sdf - voxel, 0.6, alpha, views, stride=1).item() < 0.01
    assert hull_loss(sdf - 3 * voxel, 0.6, alpha, views, stride=1).item() > 0.1


def test_hull_loss_hand_computed_and_its_gradient():
    """A constant field c against one view whose silhouette is empty: the hull is everywhere farther
    than the margin (the clamp), so the loss is (margin - tolerance - c / voxel) and each sample's
    gradient is -1 / (samples x voxel)."""
    n, half = 9, 0.5
    voxel = 2 * half / (n - 1)
    c = 0.5 * voxel
    sdf = torch.full((1, n, n, n), c, dtype=torch.float32, requires_grad=True)
    alpha = torch.zeros(1, 1, 16, 16)
    loss = hull_loss(sdf, half, alpha, torch.tensor([[0]]), margin=2.0, tolerance=0.25, stride=1)
    assert loss.item() == pytest.approx(2.0 - 0.25 - 0.5, rel=1e-5)
    loss.backward()
    assert torch.allclose(sdf.grad, torch.full_like(sdf, -1.0 / (n ** 3 * voxel)))
    # stride 2 reads every other sample: the rest get no gradient
    sdf.grad = None
    hull_loss(sdf, half, alpha, torch.tensor([[0]]), margin=2.0, tolerance=0.25, stride=2).backward()
    assert bool((sdf.grad[:, ::2, ::2, ::2] < 0).all()) and float(sdf.grad[:, 1::2].abs().sum()) == 0.0


def test_hull_loss_thins_a_shape_too_deep_for_its_side_view():
    """A box stretched along z (the depth of view 0) seen by views 0 and 6 (from the side): gradient
    descent on the hull loss alone lowers its volume where view 6 shows background, and leaves the
    true box's samples alone."""
    n = 24
    true = renderer.SDFGrid.from_function(lambda p: (p.abs() - torch.tensor([0.3, 0.2, 0.1])).amax(-1), n, -0.6, 0.6)
    deep = renderer.SDFGrid.from_function(lambda p: (p.abs() - torch.tensor([0.3, 0.2, 0.4])).amax(-1), n, -0.6, 0.6)
    views = torch.tensor([[0, 6]])
    alpha = _own_silhouettes(true.values.reshape(1, n, n, n), views)
    x = deep.values.reshape(1, n, n, n).clone().requires_grad_(True)
    opt = torch.optim.SGD([x], lr=10.0)  # the mean over samples: each gets 1 / (samples x voxel)
    start = (x < 0).sum().item()
    for _ in range(30):
        opt.zero_grad()
        hull_loss(x, 0.6, alpha, views, stride=1).backward()
        opt.step()
    inside_true = true.values.reshape(1, n, n, n) < -0.05
    assert (x < 0).sum().item() < 0.6 * start
    assert bool((x.detach()[inside_true] < 0).all())


def test_total_loss_adds_the_weighted_hull_term():
    sdf = _sphere(batch=1)
    views = torch.tensor([[0, 6]])
    alpha = _own_silhouettes(_sphere(r=0.2, batch=1), views)
    images = torch.zeros(1, 2, 4, 64, 64)
    images[:, :, 3] = alpha
    img = image_loss(sdf, 0.6, images, views, renderer.Scene(effects=("silhouette",)), 32)
    hull = hull_loss(sdf, 0.6, alpha, views)
    w = LossWeights(hull=0.5, eikonal=0.0, laplacian=0.0)
    terms = total_loss(img, sdf, 1.2 / 31, w, hull=hull)
    assert terms.total.item() == pytest.approx((img.silhouette + 0.5 * hull).item())
    assert "hull" in terms.as_dict() and hull.item() > 0
    with pytest.raises(ValueError, match="hull"):
        total_loss(img, sdf, 1.2 / 31, w)


def test_voxel_loss_hand_computed():
    # A constant SDF c: every centre's logit is (level - c) / softness; half the voxels are solid.
    c, level, soft = 0.02, 0.01, 0.05
    sdf = torch.full((1, 8, 8, 8), c, dtype=torch.float64)
    vox = torch.zeros(1, 4, 4, 4, dtype=torch.bool)
    vox[..., :2] = True
    p = 1.0 / (1.0 + math.exp(-(level - c) / soft))
    expected = -0.5 * (math.log(p) + math.log(1.0 - p))
    assert voxel_loss(sdf, 0.6, vox, "bce", level=level, softness=soft).item() == pytest.approx(expected)


def test_voxel_distances_hand_computed():
    vox = torch.zeros(2, 5, 5, 5, dtype=torch.bool)
    vox[0, 2, 2, 2] = True           # one solid voxel
    vox[1] = True                    # all solid
    d = voxel_distances(vox, truncation=2.0)
    assert d[0, 2, 2, 2].item() == pytest.approx(-0.5)
    assert d[0, 2, 2, 3].item() == pytest.approx(0.5)
    assert d[0, 2, 3, 3].item() == pytest.approx(math.sqrt(2) - 0.5)
    assert d[0, 0, 0, 0].item() == pytest.approx(2.0)  # sqrt(12) - 0.5, truncated
    assert (d[1] == -2.0).all()
    # the distance loss of a constant SDF is the mean gap to these targets, in voxels
    sdf = torch.zeros(2, 8, 8, 8)
    expected = (d - 0.0).abs().mean().item()
    assert voxel_loss(sdf, 0.6, vox, "distance", level=0.0, truncation=2.0).item() == pytest.approx(expected, rel=1e-5)


def test_voxel_distance_gradient_reaches_a_prediction_deep_on_the_wrong_side():
    # A predicted sphere of radius 0.4 against the voxels of one of radius 0.1: the centres between
    # the two lie up to 9 voxels inside the prediction but outside the object (target +truncation).
    # d loss / d SDF at a centre is (R - 1) sign(pred - target) / R^3 (0 where the prediction is past
    # the truncation on the target's side), and the trilinear weights of a centre sum to 1, so the
    # grid's gradient sums to (R - 1) / R^3 times the sum of those signs: -1 at every wrong centre.
    r, level, trunc = 32, 0.0, 3.0
    vox = (nmr_voxel_centres(r).norm(dim=-1) < 0.1)[None]
    sdf = _sphere(n=64, r=0.4, batch=1).double().requires_grad_(True)
    voxel_loss(sdf, 0.6, vox, "distance", level=level, truncation=trunc).backward()
    at = (nmr_voxel_centres(r, dtype=torch.float64).norm(dim=-1) - 0.4)[None]  # the sphere's exact SDF
    pred = at * (r - 1)
    t = voxel_distances(vox, trunc).double()
    sign = torch.sign(pred - t)
    sign[(t >= trunc) & (pred >= trunc)] = 0.0
    sign[(t <= -trunc) & (pred <= -trunc)] = 0.0
    deep = ((t >= trunc) & (pred < -trunc)).sum().item()
    assert deep > 1000  # the case clamping both sides left without gradient
    assert sdf.grad.sum().item() == pytest.approx((r - 1) / r ** 3 * sign.sum().item(), rel=1e-3)
    assert sdf.grad.sum().item() < 0  # descent raises the SDF: the sphere shrinks toward the object


def test_voxel_iou_loss_is_one_minus_iou_per_object_and_counts_objects_alike():
    # With a sharp occupancy the "iou" loss is 1 - the direct IoU at the level, averaged over
    # objects: a small object predicted empty costs 1 whatever its size, a right one 0.
    centres = nmr_voxel_centres(32).norm(dim=-1)
    vox = torch.stack([centres < 0.1, centres < 0.45])
    sdf = torch.stack([_sphere(n=64, r=0.3, batch=1)[0] * 0 + 1.0, _sphere(n=64, r=0.45, batch=1)[0]]).double()
    level = 0.0
    expected = 1.0 - iou_direct(sdf, vox, -0.6, 0.6, level=level).mean().item()
    got = voxel_loss(sdf, 0.6, vox, "iou", level=level, softness=1e-6).item()
    assert got == pytest.approx(expected, abs=1e-3)
    assert got == pytest.approx(0.5, abs=0.01)


@pytest.mark.parametrize("kind", ["iou", "distance", "bce"])
def test_voxel_loss_prefers_the_right_shape_and_its_gradient_grows_a_small_one(kind):
    # Voxels of a sphere of radius 0.3 (centres inside it): the exact SDF scores lower than a
    # smaller or larger sphere, and on the smaller one gradient descent lowers the SDF (grows it).
    vox = (nmr_voxel_centres(32).norm(dim=-1) < 0.3)[None]
    losses = {r: voxel_loss(_sphere(r=r, batch=1), 0.6, vox, kind, level=0.0).item() for r in (0.2, 0.3, 0.4)}
    assert losses[0.3] < losses[0.2] and losses[0.3] < losses[0.4]
    small = _sphere(r=0.2, batch=1).requires_grad_(True)
    voxel_loss(small, 0.6, vox, kind, level=0.0).backward()
    assert small.grad.sum().item() > 0


def test_total_loss_with_voxels_only_renders_nothing():
    sdf = _sphere(batch=1).double()
    vox = (nmr_voxel_centres(32).norm(dim=-1) < 0.3)[None]
    w = LossWeights(silhouette=0.0, shading=0.0, voxel=2.0, eikonal=0.1, laplacian=0.3)
    assert not w.renders(shading=True)
    v = voxel_loss(sdf, 0.6, vox)
    terms = total_loss(None, sdf, 1.2 / 31, w, v)
    assert terms.total.item() == pytest.approx((2.0 * v + 0.1 * terms.eikonal + 0.3 * terms.laplacian).item())
    assert set(terms.as_dict()) == {"total", "voxel", "eikonal", "laplacian"}
    with pytest.raises(ValueError, match="voxel"):
        total_loss(None, sdf, 1.2 / 31, w)
    with pytest.raises(ValueError, match="image"):
        total_loss(None, sdf, 1.2 / 31, LossWeights())


# ------------------------------------------------------------------------------------------------
# bad input


def test_bad_input_names_the_argument():
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


    with pytest.raises(ValueError, match="all 0"):
        LossWeights(silhouette=0.0, shading=0.0)
    with pytest.raises(ValueError, match="voxels"):
        voxel_loss(_sphere(batch=1), 0.6, torch.zeros(1, 4, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match="kind"):
        voxel_loss(_sphere(batch=1), 0.6, torch.zeros(1, 4, 4, 4, dtype=torch.bool), "l2")
    with pytest.raises(ValueError, match="voxel_kind"):
        LossWeights(voxel_kind="l2")
    with pytest.raises(ValueError, match="hull_margin"):
        LossWeights(hull_margin=0.0)
    with pytest.raises(ValueError, match="hull_tolerance"):
        LossWeights(hull_tolerance=-1.0)
    with pytest.raises(ValueError, match="hull_stride"):
        LossWeights(hull_stride=0)
    with pytest.raises(ValueError, match="alpha"):
        hull_loss(_sphere(batch=1), 0.6, torch.zeros(1, 64, 64), torch.tensor([[0]]))
    with pytest.raises(ValueError, match="view_ids"):
        hull_loss(_sphere(batch=1), 0.6, torch.zeros(1, 2, 64, 64), torch.tensor([[0]]))
