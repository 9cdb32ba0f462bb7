"""svr.evaluation.calibration_search: the search finding a known level, and the stored calibration
travelling with the checkpoint (applying a calibration: tests/svr/inference/test_calibration.py)."""
from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch

from svr.evaluation import calibration_search as search_module
from svr.evaluation.calibration_search import search_calibration, store_calibration, stored_calibration
from svr.inference.calibration import Calibration
from svr.inference.prediction import LoadedModel, load_model
from svr.models.checkpoint_layout import CHECKPOINT_KEY
from svr.models.network import SVRPrediction
from svr.nmr.metrics import voxels_protocol

from tests.svr.models.test_models import tiny_net


class _Spheres:
    """Objects for EvalViews: every object the same sphere, seen on a full silhouette."""

    def __init__(self, count: int, voxels: torch.Tensor):
        self.counts, self.offsets, self._voxels = [count], [0], voxels

    def locate(self, obj: int):
        return 0, obj

    def views(self, obj: int, views):
        return torch.ones(len(views), 4, 64, 64)

    def voxels(self, obj: int):
        return self._voxels


def _sphere(n: int, hs: float, radius: float) -> torch.Tensor:
    axis = torch.linspace(-hs, hs, n)
    p = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)
    return p.norm(dim=-1) - radius


def test_search_finds_the_level_that_undoes_an_overfill(monkeypatch):
    """The 'network' predicts the truth grown by one voxel: the search picks the level of one voxel,
    where the predictions score the truth's own IoU."""
    n, hs = 32, 0.6
    voxel = 2 * hs / (n - 1)
    truth = _sphere(n, hs, 0.3)
    gt = voxels_protocol(truth, -hs, hs)[0]
    model = LoadedModel(SimpleNamespace(half_side=hs, decoder=SimpleNamespace(grid_resolution=n), local=None))

    def grown(m, images, batch_size, views=None, clip=True, calibrated=True):
        assert not calibrated and not clip
        sdf = (truth - voxel).expand(len(images), n, n, n).clone()
        return SVRPrediction(coarse=sdf, refined=sdf)

    monkeypatch.setattr(search_module, "predict_sdf", grown)
    search = search_calibration(model, _Spheres(2, gt), views=(0, 7), progress=False)
    assert search.images == 4
    assert search.best.carve == "none" and search.best.level == pytest.approx(voxel, abs=1e-6)
    assert search.best_iou == pytest.approx(1.0) and search.uncalibrated_iou < 0.95
    assert [r["level_voxels"] for r in search.rows[:3]] == [0.0, 0.25, 0.5]
    # no carving, then the carving with the exact cone; the level moves the network's surface only
    assert [(r["carve"], r["carve_level_voxels"]) for r in search.rows[::7]] == [("none", 0.0), ("view", 0.0)]
    assert search.record()["carving"] is True
    # carving=False (the carvings read the input camera): the levels alone, the same best
    level_only = search_calibration(model, _Spheres(2, gt), views=(0, 7), carving=False, progress=False)
    assert {r["carve"] for r in level_only.rows} == {"none"} and len(level_only.rows) == 7
    assert level_only.best == search.best and level_only.record()["carving"] is False
    # the voxelisation in a worker process: the same scores
    pooled = search_calibration(model, _Spheres(2, gt), views=(0, 7), progress=False, workers=1)
    assert pooled.rows == search.rows and pooled.best == search.best
    with pytest.raises(ValueError, match="workers"):
        search_calibration(model, _Spheres(2, gt), views=(0, 7), progress=False, workers=-1)


