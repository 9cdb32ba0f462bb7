"""benchmarks.bench_train_step at toy size: every phase and stage step measured, the report tables;
benchmarks.training_curve on a hand-made run folder."""
from __future__ import annotations

import csv

import pytest

from benchmarks.bench_train_step import PHASES, STAGE_STEPS, compare_table, run_phases, table
from benchmarks.training_curve import main as curve_main
from benchmarks.training_curve import read_curve


def test_toy_step_benchmark_measures_every_phase(tmp_path):
    toy = [f"data.cache_dir={tmp_path / 'cache'}", "data.categories=[chair,mug]", "data.train=2", "data.val=1",
           "data.test=1", "data.batch_size=2", "data.supersample=1", "data.progress=false",
           "data.generation_workers=0", "model=tiny", "loss.render_size=16", "loss.trace.max_steps=32"]
    res = run_phases(toy, "cpu", repeats=1)
    assert set(res["phases"]) == set(PHASES) | set(STAGE_STEPS)
    for name, r in res["phases"].items():
        assert r["ms"] > 0, name
    for name in STAGE_STEPS:
        assert res["phases"][name]["images_per_s"] == pytest.approx(2 / (res["phases"][name]["ms"] / 1e3))
    assert res["batch"] == 2 and res["grid"] == 32 and res["render_size"] == 16
    text = table(res)
    assert all(f"| {name} |" in text for name in PHASES + STAGE_STEPS)
    slower = {**res, "phases": {k: {**v, "ms": 2 * v["ms"]} for k, v in res["phases"].items()}}
    assert "| 2.00x |" in compare_table(slower, res)


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
    curve_main([str(run), "--baseline", "retrieval=0.5", "--out", str(tmp_path / "c")])
    text = (tmp_path / "c.md").read_text()
    assert "| refine | 10 | 0.30 | 0.4500 | 0.4000 |" in text and "minus retrieval: -0.0500" in text
    assert (tmp_path / "c.png").stat().st_size > 0
    with pytest.raises(SystemExit):
        curve_main([str(run), "--baseline", "retrieval"])
