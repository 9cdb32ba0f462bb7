"""benchmarks.accuracy_ladder: the bootstrap intervals (benchmarks.common) against hand computations,
and the ladder's table from per-object scores (the trained rows themselves: tests/svr/models/test_models.py)."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks.accuracy_ladder import (READS, ROWS, TRAINED, calibration_of, ladder, markdown_table, read_per_object,
                                       reading, reads_note)
from benchmarks.common import bootstrap_means


def test_constant_scores_give_zero_width_intervals():
    values = np.array([0.2, 0.2, 0.2, 0.6, 0.6])
    per_cat, overall = bootstrap_means(values, np.array([0, 0, 0, 1, 1]))
    assert per_cat[0] == pytest.approx((0.2, 0.2)) and per_cat[1] == pytest.approx((0.6, 0.6))
    assert overall == pytest.approx((0.4, 0.4))  # the mean of the category means, not of objects (0.36)


def test_interval_of_a_known_sample():
    # Category 0 holds 0 and 1: a resample's mean is 0, 0.5 or 1 with chances 1/4, 1/2, 1/4, so its
    # 2.5th and 97.5th percentiles are 0 and 1. With category 1 constant at 0.5 the mean over
    # categories is 0.25, 0.5 or 0.75 with the same chances.
    per_cat, overall = bootstrap_means(np.array([0.0, 1.0, 0.5]), np.array([0, 0, 1]), samples=4000)
    assert per_cat[0] == pytest.approx((0.0, 1.0))
    assert overall == pytest.approx((0.25, 0.75))


def test_bootstrap_rejects_mismatched_input():
    with pytest.raises(ValueError, match="values and category"):
        bootstrap_means(np.zeros(3), np.zeros(2))


def _objects(scale: float) -> dict:
    keys = [("chair", 0), ("chair", 1), ("table", 0)]
    return {k: {"iou_mean": scale * (i + 1) / 4, "iou_coarse_mean": 0.1, "iou_oracle_mean": 0.99,
                "iou_retrieval_mean": 0.5, "iou_category_mean_shape_mean": 0.3, "iou_mean_shape_mean": 0.2}
            for i, k in enumerate(keys)}


def test_ladder_rows_means_and_reading():
    lookup = {("chair", 0): 0.7, ("chair", 1): 0.8, ("table", 0): 0.6, ("table", 9): 0.1}  # table 9: not scored
    summary = ladder({"shipped": _objects(1.0), "voxels": _objects(1.2)}, lookup, ["chair", "table"])
    rows = summary["rows"]
    # every row but those of the runs and baselines not scored here (camera-free)
    assert list(rows) == [k for k in ROWS if k not in ("camera_free", "retrieval_any_view")] and summary["objects"] == 3
    # shipped: chair objects 0.25 and 0.5 -> 0.375; table 0.75; mean over categories 0.5625
    assert rows["shipped"]["categories"]["chair"]["iou"] == pytest.approx(0.375)
    assert rows["shipped"]["mean"] == pytest.approx(0.5625)
    assert rows["voxels"]["mean"] == pytest.approx(1.2 * 0.5625)
    assert rows["lookup"]["mean"] == pytest.approx((0.75 + 0.6) / 2)
    lo, hi = rows["shipped"]["interval"]
    assert lo <= rows["shipped"]["mean"] <= hi
    table = markdown_table(summary)
    assert "| shipped recipe (image losses, reads the camera) | 0.375 | 0.750 | **0.562**" in table
    text = reading(summary)
    assert "**+0.062**" in text  # shipped 0.5625 - retrieval 0.5
    assert "below the category mean shape: none" in text
    assert "does not yet measure" not in text  # the 3D row is above the shipped one here
    worse = ladder({"shipped": _objects(1.0), "voxels": _objects(0.5)}, lookup, ["chair", "table"])
    assert "does not yet measure" in reading(worse)


def test_side_views_column_for_the_trained_rows():
    shipped = _objects(1.0)
    for (name, _), row, side in zip(shipped, shipped.values(), (0.2, 0.4, 0.9)):
        row["side_iou_mean"] = side
    summary = ladder({"shipped": shipped}, {("chair", 0): 0.7, ("chair", 1): 0.8, ("table", 0): 0.6},
                     ["chair", "table"])
    side = summary["rows"]["shipped"]["side_views"]
    assert side["mean"] == pytest.approx((0.3 + 0.9) / 2)  # chair (0.2 + 0.4) / 2, table 0.9
    assert side["interval"][0] <= side["mean"] <= side["interval"][1]
    assert "side_views" not in summary["rows"]["retrieval"]  # that evaluation scored no baseline's side views
    table = markdown_table(summary)
    assert f"| {side['mean']:.3f} [" in table and table.count("|  |\n") == len(summary["rows"]) - 1
    # An evaluation that scored retrieval's side views too (side_iou_retrieval_mean) fills its row.
    for row, side in zip(shipped.values(), (0.1, 0.3, 0.5)):
        row["side_iou_retrieval_mean"] = side
    summary = ladder({"shipped": shipped}, {("chair", 0): 0.7, ("chair", 1): 0.8, ("table", 0): 0.6},
                     ["chair", "table"])
    assert summary["rows"]["retrieval"]["side_views"]["mean"] == pytest.approx((0.2 + 0.5) / 2)
    assert "side views, shipped recipe (image losses, reads the camera) - silhouette retrieval: **+0.250**" \
        in reading(summary)  # (0.3 + 0.9) / 2 - 0.35
    assert "side_views" not in summary["rows"]["category_mean_shape"]


def test_camera_free_rows():
    assert set(READS) == set(ROWS) and "model=small" in TRAINED["camera_free"]
    assert "calibrate_carving=false" in TRAINED["camera_free"]
    assert TRAINED["voxels"] == ("loss=voxels", "loss.weights.hull=0")  # the voxels alone supervise it
    lookup = {("chair", 0): 0.7, ("chair", 1): 0.8, ("table", 0): 0.6}
    shipped, camera_free = _objects(1.0), _objects(0.8)
    for row in camera_free.values():
        row["iou_retrieval_any_view_mean"] = 0.4
    # The shipped run was scored before the camera-free baseline existed: its column comes from the
    # camera-free run; a network's own score never comes from another run.
    summary = ladder({"shipped": shipped, "camera_free": camera_free}, lookup, ["chair", "table"])
    rows = summary["rows"]
    assert list(rows) == [k for k in ROWS if k != "voxels"]
    assert rows["camera_free"]["mean"] == pytest.approx(0.8 * 0.5625)
    assert rows["retrieval_any_view"]["mean"] == pytest.approx(0.4)
    text = reading(summary)
    assert f"**{0.5625 - 0.8 * 0.5625:+.3f}**: what reading the input camera" in text
    assert f"**{0.8 * 0.5625 - 0.4:+.3f}**: the image-only network's margin" in text
    note = reads_note(summary)
    assert "camera-free network (image only): nothing" in note and "silhouette retrieval: the input camera" in note
    assert "silhouette retrieval, any view: nothing" in note
    only_shipped = ladder({"shipped": shipped}, lookup, ["chair", "table"])["rows"]
    assert "camera_free" not in only_shipped and "retrieval_any_view" not in only_shipped


def test_ladder_without_the_voxel_row_and_with_disjoint_data():
    summary = ladder({"shipped": _objects(1.0)}, {("chair", 0): 0.7, ("chair", 1): 0.8, ("table", 0): 0.6},
                     ["chair", "table"])
    assert "voxels" not in summary["rows"] and "shipped" in summary["rows"]
    with pytest.raises(ValueError, match="same data"):
        ladder({"shipped": _objects(1.0)}, {("sofa", 0): 0.5}, ["chair", "table"])


def test_read_per_object(tmp_path):
    path = tmp_path / "per_object.csv"
    path.write_text("category_id,category,object_index,views,iou_mean,side_iou_mean,iou_oracle_mean\n"
                    "03001627,chair,4,24,0.5,0.4,0.99\n")
    assert read_per_object(path) == {("chair", 4): {"iou_mean": 0.5, "side_iou_mean": 0.4, "iou_oracle_mean": 0.99}}


def test_a_scored_row_is_reused_unless_rescore(tmp_path, monkeypatch):
    import benchmarks.accuracy_ladder as al

    calls = []
    monkeypatch.setattr(al.subprocess, "run", lambda cmd, **kw: calls.append(cmd))
    row = tmp_path / "shipped"
    row.mkdir()
    (row / "per_object.csv").write_text("category,object_index,iou_mean\nchair,0,0.5\n")
    assert al.train_row("shipped", "demo", tmp_path, [], quiet=True) == row  # no timings.json: not scored yet
    assert len(calls) == 1
    (row / "timings.json").write_text("{}")
    assert al.train_row("shipped", "demo", tmp_path, [], quiet=True) == row and len(calls) == 1  # reused
    al.train_row("shipped", "demo", tmp_path, ["seed=1"], quiet=True, rescore=True)
    assert len(calls) == 2 and "seed=1" in calls[1] and f"out={row}" in calls[1]


def test_calibration_of_a_scored_row(tmp_path):
    import json

    assert calibration_of(tmp_path) == "none"  # not scored yet
    (tmp_path / "iou.json").write_text(json.dumps({"mean": 0.5}))
    assert calibration_of(tmp_path) == "none"  # scored before calibration existed
    settings = {"carve": "view+mirror", "mirror_axis": 0, "level": 0.0095, "threshold": 0.5}
    (tmp_path / "iou.json").write_text(json.dumps({"calibration_search": {"joint": {"settings": settings},
                                                                   "coarse": {"settings": {**settings, "level": 0.1}}}}))
    # a record from before the cone had its own level carved with the level on both fields
    assert calibration_of(tmp_path) == "carve view+mirror (mirror axis x) (cone level +0.0095), level +0.0095"
    (tmp_path / "iou.json").write_text(json.dumps({"calibration_search": {"joint": {"settings": {
        **settings, "carve_level": 0.0}}}}))
    assert calibration_of(tmp_path) == "carve view+mirror (mirror axis x), level +0.0095"
