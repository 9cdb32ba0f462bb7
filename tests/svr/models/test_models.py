"""svr.models: shapes, bounds, initial states, the paper-size config, the frozen stage, checkpoints
and bad input."""
from __future__ import annotations

import os

from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

import renderer
from svr.data.types import SVRBatch
from svr.inference.checkpoints import load_checkpoint, load_network
from svr.models import BlockRefiner, ImageEncoder, SDFDecoder, SDFRefiner, SVRNet, sphere_template
from svr.models.decoder import linear_upsample_matrix, upsample2_centres, upsample_grid
from svr.models.module import SVRLightningModule
from svr.models.refiner import fold_blocks, unfold_blocks

CONFIGS = str(Path(__file__).resolve().parents[3] / "configs")


def tiny_net(n: int = 16, refiner_stride: int = 2) -> SVRNet:
    return SVRNet(
        ImageEncoder(channels=(4, 8, 8, 8), latent_dim=16),
        SDFDecoder(latent_dim=16, base_resolution=4, channels=(8, 4), grid_resolution=n),
        SDFRefiner(channels=(4, 8), grid_resolution=n, input_stride=refiner_stride),
    )


def model_config(name: str) -> dict:
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose("train", overrides=[f"model={name}"])
    return cfg.model


def test_shapes_and_bounds():
    torch.manual_seed(0)
    net = tiny_net()
    images = torch.rand(3, 4, 64, 64)
    out = net(images)
    assert out.coarse.shape == out.refined.shape == (3, 16, 16, 16)
    assert out.final is out.refined
    assert net(images, refine=False).refined is None
    assert out.coarse.abs().max() < net.decoder.output_bound
    assert (out.refined - out.coarse).abs().max() < net.refiner.residual_bound
    assert net.voxel_size == pytest.approx(1.2 / 15)
    grid = net.grid(out.coarse)
    assert isinstance(grid, renderer.SDFGrid) and grid.bbox_max.tolist() == pytest.approx([0.6] * 3)


def test_untrained_decoder_outputs_the_template_sphere_and_refiner_the_identity():
    torch.manual_seed(0)
    net = tiny_net().eval()
    out = net(torch.rand(2, 4, 64, 64))
    b = net.decoder.output_bound
    template = b * torch.tanh(sphere_template(16, 0.6, 0.3) / b)
    assert (out.coarse - template).abs().max() < 0.02  # the head starts near zero
    assert torch.equal(out.refined, out.coarse)        # the refiner's head starts at zero


@pytest.mark.parametrize("stride", [1, 2])
def test_refiner_strides(stride):
    r = SDFRefiner(channels=(2, 4, 4), grid_resolution=16, input_stride=stride)
    torch.nn.init.normal_(r.head.weight, std=0.1)
    x = torch.randn(2, 16, 16, 16)
    y = r(x)
    assert y.shape == x.shape and not torch.equal(x, y)


def test_upsampling_matches_trilinear_interpolation():
    x = torch.randn(2, 5, 5, 5)
    fast = upsample_grid(x, linear_upsample_matrix(5, 9))
    ref = torch.nn.functional.interpolate(x[:, None], size=(9, 9, 9), mode="trilinear", align_corners=True)[:, 0]
    assert torch.allclose(fast, ref, atol=1e-6)


