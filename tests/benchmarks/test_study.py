"""The accuracy-versus-time study's code paths at toy sizes (no timing asserted)."""
from __future__ import annotations

from benchmarks.report import Point, markdown_table, pareto_front
from benchmarks import study_renderer


def test_pareto_front():
    pts = [Point("a", 1.0, 5.0), Point("b", 2.0, 2.0), Point("c", 3.0, 3.0), Point("d", 4.0, 1.0),
           Point("e", 2.0, 2.0)]
    assert pareto_front(pts) == [True, True, False, True, True]
    table = markdown_table(pts, [("time", "seconds"), ("error", "error")])
    assert table.count("\n") == len(pts) + 1 and "| c | 3 | 3 |  |" in table


def test_renderer_study_runs_at_toy_size(tmp_path):
    md = study_renderer.run(tmp_path, quick=True, progress=False)
    for name in study_renderer.sweeps(True):
        assert (tmp_path / f"accuracy_vs_time_renderer_{name}.png").stat().st_size > 1000
        assert f"accuracy_vs_time_renderer_{name}.png" in md
    assert "(default)" in md and "exact" in md
