"""svr.inference.framing_bank: training renders framed as photos are (as ``frame_image`` frames
them), a photo of one of them put back at that render's own framing, the record kept in a
checkpoint and read back by ``load_model``, and ``svr.infer``'s framing taken from it."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from svr.inference.framing import TRAINING_FRAMING, Framing, frame_image, measure_framing
from svr.inference.framing_bank import (BANK_SIDE, FramingBank, bank_features, build_framing_bank, frame_alphas,
                                        store_framing_bank, stored_framing_bank)
from svr.inference.prediction import load_model
from svr.inference.reconstruction import input_and_camera
from svr.nmr.format import NUM_VIEWS

from .test_framing import render
from .test_input_camera import pixel_checkpoint


def shapes(n: int, seed: int = 0) -> np.ndarray:
    """(n, 64, 64) uint8 alphas, anti-aliased: ellipses whose size and place go with their aspect
    (as an object's framing goes with its shape and view), wide ones large and low, tall ones small
    and high, each a little off (clear of the border)."""
    rng = np.random.default_rng(seed)
    k = 4
    x, y = np.meshgrid((np.arange(64 * k) + 0.5) / k, (np.arange(64 * k) + 0.5) / k)
    out = []
    for _ in range(n):
        t = rng.uniform(0, 1)
        cx, cy = 32 + rng.uniform(-1, 1), 26 + 10 * t + rng.uniform(-1, 1)
        rx, ry = 8 + 16 * t, 16 - 8 * t
        inside = ((x - cx) / rx) ** 2 + ((y - cy) / ry) ** 2 <= 1
        out.append(np.rint(inside.reshape(64, k, 64, k).mean(axis=(1, 3)) * 255).astype(np.uint8))
    return np.stack(out)


class Views:
    """A training split's ``silhouettes(view)``: (N, 64, 64) ``alphas`` as N / 24 objects' 24 views."""

    def __init__(self, alphas: np.ndarray) -> None:
        self.alphas = alphas.reshape(-1, NUM_VIEWS, *alphas.shape[1:])

    def __len__(self) -> int:
        return len(self.alphas)

    def silhouettes(self, view: int) -> np.ndarray:
        return self.alphas[:, view]


def test_renders_are_framed_as_frame_image_frames_a_photo():
    alphas = shapes(6)
    alphas[5, :, 0] = 255  # touches the border: left out
    framed, own, keep = frame_alphas(alphas)
    assert keep.tolist() == [0, 1, 2, 3, 4] and framed.shape == (5, 64, 64) and own.shape == (5, 3)
    for j, i in enumerate(keep):
        rgba = np.zeros((64, 64, 4), np.uint8)
        rgba[..., 3] = alphas[i]
        reference, _ = frame_image(rgba, "render.png", 64, TRAINING_FRAMING)
        assert np.abs(framed[j].numpy() - reference[..., 3] / 255.0).max() < 0.01
        f = measure_framing(alphas[i][None])
        assert own[j] == pytest.approx([f.extent, f.centre_x, f.centre_y])


def test_a_photo_of_a_training_render_gets_that_renders_framing():
    """A render in the bank, photographed larger and elsewhere, framed to the median as ``svr.infer``
    frames a photo: its nearest entry is itself, so its framing comes back; averaged over the 16
    nearest, it is closer than the median framing is."""
    bank = build_framing_bank(Views(shapes(120)))
    assert len(bank) == 120 and bank.silhouettes.shape == (120, BANK_SIDE ** 2)
    original = render()  # not among the ellipses: add it to the bank
    own = measure_framing(original[..., 3][None])
    framed, _, _ = frame_alphas(original[..., 3][None])
    bank = FramingBank(torch.cat([bank.silhouettes, bank_features(framed)]),
                       torch.cat([bank.framings, torch.tensor([[own.extent, own.centre_x, own.centre_y]])]))
    photo = render(3.3, (20, 41), (260, 250))
    median, _ = frame_image(photo, "photo.png", 64, TRAINING_FRAMING)
    found = bank.estimate(median[..., 3], neighbours=1)
    assert dataclasses.astuple(found) == pytest.approx(dataclasses.astuple(own), abs=1e-6)
    errors = []
    for alpha in shapes(20, seed=1):  # ellipses the bank has not seen, on a larger photo
        rgba = np.zeros((200, 200, 4), np.uint8)
        rgba[40:104, 60:124, 3] = alpha
        m, _ = frame_image(rgba, "photo.png", 64, TRAINING_FRAMING)
        truth = np.array(dataclasses.astuple(measure_framing(alpha[None])))
        errors.append((np.abs(np.array(dataclasses.astuple(bank.estimate(m[..., 3]))) - truth),
                       np.abs(np.array(dataclasses.astuple(TRAINING_FRAMING)) - truth)))
    bank_error, median_error = (np.mean([e[k] for e in errors], axis=0) for k in (0, 1))
    assert bank_error.sum() < 0.5 * median_error.sum()


def test_the_nearest_renders_vote_for_their_views():
    """A photo of a render in the bank gets its own view's vote from its nearest entry; the votes
    are a distribution over the 24 views; a bank stored without views votes for none."""
    alphas = shapes(4 * NUM_VIEWS, seed=2)
    bank = build_framing_bank(Views(alphas))
    assert bank.views.tolist() == [v for v in range(NUM_VIEWS) for _ in range(4)]  # each view's objects in turn
    view = 9
    rgba = np.zeros((200, 200, 4), np.uint8)
    rgba[70:134, 30:94, 3] = alphas.reshape(4, NUM_VIEWS, 64, 64)[2, view]  # object 2 seen from view 9
    median, _ = frame_image(rgba, "photo.png", 64, TRAINING_FRAMING)
    own = bank.view_votes(median[..., 3], neighbours=1)
    assert own.tolist() == [float(v == view) for v in range(NUM_VIEWS)]
    votes = bank.view_votes(median[..., 3])
    assert votes.shape == (NUM_VIEWS,) and float(votes.sum()) == pytest.approx(1.0) and float(votes.min()) >= 0
    assert float(votes[view]) > 0
    framing, looked = bank.look_up(median[..., 3])  # both from one pass over the bank
    assert framing == bank.estimate(median[..., 3]) and torch.equal(looked, votes)
    assert dataclasses.replace(bank, views=None).view_votes(median[..., 3]) is None
    assert dataclasses.replace(bank, views=None).look_up(median[..., 3])[1] is None
    with pytest.raises(ValueError, match="views must be"):
        dataclasses.replace(bank, views=torch.full((len(bank),), NUM_VIEWS))


def test_the_record_round_trips_and_a_bad_one_is_named():
    bank = build_framing_bank(Views(shapes(48)))
    back = FramingBank.from_record(bank.record())
    assert torch.equal(back.silhouettes, bank.silhouettes) and torch.equal(back.framings, bank.framings)
    assert back.framing == bank.framing and torch.equal(back.views, bank.views)
    older = {k: v for k, v in bank.record().items() if k != "views"}  # stored before the views were kept
    assert FramingBank.from_record(older).views is None
    assert bank.record()["silhouettes"].shape == (48, BANK_SIDE ** 2 // 8)  # bit-packed
    with pytest.raises(ValueError, match="ckpt.ckpt: framing bank: not a readable framing bank"):
        FramingBank.from_record({**bank.record(), "side": 16}, "ckpt.ckpt: framing bank")
    with pytest.raises(ValueError, match="not a readable framing bank"):
        FramingBank.from_record({"side": BANK_SIDE})
    with pytest.raises(ValueError, match="alpha must be"):
        bank_features(np.zeros((2, 32, 32), np.uint8))


def test_a_large_split_is_thinned_to_the_cap():
    views = Views(shapes(30 * NUM_VIEWS))
    assert len(build_framing_bank(views, max_renders=NUM_VIEWS * 10)) == 10 * NUM_VIEWS  # every 3rd object
    with pytest.raises(ValueError, match="max_renders"):
        build_framing_bank(views, max_renders=3)


def test_the_checkpoint_keeps_the_bank_and_infer_frames_by_it(tmp_path):
    ckpt = pixel_checkpoint(tmp_path)
    assert stored_framing_bank(ckpt) is None and load_model(ckpt, "cpu").framing_bank is None
    # Every render says the object's box is small and high in the frame: a photo framed by the bank
    # is framed so.
    bank = build_framing_bank(Views(shapes(48)))
    bank = FramingBank(bank.silhouettes, torch.tensor([[0.5, 0.45, 0.4]]).expand(len(bank), 3).clone())
    store_framing_bank(ckpt, bank)
    model = load_model(ckpt, "cpu")
    assert model.framing_bank is not None and torch.equal(model.framing_bank.silhouettes, bank.silhouettes)
    photo = render(3.3, (20, 41), (260, 250))
    _, camera = input_and_camera(model, photo, "photo.png", None, True)
    assert dataclasses.astuple(camera.framing) == pytest.approx((0.5, 0.45, 0.4), abs=1e-6)
    assert camera.framing_source == "framing bank" and camera.record()["framing_source"] == "framing bank"
    _, without = input_and_camera(dataclasses.replace(model, framing_bank=None), photo, "photo.png", None, True)
    assert dataclasses.astuple(without.framing) != pytest.approx((0.5, 0.45, 0.4), abs=1e-3)  # the head's
    assert isinstance(without.framing, Framing) and without.framing_source == "camera head"
    # The bank's renders all vote for one view, which the untrained head rates like any other: the
    # estimate follows them; a bank without views leaves the head's estimate alone, and so does a
    # camera that is given.
    head_view = round(without.view) % NUM_VIEWS
    voted = (head_view + 12) % NUM_VIEWS
    votes_for = dataclasses.replace(bank, views=torch.full((len(bank),), voted))
    _, camera = input_and_camera(dataclasses.replace(model, framing_bank=votes_for), photo, "photo.png", None, True)
    assert abs(camera.view - voted) < 1.0
    _, camera = input_and_camera(dataclasses.replace(model, framing_bank=dataclasses.replace(bank, views=None)),
                                 photo, "photo.png", None, True)
    assert camera.view == without.view
    _, camera = input_and_camera(dataclasses.replace(model, framing_bank=votes_for), photo, "photo.png", 5.0, True)
    assert camera.view == 5.0


@pytest.mark.cuda
def test_a_checkpoint_loaded_onto_the_gpu_reads_its_bank(tmp_path):
    """load_model maps the checkpoint onto the GPU, the bank's record with it; the bank is read on
    the host (a GPU demo stopped here: a CUDA tensor cannot become a numpy array)."""
    ckpt = pixel_checkpoint(tmp_path)
    bank = build_framing_bank(Views(shapes(48)))
    store_framing_bank(ckpt, bank)
    model = load_model(ckpt, "cuda")
    assert torch.equal(model.framing_bank.silhouettes, bank.silhouettes)
    assert torch.equal(model.framing_bank.framings, bank.framings)


def test_scoring_banks_the_checkpoints_that_have_a_camera_head_once(tmp_path, capsys):
    from svr.scoring import bank_checkpoints

    class Data:  # what bank_checkpoints reads of a data module
        prepared: list = []

        def prepare_split(self, split, progress=True):
            self.prepared.append(split)

        def dataset(self, split):
            return Views(shapes(48))

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    with_head = pixel_checkpoint(tmp_path / "a")
    without = pixel_checkpoint(tmp_path / "b", "model.camera=null")
    assert bank_checkpoints([with_head, without, with_head], Data()) == 48
    assert "stored a framing bank of 48 training renders in 1 checkpoint(s)" in capsys.readouterr().out
    assert len(stored_framing_bank(with_head)) == 48 and stored_framing_bank(without) is None
    assert Data.prepared == ["train"]
    stamp = with_head.stat().st_mtime_ns
    assert bank_checkpoints([with_head, without], Data()) is None  # kept, not rebuilt
    assert with_head.stat().st_mtime_ns == stamp
    # A bank stored before banks kept their renders' views is replaced by one that has them.
    store_framing_bank(with_head, dataclasses.replace(stored_framing_bank(with_head), views=None))
    assert stored_framing_bank(with_head).views is None
    assert bank_checkpoints([with_head], Data()) == 48 and stored_framing_bank(with_head).views is not None


def test_a_split_whose_silhouettes_all_touch_the_border_gets_no_bank(tmp_path, capsys):
    from svr.scoring import bank_checkpoints

    alphas = shapes(NUM_VIEWS)
    alphas[:, :, 0] = 255
    framed, own, keep = frame_alphas(alphas)
    assert framed.shape == (0, 64, 64) and own.shape == (0, 3) and len(keep) == 0
    with pytest.raises(ValueError, match="at least one render"):
        build_framing_bank(Views(alphas))

    class Data:
        def prepare_split(self, split, progress=True):
            pass

        def dataset(self, split):
            return Views(alphas)

    ckpt = pixel_checkpoint(tmp_path)
    assert bank_checkpoints([ckpt], Data()) is None and stored_framing_bank(ckpt) is None
    assert "no framing bank stored" in capsys.readouterr().out