def test_cell_centred_upsampling_matches_trilinear_interpolation():
    x = torch.randn(2, 5, 5, 5, requires_grad=True)
    fast = upsample2_centres(x)
    ref = torch.nn.functional.interpolate(x[:, None], scale_factor=2, mode="trilinear", align_corners=False)[:, 0]
    assert fast.shape == (2, 10, 10, 10) and torch.allclose(fast, ref, atol=1e-6)
    g = torch.randn_like(fast)
    assert torch.allclose(torch.autograd.grad(fast, x, g)[0], torch.autograd.grad(ref, x, g)[0], atol=1e-5)
    small = torch.randn(1, 3, 3, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(upsample2_centres, (small,))


def test_decoder_head_stride_and_upsampling():
    torch.manual_seed(0)
    dec = SDFDecoder(latent_dim=8, base_resolution=2, channels=(8, 4), grid_resolution=16, head_stride=2,
                     upsampling="centres")
    assert isinstance(dec.head, torch.nn.ConvTranspose3d)
    out = dec(torch.randn(3, 8))
    assert out.shape == (3, 16, 16, 16) and out.abs().max() < dec.output_bound
    with pytest.raises(ValueError, match="head_stride"):
        SDFDecoder(head_stride=3)
    with pytest.raises(ValueError, match="upsampling"):
        SDFDecoder(upsampling="nearest")
    with pytest.raises(ValueError, match="power of two"):
        SDFDecoder(base_resolution=3, channels=(8, 4), grid_resolution=36, head_stride=2, upsampling="centres")


def test_block_folding_is_space_to_depth_and_invertible():
    grid = torch.arange(2 * 6 ** 3, dtype=torch.float32).reshape(2, 6, 6, 6)
    blocks = fold_blocks(grid)
    assert blocks.shape == (2, 8, 3, 3, 3)
    # voxel (2i+a, 2j+c, 2k+e) -> channel 4a + 2c + e at site (i, j, k)
    assert blocks[1, 4 * 1 + 2 * 0 + 1, 2, 0, 1] == grid[1, 5, 0, 3]
    assert torch.equal(unfold_blocks(blocks), grid)
    with pytest.raises(ValueError, match="even"):
        fold_blocks(torch.zeros(1, 5, 5, 5))
    with pytest.raises(ValueError, match="blocks"):
        unfold_blocks(torch.zeros(1, 4, 3, 3, 3))


def test_block_refiner_adds_a_bounded_residual_and_learns():
    torch.manual_seed(0)
    ref = BlockRefiner(channels=(4, 8), grid_resolution=16, residual_bound=0.05)
    x = torch.randn(2, 16, 16, 16) * 0.3
    assert torch.equal(ref(x), x)  # the zero head: identity before training
    torch.nn.init.normal_(ref.head.weight, std=1.0)
    y = ref(x)
    residual = y - x
    assert 0 < residual.abs().max() <= 0.05 + 1e-6
    # Every weight gets a gradient, and so does the input (the joint stage trains through it).
    x.requires_grad_(True)
    (ref(x) ** 2).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in ref.parameters())
    assert x.grad is not None and x.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="grid_resolution"):
        BlockRefiner(channels=(4, 8, 8), grid_resolution=20)


def test_paper_config_has_the_authors_size_and_small_trains_on_cpu():
    with torch.device("meta"):
        paper = instantiate(model_config("paper"))
    n_paper = sum(p.numel() for p in paper.parameters())
    assert 120e6 < n_paper < 200e6  # SPEC 4: about 160M parameters, mostly fully connected
    small = instantiate(model_config("small"))
    assert sum(p.numel() for p in small.parameters()) < 5e6
    assert small.grid_resolution == paper.grid_resolution == 64


def test_bad_arguments_name_the_argument():
    with pytest.raises(ValueError, match="image_size"):
        ImageEncoder(image_size=60, channels=(4, 4, 4))
    with pytest.raises(ValueError, match="channels"):
        ImageEncoder(channels=())
    with pytest.raises(ValueError, match="grid_resolution"):
        SDFDecoder(base_resolution=8, channels=(4, 4, 4, 4), grid_resolution=32)
    with pytest.raises(ValueError, match="template_radius"):
        SDFDecoder(template_radius=0.7, half_side=0.6)
    with pytest.raises(ValueError, match="grid_resolution"):
        SDFRefiner(channels=(2, 4, 4), grid_resolution=18)
    with pytest.raises(ValueError, match="input_stride"):
        SDFRefiner(input_stride=3)
    with pytest.raises(ValueError, match="half_side"):
        SVRNet(ImageEncoder(), SDFDecoder(half_side=0.5, template_radius=0.2), SDFRefiner(half_side=0.5),
               half_side=0.5)
    with pytest.raises(ValueError, match="decoder.half_side"):
        SVRNet(ImageEncoder(), SDFDecoder(half_side=0.7), SDFRefiner(), half_side=0.6)
    with pytest.raises(ValueError, match="images"):
        ImageEncoder()(torch.zeros(1, 3, 64, 64))
    with pytest.raises(ValueError, match="stage"):
        SVRLightningModule(tiny_net(), stage="fine")
    with pytest.raises(TypeError, match="net"):
        SVRLightningModule(torch.nn.Linear(2, 2))