def test_search_without_carving_never_carves(monkeypatch):
    """Where carving would win (the prediction fills the box, the silhouette does not), carving=False
    still chooses no carving."""
    n, hs = 32, 0.6
    truth = _sphere(n, hs, 0.3)
    gt = voxels_protocol(truth, -hs, hs)[0]
    model = LoadedModel(SimpleNamespace(half_side=hs, decoder=SimpleNamespace(grid_resolution=n), local=None))

    class _Disc(_Spheres):
        def views(self, obj: int, views):
            img = torch.ones(len(views), 4, 64, 64)
            yx = torch.stack(torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij"), -1)
            img[:, 3] = ((yx - 31.5).norm(dim=-1) < 12).float()
            return img

    def full(m, images, batch_size, views=None, clip=True, calibrated=True):
        sdf = torch.full((len(images), n, n, n), -0.1)
        return SVRPrediction(coarse=sdf, refined=sdf)

    monkeypatch.setattr(search_module, "predict_sdf", full)
    carved = search_calibration(model, _Disc(1, gt), views=(0,), levels_voxels=(0.0,), progress=False)
    assert carved.best.carve == "view"
    plain = search_calibration(model, _Disc(1, gt), views=(0,), levels_voxels=(0.0,), carving=False, progress=False)
    assert plain.best.carve == "none" and len(plain.rows) == 1


def test_stored_calibration_travels_with_the_checkpoint(tmp_path):
    torch.manual_seed(0)
    net = tiny_net()
    path = tmp_path / "net.ckpt"
    torch.save({"state_dict": {f"net.{k}": v for k, v in net.state_dict().items()},
                CHECKPOINT_KEY: {"stage": "joint", "model_config": _tiny_config()}}, path)
    assert stored_calibration(path) is None
    assert load_model(path, "cpu").calibration is None
    search = SimpleNamespace(record=lambda: {"settings": Calibration(level=0.02).to_dict(), "split": "val"})
    store_calibration(path, search)
    assert stored_calibration(path)["split"] == "val"
    assert load_model(path, "cpu").calibration == Calibration(level=0.02)


def _tiny_config() -> dict:
    return {
        "_target_": "svr.models.SVRNet",
        "encoder": {"_target_": "svr.models.ImageEncoder", "channels": [4, 8, 8, 8], "latent_dim": 16},
        "decoder": {"_target_": "svr.models.SDFDecoder", "latent_dim": 16, "base_resolution": 4, "channels": [8, 4],
                    "grid_resolution": 16},
        "refiner": {"_target_": "svr.models.SDFRefiner", "channels": [4, 8], "grid_resolution": 16,
                    "input_stride": 2},
    }


def test_a_stored_carving_is_searched_again_without_carving(monkeypatch, tmp_path):
    """svr.scoring.calibrate_checkpoint: a stored record is kept unless it carves where carving is
    not allowed; then the levels alone are searched and stored."""
    import svr.scoring as scoring

    stored = {"settings": Calibration(carve="view", level=0.01).to_dict(), "split": "val"}
    searched = []

    def search(model, objects, carving=True, progress=True, workers=0):
        searched.append(carving)
        return SimpleNamespace(record=lambda: {"settings": Calibration(level=0.02).to_dict(), "carving": carving},
                               seconds=0.0, best=Calibration(level=0.02), uncalibrated_iou=0.4, best_iou=0.5)

    monkeypatch.setattr(scoring, "stored_calibration", lambda path: stored)
    monkeypatch.setattr(scoring, "search_calibration", search)
    monkeypatch.setattr(scoring, "store_calibration", lambda path, s: path)
    monkeypatch.setattr(scoring, "load_model", lambda path, device: None)
    dm = SimpleNamespace(prepare_split=lambda split, progress=True: None, dataset=lambda split: None)
    assert scoring.calibrate_checkpoint(tmp_path / "x.ckpt", dm, progress=False) is stored and searched == []
    record = scoring.calibrate_checkpoint(tmp_path / "x.ckpt", dm, progress=False, carving=False)
    assert searched == [False] and record["settings"]["carve"] == "none"
    stored["settings"] = Calibration(level=0.03).to_dict()  # a level only: kept
    assert scoring.calibrate_checkpoint(tmp_path / "x.ckpt", dm, progress=False, carving=False) is stored
    assert searched == [False]
