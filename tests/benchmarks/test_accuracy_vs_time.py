"""The accuracy-versus-time study (benchmarks/accuracy_vs_time*.py): its helpers and its driver (each
part a command of its own), and under `slow` every part's code path at toy size through the driver (no
timing asserted) and the full study."""
from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest

from benchmarks import accuracy_vs_time, accuracy_vs_time_renderer, accuracy_vs_time_svr
from benchmarks.common import (Point, cheapest_within, fmt_value, markdown_table, pareto_front, parse_steps, reading,
                               run_study_part)


def test_pareto_front():
    pts = [Point("a", 1.0, 5.0), Point("b", 2.0, 2.0), Point("c", 3.0, 3.0), Point("d", 4.0, 1.0),
           Point("e", 2.0, 2.0)]
    assert pareto_front(pts) == [True, True, False, True, True]
    table = markdown_table(pts, [("time", "seconds"), ("error", "error")])
    assert table.count("\n") == len(pts) + 1 and "| c | 3 | 3 |  |" in table
    assert fmt_value((0.25, 0.3125)) == "[0.25, 0.3125]" and fmt_value((1, 2)) == "(1, 2)"


def test_reading_names_the_front_the_cheap_choice_and_the_default():
    pts = [Point("fast", 1.0, 10.0), Point("good", 2.0, 1.05), Point("best", 8.0, 1.0),
           Point("dflt", 4.0, 2.0, default=True), Point("broken", 0.5, math.nan)]
    best, good = cheapest_within(pts, 0.1)
    assert (best.label, good.label) == ("best", "good")
    text = reading(pts, "s", "error")
    assert "fast (1 s, 10), good (2 s, 1.05), best (8 s, 1)" in text
    assert "good comes within 10% of the lowest error" in text
    assert "The default (dflt) is not on the front: good" in text
    assert "broken" not in text
    assert "is on the front" in reading([Point("x", 1.0, 1.0, default=True)])
    with pytest.raises(ValueError, match="tolerance"):
        reading(pts, tolerance=-1)
    with pytest.raises(ValueError, match="points"):
        cheapest_within([Point("n", 1.0, math.nan)])


def test_bad_arguments_name_themselves():
    assert accuracy_vs_time.parse_parts("svr, renderer") == ("renderer", "svr")
    for bad in ("", "renderer,gpu"):
        with pytest.raises(ValueError, match="parts"):
            accuracy_vs_time.parse_parts(bad)
    assert parse_steps("30,10") == (30, 10) and parse_steps(None) is None
    for bad in ("30", "a,b", "0,5"):
        with pytest.raises(ValueError, match="steps"):
            parse_steps(bad)
    with pytest.raises(ValueError, match="views"):
        accuracy_vs_time_svr.Run("x", views=25)
    with pytest.raises(ValueError, match="render_size"):
        accuracy_vs_time_svr.Run("x", render_size=128)
    with pytest.raises(ValueError, match="head"):
        accuracy_vs_time_svr.Run("x", head=16)
    with pytest.raises(ValueError, match="reps"):
        accuracy_vs_time_renderer.Renderer("cpu", "auto", reference_grid=16, reps=0)


def test_study_runs_vary_one_setting_each():
    runs = accuracy_vs_time_svr.runs()
    default = next(r for r in runs if r.default)
    fields = ("model", "views", "render_size", "head", "coarse_only")
    for r in runs:
        changed = [f for f in fields if getattr(r, f) != getattr(default, f)]
        assert len(changed) == (0 if r is default else 1), (r.label, changed)
    assert {r.axis for r in runs} == {"default", "refiner", "model", "views", "render size", "head"}
    h64 = next(r for r in runs if r.head == 64)
    overrides = accuracy_vs_time_svr.run_overrides(h64, [], (2, 2), 2, accuracy_vs_time_svr.Path("c"), False)
    assert "model.decoder.channels=[64,32,16,8]" in overrides and "loss.render_size=64" in overrides


def test_object_scores_average_categories_and_compare_by_interval():
    scores = accuracy_vs_time_svr.ObjectScores(np.array([0, 0, 1]), np.array([0.2, 0.4, 0.9]))
    mean, (lo, hi) = scores.benchmark_mean()
    assert mean == pytest.approx(0.6) and lo <= mean <= hi  # (0.3 + 0.9) / 2, not the objects' 0.5
    ref = Point("ref", 10.0, 0.4, default=True, extra={"iou": 0.6, "iou_interval": (0.5, 0.7)})
    near = Point("near", 5.0, 0.35, extra={"iou": 0.65, "iou_interval": (0.55, 0.75)})
    far = Point("far", 20.0, 0.1, extra={"iou": 0.9, "iou_interval": (0.8, 0.95)})
    assert "not resolved" in accuracy_vs_time_svr.compare(near, ref)
    assert "+0.300, higher, resolved" in accuracy_vs_time_svr.compare(far, ref) and "(2.00x the time)" in \
        accuracy_vs_time_svr.compare(far, ref)