# ------------------------------------------------------------------------------------------------
# stages


def fake_batch(b: int = 4, v: int = 2, n_views: int = 24) -> SVRBatch:
    g = torch.Generator().manual_seed(0)
    images = torch.zeros(b, v, 4, 64, 64)
    images[:, :, :, 20:44, 24:40] = 1.0  # a box silhouette, white object on a white background
    images[:, :, :3] = 1.0
    return SVRBatch(images=images, view_ids=torch.randint(0, n_views, (b, v), generator=g),
                    voxels=torch.zeros(b, 32, 32, 32, dtype=torch.bool), category=torch.zeros(b, dtype=torch.long),
                    object_index=torch.arange(b))


def _bn_state(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in module.state_dict().items()}


def test_refine_stage_freezes_encoder_and_decoder():
    torch.manual_seed(0)
    module = SVRLightningModule(tiny_net(), stage="refine", render_size=16)
    enc, dec, ref = module.net.encoder, module.net.decoder, module.net.refiner
    assert not any(p.requires_grad for p in list(enc.parameters()) + list(dec.parameters()))
    assert all(p.requires_grad for p in ref.parameters())
    module.train()  # as Lightning does: the frozen parts must stay in eval mode
    bns = [m for m in list(enc.modules()) + list(dec.modules()) if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    assert bns and all(not m.training for m in bns)
    assert all(m.training for m in ref.modules())
    before = {"enc": _bn_state(enc), "dec": _bn_state(dec), "ref": _bn_state(ref)}
    opt = torch.optim.Adam([p for p in module.parameters() if p.requires_grad], lr=1e-2)
    batch = fake_batch()
    for _ in range(3):
        sdf = module(batch.images[:, 0])
        loss = module.compute_loss(batch, sdf).total
        opt.zero_grad()
        loss.backward()
        opt.step()
    for name in ("enc", "dec"):
        after = _bn_state(getattr(module.net, {"enc": "encoder", "dec": "decoder"}[name]))
        for k, v in before[name].items():
            assert torch.equal(v, after[k]), f"{name}.{k} changed (weights or batch-norm statistics)"
    assert any(not torch.equal(v, _bn_state(ref)[k]) for k, v in before["ref"].items())


def test_coarse_stage_does_not_run_or_train_the_refiner():
    module = SVRLightningModule(tiny_net(), stage="coarse", render_size=16)
    coarse, refined = module.stage_sdf(torch.rand(2, 4, 64, 64))
    assert refined is None
    assert not any(p.requires_grad for p in module.net.refiner.parameters())
    assert all(p.requires_grad for p in module.net.encoder.parameters())
    joint = SVRLightningModule(tiny_net(), stage="joint")
    assert all(p.requires_grad for p in joint.parameters())


def test_voxel_supervised_stage_learns_without_rendering(monkeypatch):
    """The ladder's 3D-supervised row (configs/loss/voxels.yaml): its loss falls on a toy batch, and
    no step renders."""
    import svr.models.module as module_file
    from svr.nmr.voxels import nmr_voxel_centres
    from svr.losses import LossWeights

    def no_render(*args, **kwargs):
        raise AssertionError("the voxel-only loss rendered")

    monkeypatch.setattr(module_file, "image_loss", no_render)
    torch.manual_seed(0)
    module = SVRLightningModule(tiny_net(), stage="coarse",
                                loss_weights=LossWeights(silhouette=0.0, shading=0.0, voxel=1.0))
    batch = fake_batch()
    centres = nmr_voxel_centres(32)
    batch.voxels[:] = (centres.abs() < torch.tensor([0.4, 0.2, 0.3])).all(-1)  # a box, unlike the template
    opt = torch.optim.Adam([p for p in module.parameters() if p.requires_grad], lr=1e-2)
    losses = []
    for _ in range(30):
        terms = module.compute_loss(batch, module(batch.images[:, 0]))
        assert terms.silhouette is None and terms.voxel is not None
        opt.zero_grad()
        terms.total.backward()
        opt.step()
        losses.append(terms.voxel.item())
    assert losses[-1] < 0.9 * losses[0]  # measured: 0.493 -> 0.221 (kind iou: a box, from the sphere template)


def test_hull_term_is_in_the_stage_loss_and_falls_when_trained_on():
    """loss.weights.hull > 0: compute_loss adds the supervised views' hull term (weighted, at its
    stride), and a few steps on it alone (the silhouette weight near 0) lower it."""
    from svr.losses import LossWeights, hull_loss

    torch.manual_seed(0)
    weights = LossWeights(silhouette=1e-6, shading=0.0, hull=1.0, hull_tolerance=0.0, hull_stride=3, eikonal=0.0,
                          laplacian=0.0)
    module = SVRLightningModule(tiny_net(), stage="coarse", render_size=16, loss_weights=weights)
    batch = fake_batch()
    batch.images[:, :, 3] = 0.0
    batch.images[:, :, 3, 28:36, 28:36] = 1.0  # a small square: the initial sphere is far outside its hull
    opt = torch.optim.Adam([p for p in module.parameters() if p.requires_grad], lr=1e-2)
    losses = []
    for _ in range(15):
        sdf = module(batch.images[:, 0])
        terms = module.compute_loss(batch, sdf)
        expected = hull_loss(sdf, module.net.half_side, batch.images[:, :, 3], batch.view_ids, 2.0, 0.0, stride=3)
        assert terms.hull.item() == pytest.approx(expected.item(), rel=1e-5)
        assert terms.total.item() == pytest.approx((terms.hull + 1e-6 * terms.silhouette).item(), rel=1e-4)
        opt.zero_grad()
        terms.total.backward()
        opt.step()
        losses.append(terms.hull.item())
    assert losses[-1] < 0.7 * losses[0]  # measured: 0.235 -> 0.0


def test_checkpoint_round_trip_and_bad_files(tmp_path):
    import pytorch_lightning as pl

    cfg = model_config("tiny")
    from omegaconf import OmegaConf

    plain = OmegaConf.to_container(cfg, resolve=True)
    net = instantiate(plain)
    module = SVRLightningModule(net, stage="coarse", model_config=plain)
    trainer = pl.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, max_steps=0)
    trainer.strategy.connect(module)
    path = tmp_path / "m.ckpt"
    trainer.save_checkpoint(path)
    net2, meta = load_network(path)
    assert meta["stage"] == "coarse" and meta["grid_resolution"] == 32
    images = torch.rand(2, 4, 64, 64)
    net.eval()
    assert torch.equal(net(images).final, net2(images).final)

    (tmp_path / "junk.ckpt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.ckpt"):
        load_checkpoint(tmp_path / "junk.ckpt")
    (tmp_path / "random.ckpt").write_bytes(os.urandom(4096))
    with pytest.raises(ValueError, match="random.ckpt") as err:
        load_checkpoint(tmp_path / "random.ckpt")
    assert "weights_only" not in str(err.value)  # never the advice to load it unsafely
    torch.save({"state_dict": {}}, tmp_path / "other.ckpt")
    with pytest.raises(ValueError, match="other.ckpt"):
        load_checkpoint(tmp_path / "other.ckpt")
    with pytest.raises(FileNotFoundError, match="missing.ckpt"):
        load_checkpoint(tmp_path / "missing.ckpt")
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(ValueError, match="truncated.ckpt"):
        load_checkpoint(truncated)
