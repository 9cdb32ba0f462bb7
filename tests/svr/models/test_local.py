"""svr.models.PixelAlignedHead: each cell reads the input image where it projects (checked against a
rendered silhouette), the untrained head changes nothing, and a network with one asks for views."""
from __future__ import annotations

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

import renderer
from svr.inference.prediction import LoadedModel, predict_sdf
from svr.models import ImageEncoder, PixelAlignedHead, SDFDecoder, SDFRefiner, SVRNet

from .test_models import CONFIGS


def sphere_silhouette(centre, radius: float, view: int) -> torch.Tensor:
    """(1, 4, 64, 64) RGBA image of a sphere seen from NMR view ``view`` (alpha: its silhouette)."""
    n = 48
    axis = torch.linspace(-0.6, 0.6, n)
    pts = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)
    sdf = (pts - torch.tensor(centre)).norm(dim=-1) - radius
    out = renderer.render(renderer.SDFGrid(sdf[None], -0.6, 0.6), renderer.Cameras.nmr([view]),
                          renderer.Scene(effects=("silhouette",)), backend="reference")
    alpha = out.silhouette.reshape(1, 1, 64, 64).float()
    return torch.cat([torch.ones(1, 3, 64, 64), alpha], 1)


def test_each_cell_reads_the_silhouette_where_it_projects():
    head = PixelAlignedHead(image_channels=(4,), volume_channels=2, hidden=4, head_stride=2)
    decoder = SDFDecoder(latent_dim=8, base_resolution=4, channels=(4, 2), grid_resolution=32, head_stride=2,
                         upsampling="centres")
    points = decoder.head_points  # (16, 16, 16, 3): the head's samples; cells are 8^3
    view = 5
    image = sphere_silhouette((0.3, 0.0, 0.0), 0.2, view)
    x = head.cell_inputs(torch.zeros(1, 2, 8, 8, 8), [image], torch.tensor([view]), points)
    # Columns: 2 features, 3 position, then 8 sub-samples x RGBA, so the alphas are 5 + 4k + 3.
    alpha = x[0, :, [5 + 4 * k + 3 for k in range(8)]]  # (512 cells, 8)
    sub = points.reshape(8, 2, 8, 2, 8, 2, 3).permute(0, 2, 4, 1, 3, 5, 6).reshape(512, 8, 3)
    eye = renderer.Cameras.nmr([view]).eye[0]
    d = sub.reshape(-1, 3) - eye
    d = d / d.norm(dim=-1, keepdim=True)
    c = torch.tensor([0.3, 0.0, 0.0])
    t = ((c - eye) * d).sum(-1)
    miss = ((eye + t[:, None] * d) - c).norm(dim=-1)  # distance from the sphere's centre to each ray
    expected = (miss < 0.2).float().reshape(512, 8)
    clear = ((miss - 0.2).abs() > 0.05).reshape(512, 8)  # away from the anti-aliased outline
    assert clear.sum() > 3000 and expected[clear].sum() > 50
    assert (alpha[clear] - expected[clear]).abs().max() < 0.2


def test_the_untrained_head_leaves_the_features_and_trains_them():
    torch.manual_seed(0)
    head = PixelAlignedHead(image_channels=(4, 8), volume_channels=3, hidden=5, head_stride=1)
    vol = torch.randn(2, 3, 4, 4, 4)
    axis = torch.linspace(-0.5, 0.5, 4)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)
    maps = [torch.rand(2, 4, 64, 64), torch.rand(2, 8, 32, 32, requires_grad=True)]
    out = head(vol, maps, torch.tensor([0, 7]), points)
    assert torch.equal(out, vol)
    out.sum().backward()
    assert head.out.weight.grad.abs().sum() > 0  # the zero layer learns first, the rest after
    with pytest.raises(ValueError, match="head_stride"):
        head(vol, maps, torch.tensor([0, 7]), torch.zeros(8, 8, 8, 3))
    with pytest.raises(ValueError, match="views"):
        head(vol, maps, torch.tensor([0]), points)


