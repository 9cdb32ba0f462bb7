"""svr.models.ShapePrior: the visual hull of known silhouettes, retrieval by silhouette that never
returns an excluded object, and the pixel-aligned head reading the prior at its samples."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

import renderer
from svr.models import ImageEncoder, PixelAlignedHead, SDFDecoder, SDFRefiner, ShapePrior, SVRNet
from svr.models.prior import view_grid, visual_hull

from .test_local import sphere_silhouette
from .test_models import CONFIGS


def disc(radius_px: float) -> np.ndarray:
    """(64, 64) uint8 alpha of a disc centred in the image."""
    yy, xx = np.mgrid[0:64, 0:64] - 31.5
    return ((xx ** 2 + yy ** 2) < radius_px ** 2).astype(np.uint8) * 255


class Discs:
    """A stand-in training split: object g shows a centred disc of radius ``radii[g]`` pixels in every
    view (``images_uint8``, ``offsets`` as ``NMRDataset``)."""

    def __init__(self, radii, counts):
        self.radii = list(radii)
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    def __len__(self):
        return len(self.radii)

    def images_uint8(self, g):
        out = np.zeros((24, 4, 64, 64), np.uint8)
        out[:, 3] = disc(self.radii[g])
        return out


def grid_points(side: int, half: float = 0.6) -> torch.Tensor:
    axis = torch.linspace(-half, half, side)
    return torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)


def test_the_hull_of_a_sphere_holds_the_sphere_and_not_its_equator_outside():
    r = 0.3
    alpha = torch.cat([sphere_silhouette((0.0, 0.0, 0.0), r, v)[:, 3] for v in range(24)])
    pts = grid_points(24).reshape(-1, 3)
    hull = visual_hull(alpha, view_grid(pts))
    dist = pts.norm(dim=-1)
    inside = dist < r - 0.06
    equator_out = (dist > r + 0.06) & (pts[:, 1].abs() < 0.05)  # the 24 views ring the equator
    assert inside.sum() > 200 and equator_out.sum() > 100
    assert hull[inside].min() > 0.95
    assert hull[equator_out].max() < 0.05
    assert hull.max() <= 1.0 and hull.min() >= 0.0


def test_retrieval_finds_the_same_silhouette_and_never_an_excluded_object():
    data = Discs([6, 9, 12, 15, 18], counts=[2, 3])
    prior = ShapePrior(objects=5, side=8, neighbours=1, categories=2)
    prior.attach(grid_points(8))
    prior.fill(data)
    assert prior.first.tolist() == [0, 2]
    query = torch.from_numpy(disc(12)).float().div(255)[None].repeat(3, 1, 1)
    views = torch.tensor([0, 7, 23])
    assert prior.nearest(query, views).flatten().tolist() == [2, 2, 2]
    # Excluded, the object itself is never found; the next closest disc is (radius 9 or 15).
    found = prior.nearest(query, views, exclude=torch.tensor([2, 2, -1])).flatten().tolist()
    assert found[0] in (1, 3) and found[1] in (1, 3) and found[2] == 2
    # A training batch's (category, object index) names the global object.
    assert prior.exclusion(torch.tensor([0, 1, 1]), torch.tensor([1, 0, 2])).tolist() == [1, 2, 4]
    # The output is the found object's hull (neighbours=1), larger discs giving larger hulls.
    out = prior(query[:1], views[:1])
    torch.testing.assert_close(out.flatten(), prior.hulls[2].float() / 255)
    small, large = (prior(torch.from_numpy(disc(r)).float().div(255)[None], views[:1]) for r in (6, 18))
    assert small.sum() < out.sum() < large.sum()
    # Fractional views and (view, elevation) rows compare in the nearest NMR view.
    assert torch.equal(prior(query[:1], torch.tensor([[0.2, 40.0]])), out)


def test_the_mean_of_several_neighbours_and_argument_checks():
    data = Discs([6, 9, 12, 15, 18], counts=[5])
    prior = ShapePrior(objects=5, side=8, neighbours=2)
    prior.attach(grid_points(8))
    prior.fill(data)
    query = torch.from_numpy(disc(13)).float().div(255)[None]
    out = prior(query, torch.tensor([4]))
    torch.testing.assert_close(out.flatten(), (prior.hulls[2].float() + prior.hulls[3].float()).flatten() / 510)
    assert ShapePrior(objects=3, side=8, neighbours=4).neighbours == 2  # one may be excluded
    with pytest.raises(ValueError, match="objects"):
        ShapePrior(objects=1, side=8)
    with pytest.raises(ValueError, match="auto"):
        ShapePrior(objects="auto", side=8)
    with pytest.raises(ValueError, match="training split has 5"):
        ShapePrior(objects=4, side=8, neighbours=1).fill(data)


def test_the_head_reads_the_prior_at_each_cells_samples():
    head = PixelAlignedHead(image_channels=(4,), volume_channels=2, hidden=4, head_stride=2, prior=True)
    points = grid_points(8)
    prior = torch.rand(1, 8, 8, 8)
    x = head.cell_inputs(torch.zeros(1, 2, 4, 4, 4), [torch.rand(1, 4, 64, 64)], torch.tensor([3]), points, prior)
    assert x.shape == (1, 64, head.first.in_features)
    # The last 8 columns of cell (i, j, k) are the prior at its 2x2x2 samples, in sample order.
    cells = prior.reshape(4, 2, 4, 2, 4, 2).permute(0, 2, 4, 1, 3, 5).reshape(64, 8)
    torch.testing.assert_close(x[0, :, -8:], cells)
    with pytest.raises(ValueError, match="prior"):
        head.cell_inputs(torch.zeros(1, 2, 4, 4, 4), [torch.rand(1, 4, 64, 64)], torch.tensor([3]), points)
    with pytest.raises(ValueError, match="true or false"):
        PixelAlignedHead(prior="yes")


def test_a_network_with_a_prior_checks_its_parts_and_uses_it():
    enc = ImageEncoder(channels=(4, 8), latent_dim=8)
    dec = SDFDecoder(latent_dim=8, base_resolution=4, channels=(8, 4), grid_resolution=16, head_stride=2,
                     upsampling="centres")
    ref = SDFRefiner(channels=(4, 8), grid_resolution=16, input_stride=2)
    side = dec.head_points.shape[0]
    with pytest.raises(ValueError, match="local.prior"):
        SVRNet(enc, dec, ref, local=PixelAlignedHead(image_channels=(4, 4), volume_channels=4, prior=True))
    with pytest.raises(ValueError, match="reads it"):
        SVRNet(enc, dec, ref, local=PixelAlignedHead(image_channels=(4, 4), volume_channels=4),
               prior=ShapePrior(objects=5, side=side, neighbours=1))
    with pytest.raises(ValueError, match="prior.side"):
        SVRNet(enc, dec, ref, local=PixelAlignedHead(image_channels=(4, 4), volume_channels=4, prior=True),
               prior=ShapePrior(objects=5, side=side + 1, neighbours=1))
    torch.manual_seed(0)
    local = PixelAlignedHead(image_channels=(4, 4), volume_channels=4, prior=True)
    net = SVRNet(enc, dec, ref, local=local, prior=ShapePrior(objects=5, side=side, neighbours=1)).eval()
    net.prior.fill(Discs([6, 9, 12, 15, 18], counts=[5]))
    torch.nn.init.normal_(local.out.weight, std=0.5)
    image = torch.ones(1, 4, 64, 64)
    image[0, 3] = torch.from_numpy(disc(12)).float() / 255
    with torch.no_grad():
        own = net.coarse(image, torch.tensor([0]))
        other = net.coarse(image, torch.tensor([0]),
                           prior=net.shape_prior(image, torch.tensor([0]), exclude=torch.tensor([2])))
    assert (own - other).abs().max() > 1e-4  # another neighbour's hull, another shape
    # The silhouettes travel with the weights; the hulls are made from them again on loading.
    state = net.state_dict()
    assert {"prior.silhouettes", "prior.first"} <= set(state) and "prior.hulls" not in state
    assert "prior.bank" not in state and "prior.bank_sums" not in state  # made again, as the hulls
    again = SVRNet(enc, dec, ref, local=local, prior=ShapePrior(objects=5, side=side, neighbours=1)).eval()
    assert again.prior.hulls.sum() == 0
    again.load_state_dict(state)
    assert torch.equal(again.prior.hulls, net.prior.hulls) and net.prior.hulls.sum() > 0
    assert torch.equal(again.prior.bank, net.prior.bank) and net.prior.bank.sum() > 0


def test_model_pixel_prior_composes():
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose("train", overrides=["model=pixel_prior", "model.local.mirror_axis=0",
                                          "model.camera.elevation=false", "model.prior.objects=20",
                                          "model.prior.categories=2"])
    net = instantiate(cfg.model)
    assert isinstance(net.prior, ShapePrior) and net.local.prior and net.prior.side == 32
    assert net.prior.hulls.shape == (20, 32 ** 3)



def test_the_kept_bank_scores_as_the_stored_silhouettes_do():
    """The lookup compares against ``bank`` and ``bank_sums``, kept since the last ``rebuild``: the
    same soft IoU, to float precision, as the stored bytes converted on the spot."""
    from svr.nmr.metrics import silhouette_features, soft_silhouette_iou

    gen = torch.Generator().manual_seed(0)
    prior = ShapePrior(objects=40, side=8, neighbours=3)
    prior.silhouettes.copy_(torch.randint(0, 256, prior.silhouettes.shape, generator=gen, dtype=torch.uint8))
    prior.attach(grid_points(8))  # rebuilds: the silhouettes are set
    assert torch.equal(prior.bank, prior.silhouettes.float() / 255)
    alpha = torch.rand(6, 64, 64, generator=gen)
    views = torch.tensor([0, 0, 5, 11, 23, 5])
    q = silhouette_features(alpha)
    for v in views.unique().tolist():
        direct = soft_silhouette_iou(q, prior.silhouettes[v].float() / 255)
        torch.testing.assert_close(soft_silhouette_iou(q, prior.bank[v], prior.bank_sums[v]), direct)
    found = prior.nearest(alpha, views)
    expect = torch.stack([soft_silhouette_iou(q[i:i + 1], prior.silhouettes[int(v)].float() / 255)[0].topk(3).indices
                          for i, v in enumerate(views)])
    assert torch.equal(found, expect)
