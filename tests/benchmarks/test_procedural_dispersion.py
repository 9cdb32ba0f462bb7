"""benchmarks.procedural_dispersion and the lookup ceiling it shares with the accuracy ladder
(benchmarks.common): figures known by construction on toy voxels, then the command on a toy dataset."""
from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks.common import bootstrap_interval, iou_matrix, lookup_ceiling
from benchmarks.procedural_dispersion import main, mean_pairwise_iou


def _boxes(n: int, size: int = 4) -> np.ndarray:
    """n disjoint boxes, one per object, along the first axis of a 32^3 grid."""
    out = np.zeros((n, 32, 32, 32), dtype=bool)
    for k in range(n):
        out[k, k * size:(k + 1) * size, 4:12, 4:12] = True
    return out


def test_identical_train_and_test_give_a_lookup_ceiling_of_one():
    vox = _boxes(5)
    assert np.allclose(lookup_ceiling(vox, vox[::-1]), 1.0)


def test_disjoint_boxes_give_a_lookup_ceiling_of_zero():
    vox = _boxes(6)
    assert np.allclose(lookup_ceiling(vox[:3], vox[3:]), 0.0)
    assert mean_pairwise_iou(vox) == 0.0


def test_iou_matrix_matches_a_hand_count():
    a = np.zeros((1, 32, 32, 32), dtype=bool)
    b = np.zeros((2, 32, 32, 32), dtype=bool)
    a[0, :2] = True             # 2048 cells
    b[0, 1:3] = True            # overlaps a in 1024 of 3072
    b[1, :2, :16] = True        # inside a: 1024 of 2048
    assert np.allclose(iou_matrix(a, b), [[1024 / 3072, 1024 / 2048]])
    # b[0] and b[1] share row 1 of b[1]'s half: 512 of 2048 + 1024 - 512 cells
    assert mean_pairwise_iou(np.concatenate([a, b])) == pytest.approx((1 / 3 + 1 / 2 + 512 / 2560) / 3)
    with pytest.raises(ValueError, match="at least 2 objects"):
        mean_pairwise_iou(a)


def test_bootstrap_interval_of_a_constant_has_zero_width_and_brackets_the_mean():
    assert bootstrap_interval(np.full(10, 0.7)) == pytest.approx((0.7, 0.7))
    values = np.random.default_rng(1).uniform(size=200)
    lo, hi = bootstrap_interval(values)
    assert lo < values.mean() < hi and hi - lo < 0.2


def test_probe_command_on_a_toy_dataset(tmp_path, capsys):
    stem = tmp_path / "out" / "disp"
    assert main(["--preset", "demo", "--categories", "chair", "mug", "--train", "3", "--test", "2",
                 "--oracle-objects", "1", "--cache-dir", str(tmp_path / "cache"), "--out", str(stem)]) == 0
    summary = json.loads(stem.with_suffix(".json").read_text())
    assert list(summary["categories"]) == ["chair", "mug"]
    for row in summary["categories"].values():
        assert 0.0 <= row["retrieval"] <= row["lookup"] <= 1.0  # retrieval is one of the lookups
        assert row["oracle"] >= 0.9 and 0.0 <= row["diversity"] <= 1.0
    text = stem.with_suffix(".md").read_text()
    assert "| chair |" in text and "lookup ceiling" in text and "disp.png" in text
    assert stem.with_suffix(".png").stat().st_size > 1000