def test_timeline_subtracts_the_validations(tmp_path):
    path = tmp_path / "timeline.jsonl"
    events = [{"event": "start", "stage": "coarse", "step": 0, "wall": 101.0, "cpu": 11.0},
              {"event": "val", "stage": "coarse", "step": 2, "wall": 105.0, "cpu": 14.0, "iou": 0.5,
               "val_wall": 2.0, "val_cpu": 1.0},
              {"event": "end", "stage": "coarse", "step": 4, "wall": 108.0, "cpu": 16.0}]
    path.write_text("".join(json.dumps(e) + "\n" for e in events))
    got = accuracy_vs_time_svr.read_timeline(path, start_wall=100.0, start_cpu=10.0)
    assert [e["train_cpu"] for e in got] == [1.0, 3.0, 5.0]
    assert [e["train_wall"] for e in got] == [1.0, 3.0, 6.0]


def test_the_driver_runs_each_part_as_a_command_and_assembles_their_sections(tmp_path, monkeypatch):
    """The driver runs each chosen part as ``python -m benchmarks.accuracy_vs_time_<part>`` with the
    study's options and builds the report from the sections the parts keep; a part not run says how
    to run it. The parts themselves are stood in for here (each part's own toy run is `slow`: the
    renderer's alone takes about 50 s, compiling its kernels in a fresh process)."""
    docs, work = tmp_path / "docs", tmp_path / "work"
    commands, real_run = [], subprocess.run

    def fake_part(cmd, *args, **kwargs):
        if not (len(cmd) > 2 and str(cmd[2]).startswith("benchmarks.accuracy_vs_time_")):
            return real_run(cmd, *args, **kwargs)  # e.g. the machine description's git call
        commands.append(cmd)
        part = cmd[2].rsplit("_", 1)[1]
        run_study_part(part, lambda: f"## {accuracy_vs_time.TITLES[part]}\n\nthe {part} section\n", work, True)

    monkeypatch.setattr(subprocess, "run", fake_part)
    path = accuracy_vs_time.run_parts(("renderer", "svr"), docs, work, quick=True, cuda=False, svr_steps=(3, 2),
                                      progress=False)
    assert [c[2] for c in commands] == ["benchmarks.accuracy_vs_time_renderer", "benchmarks.accuracy_vs_time_svr"]
    assert "--no-cuda" in commands[0] and "--quick" in commands[0] and "--no-progress" in commands[0]
    assert commands[1][-2:] == ["--steps", "3,2"] and "--no-cuda" not in commands[1]
    md = path.read_text()
    assert path == docs / accuracy_vs_time.REPORT and "`--quick` results" in md and "## Machine" in md
    assert "the renderer section" in md and "the svr section" in md
    assert "Not run yet: `python -m benchmarks.accuracy_vs_time --parts mvr`" in md
    assert not list(docs.glob("*.tmp")) and not list(docs.glob(".*.tmp"))


@pytest.mark.slow
def test_every_part_runs_at_toy_size_into_one_report(tmp_path):
    """All three parts at toy size, each a process of its own (about 75 s on 2 cores, so `slow`; the
    default suite checks the driver with the parts stood in for)."""
    docs, work = tmp_path / "docs", tmp_path / "work"
    path = accuracy_vs_time.run_parts(accuracy_vs_time.PARTS, docs, work, quick=True, cuda=False, progress=False)
    md = path.read_text()
    assert path == docs / accuracy_vs_time.REPORT and "`--quick` results" in md
    for heading in ("## Renderer", "## Multi-view reconstruction", "## Single-view reconstruction", "## Machine"):
        assert heading in md
    pngs = [f"study_renderer_{name}.png" for name in accuracy_vs_time_renderer.sweeps(True)] + ["study_mvr.png", "study_svr.png"]
    for png in pngs:
        assert (docs / png).stat().st_size > 1000 and f"({png})" in md
    assert md.count("(default)") >= len(pngs) and md.count("**What to choose.**") == len(pngs)
    assert "Exact against conservative" in md and "load average" in md and "not run" not in md
    # A point per stage of each training run: after the coarse stage and after the refine stage.
    svr_rows = [line for line in md.splitlines() if line.startswith(("| tiny ", "| **tiny "))]
    assert len(svr_rows) == sum(1 if r.coarse_only else 2 for r in accuracy_vs_time_svr.runs(True))
    # Each point's val IoU lies in its 95% interval (a column "[lo, hi]"), and the reading weighs them.
    assert "| val IoU | 95% interval |" in md and "validation objects" in md
    for line in svr_rows:
        cells = [c.strip() for c in line.strip("|").split("|")]
        iou, (lo, hi) = float(cells[1]), (float(x) for x in cells[2].strip("[]").split(","))
        assert 0.0 <= lo <= iou <= hi <= 1.0, line
    assert "resolved" in md
    assert not list(docs.glob("*.tmp")) and not list(docs.glob(".*.tmp"))

    # The report is rebuilt from the kept sections; a part never run says how to run it.
    (work / "sections" / "svr.md").unlink()
    accuracy_vs_time.main(["--report-only", "--docs", str(docs), "--work", str(work)])
    md = path.read_text()
    assert "## Renderer" in md and "Not run yet: `python -m benchmarks.accuracy_vs_time --parts svr`" in md


@pytest.mark.slow
def test_full_study(tmp_path):
    """The whole study as the report's command runs it (about 25 minutes on 2 cores)."""
    path = accuracy_vs_time.run_parts(accuracy_vs_time.PARTS, tmp_path / "docs", tmp_path / "work", cuda=False, progress=False)
    md = path.read_text()
    assert "`--quick` results" not in md and "not run" not in md
    assert "| **mvr.yaml** (default) |" in md and "| **small 2v +ref** (default) |" in md
