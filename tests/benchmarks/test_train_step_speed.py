"""benchmarks.train_step_speed at toy size: every phase and stage step measured, the report tables."""
from __future__ import annotations

import pytest

from benchmarks.train_step_speed import PHASES, STAGE_STEPS, compare_table, run_phases, table


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
