"""benchmarks.mvr_parameter_study: every setting of every study is a valid mvr configuration; one
study end to end at toy scale (``slow``)."""
from __future__ import annotations

import pytest

from benchmarks.mvr_parameter_study import _studies, run_study
from mvr import configure_runtime
from mvr.settings import compose_config, reconstruct_kwargs


def test_every_setting_composes_into_reconstruct_arguments(tmp_path):
    for study in _studies().values():
        for setting in study.settings:
            cfg = compose_config(["target=torus", f"out_dir={tmp_path}", *setting.overrides])
            assert reconstruct_kwargs(cfg)["schedule"] is not None, (study.name, setting.label)


@pytest.mark.slow
def test_study_end_to_end(tmp_path):
    """One parameter study at toy scale writes its table and plot."""
    configure_runtime(threads=1)
    md = run_study(_studies()["noise"], "torus", tmp_path / "work", tmp_path / "docs", passes=1)
    text = md.read_text()
    rows = [line.split("|")[1].strip().strip("*").split("*")[0] for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| noise") and "---" not in line]
    assert rows == ["none", "image", "camera"]  # a row's name is bold where it is on the Pareto front
    assert (tmp_path / "docs" / "mvr_noise.png").stat().st_size > 1000
