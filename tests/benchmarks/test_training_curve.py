"""benchmarks.training_curve on a hand-made run folder: stages and resumed parts joined in order."""
from __future__ import annotations

import csv

import pytest

from benchmarks.training_curve import main as curve_main
from benchmarks.training_curve import read_curve


def _write_metrics(path, rows):
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, ["step", "train/total", "val/iou", "val/iou_coarse", "val/train_seconds"])
        w.writeheader()
        for r in rows:
            w.writerow(r)


def test_training_curve_joins_stages_and_resumed_parts(tmp_path):
    run = tmp_path / "run"
    _write_metrics(run / "coarse" / "csv" / "metrics.1.csv",
                   [{"step": 9, "train/total": 1.0}, {"step": 10, "val/iou": 0.3, "val/iou_coarse": 0.3,
                                                      "val/train_seconds": 360}])
    _write_metrics(run / "coarse" / "csv" / "metrics.csv",
                   [{"step": 20, "val/iou": 0.4, "val/iou_coarse": 0.4, "val/train_seconds": 720}])
    _write_metrics(run / "refine" / "csv" / "metrics.csv",
                   [{"step": 10, "val/iou": 0.45, "val/iou_coarse": 0.4, "val/train_seconds": 360}])
    rows = read_curve(run)
    assert [(r["stage"], r["step"]) for r in rows] == [("coarse", 10), ("coarse", 20), ("refine", 10)]
    assert [r["hours"] for r in rows] == pytest.approx([0.1, 0.2, 0.3])  # stages add up
    curve_main([str(run), "--baseline", "retrieval=0.5", "--final", "test IoU=0.56", "--out", str(tmp_path / "c")])
    text = (tmp_path / "c.md").read_text()
    assert "| refine | 10 | 0.30 | 0.4500 | 0.4000 |" in text and "minus retrieval: -0.0500" in text
    assert "- test IoU (the finished run): 0.5600; minus retrieval: +0.0600" in text
    assert (tmp_path / "c.png").stat().st_size > 0
    with pytest.raises(SystemExit):
        curve_main([str(run), "--baseline", "retrieval"])