def test_the_first_layer_in_two_products_is_the_plain_one():
    """The head multiplies the inputs that need a gradient apart from those that do not (to spare the
    backward pass their input gradient): the same output and the same gradients as ``first`` on the
    concatenated ``cell_inputs``."""
    torch.manual_seed(0)
    head = PixelAlignedHead(image_channels=(4, 8, 6), volume_channels=3, hidden=7, head_stride=2, mirror_axis=0)
    torch.nn.init.normal_(head.out.weight)
    axis = torch.linspace(-0.5, 0.5, 8)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)
    images = torch.rand(2, 4, 64, 64)  # data: no gradient

    def run(split: bool):
        vol = torch.randn(2, 3, 4, 4, 4, generator=torch.Generator().manual_seed(1)).requires_grad_(True)
        maps = [images] + [torch.rand(2, c, r, r, generator=torch.Generator().manual_seed(c)).requires_grad_(True)
                           for c, r in ((8, 32), (6, 16))]
        head.zero_grad()
        if split:
            out = head(vol, maps, torch.tensor([0, 7]), points)
        else:
            h = torch.relu(head.first(head.cell_inputs(vol, maps, torch.tensor([0, 7]), points)))
            out = vol + head.out(h).reshape(2, 4, 4, 4, 3).permute(0, 4, 1, 2, 3)
        (out * torch.linspace(-1, 1, out.numel()).reshape(out.shape)).sum().backward()
        return out.detach(), vol.grad, [m.grad for m in maps[1:]], head.first.weight.grad.clone()

    (a, ga, ma, wa), (b, gb, mb, wb) = run(True), run(False)
    torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(ga, gb, rtol=1e-5, atol=1e-6)
    for x, y in zip(ma, mb):
        assert x.abs().sum() > 0
        torch.testing.assert_close(x, y, rtol=1e-5, atol=1e-6)
    assert wa[:, 3:].abs().sum() > 0  # the positions, image samples and depths learn too
    torch.testing.assert_close(wa, wb, rtol=1e-5, atol=1e-6)


def test_model_pixel_builds_trains_and_needs_views():
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose("train", overrides=["model=pixel", "model.local.mirror_axis=0", "model.camera.elevation=false"])
    net = instantiate(cfg.model)
    assert isinstance(net.local, PixelAlignedHead) and net.needs_views and net.local.mirror_axis == 0
    images = torch.rand(2, 4, 64, 64)
    with pytest.raises(ValueError, match="views"):
        net(images)
    with pytest.raises(ValueError, match="views"):
        predict_sdf(LoadedModel(net), images)
    torch.nn.init.normal_(net.local.out.weight, std=0.1)
    out = net(images, refine=False, views=torch.tensor([3, 17]))
    out.coarse.sum().backward()
    assert net.local.first.weight.grad.abs().sum() > 0
    assert net.encoder.convs[0].weight.grad.abs().sum() > 0
    # The views matter: the same image seen from another camera gives another shape.
    net.eval()
    with torch.no_grad():
        a = net(images[:1], refine=False, views=torch.tensor([3])).coarse
        b = net(images[:1], refine=False, views=torch.tensor([9])).coarse
    assert (a - b).abs().max() > 1e-4
    one = predict_sdf(LoadedModel(net), images, views=4, refine=False).coarse
    assert one.shape == (2, 64, 64, 64)


def test_mismatched_channels_are_refused():
    enc = ImageEncoder(channels=(4, 8), latent_dim=8)
    dec = SDFDecoder(latent_dim=8, base_resolution=4, channels=(8, 4), grid_resolution=16)
    ref = SDFRefiner(channels=(4, 8), grid_resolution=16, input_stride=2)
    with pytest.raises(ValueError, match="image_channels"):
        SVRNet(enc, dec, ref, local=PixelAlignedHead(image_channels=(4, 16), volume_channels=4))
    with pytest.raises(ValueError, match="volume_channels"):
        SVRNet(enc, dec, ref, local=PixelAlignedHead(image_channels=(4, 4), volume_channels=8))
