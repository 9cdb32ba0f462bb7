"""benchmarks.svr_depth_errors: the counts by hand, and the whole loop on a sphere whose 24 views
are rendered here: the exact prediction has no errors, a deeper one only hidden false positives."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from benchmarks.svr_depth_errors import depth_errors, main, object_counts, rates
from svr.models.decoder import sphere_template
from svr.nmr.format import NUM_VIEWS
from svr.nmr.side_views import render_silhouettes
from svr.nmr.views import view_cameras
from svr.nmr.voxels import sdf_at_voxel_centres

HALF_SIDE, N = 0.6, 32


def test_counts_and_rates_by_hand():
    truth = torch.zeros(4, 4, 4, dtype=torch.bool)
    truth[1:3, 1:3, 1:3] = True                       # 8 solid voxels
    cone = torch.zeros_like(truth)
    cone[1:3, 1:3, :] = True                          # the input view looks along z
    hull = cone.clone()
    hull[:, :, 3] = False                             # the other views carve the last layer
    occ = truth.clone()
    occ[1:3, 1:3, 3] = True                           # 4 hidden false positives, outside the hull
    occ[0, 0, 0] = True                               # 1 visible one
    occ[1, 1, 1] = False                              # 1 false negative inside the cone
    sil = torch.zeros(3, 2, 2, dtype=torch.bool)
    alpha = sil.clone()
    sil[0] = True
    alpha[0, 0] = True                                # input view: 4 predicted, 2 true
    sil[1:, 0, 0] = True
    alpha[1:, 0, 0] = True                            # side views: exact
    c = object_counts(occ, truth, cone, hull, sil, alpha)
    assert (c["truth"], c["fp_hidden"], c["fp_hidden_outside_hull"], c["fp_visible"], c["fn_inside"],
            c["fn_outside"]) == (8, 4, 4, 1, 1, 0)
    r = rates(c)
    assert r["fp_hidden"] == 0.5 and r["fp_visible"] == 0.125 and r["fn_inside"] == 0.125
    assert r["input_area"] == 2.0 and r["input_iou"] == 0.5 and r["side_area"] == 1.0 and r["side_iou"] == 1.0
    with pytest.raises(ValueError, match="hull"):
        object_counts(occ, truth, cone, hull[:3], sil, alpha)


class _SphereSplit:
    """One object: a sphere, its 24 NMR views' alpha (rendered here) and its voxels."""

    categories = [("00000000", "sphere")]

    def __init__(self, radius: float = 0.3):
        self.sdf = sphere_template(N, HALF_SIDE, radius)[None]
        sil = render_silhouettes(self.sdf, HALF_SIDE, torch.arange(NUM_VIEWS)[None])[0]
        self.images = np.zeros((NUM_VIEWS, 4, 64, 64), np.uint8)
        self.images[:, 3] = sil.numpy() * 255
        at, _ = sdf_at_voxel_centres(self.sdf, -HALF_SIDE, HALF_SIDE, 32)
        self.solid = at[0] < 0

    def __len__(self) -> int:
        return 1

    def images_uint8(self, index, views):
        return self.images[views]

    def voxels(self, index):
        return self.solid

    def category_of(self, index):
        return 0


def test_exact_and_deeper_predictions_of_a_sphere():
    split = _SphereSplit()
    exact = depth_errors(lambda image, view: split.sdf, split, HALF_SIDE, N, progress=False)["mean"]
    assert exact["fp_hidden"] == 0 and exact["fp_visible"] == 0 and exact["fn_inside"] == 0
    assert exact["input_iou"] == 1.0 and exact["side_iou"] == 1.0
    # Stretched 1.5x along view 0's line of sight: wrong only behind the input's outline.
    eye = view_cameras(torch.tensor([0.0]), 64).eye[0].float()
    d = eye / eye.norm()
    axis = torch.linspace(-HALF_SIDE, HALF_SIDE, N)
    p = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)
    along = (p @ d)[..., None]
    deep = ((p - along * d + along * d / 1.5).norm(dim=-1) - 0.3)[None]
    got = depth_errors(lambda image, view: deep, split, HALF_SIDE, N, progress=False)["mean"]
    assert got["fp_hidden"] > 0.4 and got["fp_hidden_outside_hull"] > 0.4  # 0.49 and 0.48 when written
    assert got["fp_visible"] < 0.02 and got["fn_inside"] == 0 and got["fn_outside"] == 0
    assert got["input_iou"] > 0.97 and got["side_area"] > 1.3 and got["side_iou"] < 0.75  # 0.99, 1.49, 0.67


def test_bad_arguments(tmp_path):
    with pytest.raises(SystemExit):
        main([str(tmp_path / "missing.ckpt")])
    ckpt = tmp_path / "a.ckpt"
    ckpt.write_bytes(b"")
    with pytest.raises(SystemExit):
        main([str(ckpt), "--every", "0"])
    with pytest.raises(SystemExit):
        main([str(ckpt), "--out", str(tmp_path / "t.txt")])
