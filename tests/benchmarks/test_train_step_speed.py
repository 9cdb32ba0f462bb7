"""benchmarks.train_step_speed at toy size: every phase and stage step measured, the report tables, and
(``slow``) ``--baseline`` against another checkout of this layout."""
from __future__ import annotations

import shutil

import pytest

from benchmarks.train_step_speed import PHASES, ROOT, STAGE_STEPS, compare_table, main, run_phases, table


def _toy(tmp_path) -> list[str]:
    return [f"data.cache_dir={tmp_path / 'cache'}", "data.categories=[chair,mug]", "data.train=2", "data.val=1",
            "data.test=1", "data.batch_size=2", "data.supersample=1", "data.progress=false",
            "data.generation_workers=0", "model=tiny", "loss.render_size=16", "loss.trace.max_steps=32"]


def test_toy_step_benchmark_measures_every_phase(tmp_path):
    res = run_phases(_toy(tmp_path), "cpu", repeats=1)
    assert set(res["phases"]) == (set(PHASES) - {"prior"}) | set(STAGE_STEPS)  # model=tiny has no prior
    for name, r in res["phases"].items():
        assert r["ms"] > 0, name
    for name in STAGE_STEPS:
        assert res["phases"][name]["images_per_s"] == pytest.approx(2 / (res["phases"][name]["ms"] / 1e3))
    assert res["batch"] == 2 and res["grid"] == 32 and res["render_size"] == 16
    text = table(res)
    assert all(f"| {name} |" in text for name in PHASES + STAGE_STEPS if name != "prior")
    slower = {**res, "phases": {k: {**v, "ms": 2 * v["ms"]} for k, v in res["phases"].items()}}
    assert "| 2.00x |" in compare_table(slower, res)


def test_pixel_head_with_mirror_axis_auto_is_built_as_training_builds_it(tmp_path):
    """model=pixel's mirror_axis "auto" (the demo's model) is measured on the training split, as
    the training command does, instead of failing in the network's constructor."""
    overrides = [o for o in _toy(tmp_path) if o != "model=tiny"] + ["model=pixel"]
    res = run_phases(overrides, "cpu", repeats=1, stages=False)
    assert set(res["phases"]) == set(PHASES) - {"prior"}


def test_the_shape_priors_lookup_is_a_phase_of_its_own(tmp_path):
    """model=pixel_prior: the prior is filled from the training split as training fills it, and its
    lookup for the batch is timed alone."""
    overrides = [o for o in _toy(tmp_path) if o != "model=tiny"] + ["model=pixel_prior"]
    res = run_phases(overrides, "cpu", repeats=1, stages=False)
    assert set(res["phases"]) == set(PHASES) and res["phases"]["prior"]["ms"] > 0
    assert "| prior |" in table(res)


@pytest.mark.slow
def test_baseline_measures_another_checkout_with_its_own_code_and_configs(tmp_path, capsys):
    """A copy of this checkout's packages and configs, one config default changed (2 -> 3 views per
    object), as the baseline: each checkout is measured in a process of its own, with its configs."""
    base = tmp_path / "before"
    for folder in ("renderer", "sdfcommon", "svr", "mvr", "benchmarks", "configs"):
        shutil.copytree(ROOT / folder, base / folder, ignore=shutil.ignore_patterns("__pycache__"))
    data = base / "configs" / "data" / "procedural.yaml"
    data.write_text(data.read_text().replace("views_per_sample: 2 ", "views_per_sample: 3 ", 1))
    main([*_toy(tmp_path), "--baseline", str(base), "--rounds", "1", "--repeats", "1", "--no-write"])
    out = capsys.readouterr().out
    assert f"Before: `{base}` (not a git checkout); batch 2, 3 views" in out
    assert "After: this checkout (" in out and "; batch 2, 2 views" in out
    assert all(f"| {name} |" in out for name in PHASES + STAGE_STEPS if name != "prior") and "x |" in out
