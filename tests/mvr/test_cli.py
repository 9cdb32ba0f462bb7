"""``python -m mvr``: a user's mistake is one line with exit status 2 (issue 17 items 7 and 9), and a
refused run leaves out_dir as it was (item 8); every setting is checked before any work, --help names
the shapes and groups, and a stopped run says in one line how to resume (issue 40)."""
from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from mvr.__main__ import main

# The module (the package's name ``mvr.reconstruct`` is the function).
RECONSTRUCT_MODULE = importlib.import_module("mvr.reconstruct")

from ..entry_points import expect_usage_error, files_under, run_entry

# No process-wide runtime changes in the test process; tiny settings in case a run gets far.
RUNTIME = ["runtime.threads=null", "runtime.tune_malloc=false", "runtime.flush_denormal=false", "progress=false"]
QUIET = [*RUNTIME, "schedule.resolutions=[8]", "optim.max_passes=1", "target_settings.mesh_resolution=48",
         "evaluation.samples=500"]


def refused(args: list[str], monkeypatch, capsys) -> str:
    return expect_usage_error(main, [*args, *QUIET], monkeypatch, capsys, "sdfdiff-mvr")


def test_bad_targets_and_settings_are_one_line_and_leave_nothing(tmp_path, monkeypatch, capsys):
    empty = tmp_path / "empty.obj"
    empty.write_bytes(b"")
    corrupt = tmp_path / "corrupt.stl"
    corrupt.write_bytes(np.random.default_rng(0).bytes(500))
    open_box = tmp_path / "open.ply"
    box = trimesh.creation.box()
    trimesh.Trimesh(box.vertices, box.faces[:-2]).export(open_box)
    folder = tmp_path / "meshes"
    folder.mkdir()
    cases = [(f"target={tmp_path / 'missing.obj'}", "missing.obj"),
             (f"target={empty}", "empty (0 bytes)"),
             (f"target={open_box}", "not watertight"),
             ("target=nosuchshape", "neither a built-in shape"),
             (f"target={corrupt}", "not a valid STL file"),
             (f"target={folder}", "is a folder"),
             ("optim.lr=fast", "optim.lr must be a number, got 'fast'"),
             ("schedule.levels=abc", "schedule.levels must be an integer, got 'abc'"),
             ("seed=x", "seed must be an integer, got 'x'")]
    for k, (override, message) in enumerate(cases):
        out = tmp_path / f"out{k}"
        args = ["target=sphere", f"out_dir={out}", override]
        line = refused(args, monkeypatch, capsys)
        assert message in line, (override, line)
        assert "No module named" not in line and "(none)" not in line and "'>'" not in line
        assert not out.exists(), (override, sorted(files_under(out)))


def test_a_scan_with_a_small_hole_goes_in_on_request(tmp_path, monkeypatch, capsys):
    """Issue 42 point 3: target_settings.max_hole_edges closes a mesh file's small holes, says how
    many boundary edges it closed and records them in metrics.json; without it the refusal names
    the setting and the value that would do."""
    open_box = tmp_path / "open.ply"
    box = trimesh.creation.box()
    trimesh.Trimesh(box.vertices, box.faces[:-2]).export(open_box)  # one square hole: 4 boundary edges
    line = refused([f"target={open_box}", f"out_dir={tmp_path / 'refused'}"], monkeypatch, capsys)
    assert "4 boundary edges" in line and "target_settings.max_hole_edges=4" in line
    out = tmp_path / "run"
    run_entry(main, [f"target={open_box}", f"out_dir={out}", "target_settings.max_hole_edges=4", *QUIET],
              monkeypatch)
    said = capsys.readouterr()
    assert "closed holes with 4 boundary edges" in said.out + said.err  # hydra's log handler: stdout
    assert json.loads((out / "metrics.json").read_text())["target_holes_closed"] == 4


@pytest.mark.parametrize("override, message", [("+nonsense=1", "nonsense: unknown setting"),
                                               ("+optim.nope=1", "optim.nope: unknown setting"),
                                               ("resume=sometimes", "resume must be"),
                                               ("backend=3", "backend must be a string, got 3")])
def test_a_bad_key_or_value_fails_before_any_folder(override, message, tmp_path, monkeypatch, capsys):
    """Checked when the settings are built, before out_dir (given or the default under
    paths.output_dir) is made."""
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    out = tmp_path / "out"
    assert message in refused(["target=sphere", f"out_dir={out}", override], monkeypatch, capsys)
    assert message in refused(["target=sphere", override], monkeypatch, capsys)
    assert not out.exists() and list(cwd.iterdir()) == []


def _previous_run(out: Path, checkpoint) -> dict[str, bytes]:
    """An out_dir as a finished run leaves it: hydra's record, settings, a log, results, a level checkpoint."""
    (out / ".hydra").mkdir(parents=True)
    (out / ".hydra" / "config.yaml").write_text("target: sphere\noptim:\n  lr: 0.05\n")
    (out / ".hydra" / "overrides.yaml").write_text("- target=sphere\n")
    (out / "settings.json").write_text('{"fingerprint": "earlier"}')
    (out / "mvr.log").write_text("[earlier] wrote it\n")
    (out / "metrics.json").write_text('{"hausdorff_rel": 0.05}')
    (out / "checkpoints").mkdir()
    if isinstance(checkpoint, bytes):
        (out / "checkpoints" / "level_00.pt").write_bytes(checkpoint)
    else:
        torch.save(checkpoint, out / "checkpoints" / "level_00.pt")
    return files_under(out)


def test_a_refused_rerun_leaves_out_dir_as_it_was(tmp_path, monkeypatch, capsys):
    """Item 8: a rerun with other settings is refused without rewriting out_dir/.hydra (or anything)."""
    out = tmp_path / "run"
    before = _previous_run(out, {"fingerprint": "0123456789abcdef", "level": 0, "values": torch.zeros(1, 8, 8, 8),
                                 "bbox_min": torch.full((3,), -1.0), "bbox_max": torch.ones(3), "reports": []})
    line = refused(["target=sphere", f"out_dir={out}", "optim.lr=0.5"], monkeypatch, capsys)
    assert "other settings" in line and "resume=false" in line
    assert files_under(out) == before


@pytest.mark.parametrize("content", [b"", b"\x80\x02 not a checkpoint", np.random.default_rng(1).bytes(400)])
def test_a_corrupt_level_checkpoint_is_one_line(content, tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    before = _previous_run(out, content)
    line = refused(["target=sphere", f"out_dir={out}"], monkeypatch, capsys)
    assert "level_00.pt" in line and "resume=false" in line and "weights_only" not in line
    assert files_under(out) == before


# ------------------------------------------------------------------------------------------------
# Issue 40: every setting checked before any work (items 5, 13); --help (item 18); Ctrl+C and
# SIGTERM (item 16)


def _no_work(*args, **kwargs):
    raise AssertionError("the run started although its settings are refused")


@pytest.mark.parametrize("override, message", [
    ("seed=-1", "seed must be an integer in [0, 4294967295], got -1"),
    ("seed=4294967296", "seed must be an integer in [0, 4294967295]"),
    ("optim.max_passes=0", "optim.max_passes must be"),
    ("optim.max_passes=-5", "optim.max_passes must be"),
    ("optim.max_passes=[3,0]", "optim.max_passes must be"),
    ("optim.max_passes=[]", "optim.max_passes must be"),
    ("optim.max_seconds=-1", "optim.max_seconds must be"),
    ("scene.camera_light=-1", "scene.camera_light must be a finite number >= 0, got -1"),
    ("scene.ambient=-0.5", "scene.ambient must be a finite number >= 0"),
    ("target_settings.extent=0", "target_settings.extent must be a positive"),
    ("target_settings.normals=bumpy", "target_settings.normals must be one of"),
    ("target_settings.mesh_resolution=8", "target_settings.mesh_resolution must be an integer >= 16"),
    ("backend=bogus", "backend must be one of"),
])
def test_every_setting_is_refused_before_any_work(override, message, tmp_path, monkeypatch, capsys):
    """Items 5 and 13: a bad seed, pass limit, light or target setting is one line naming it, before
    the fit starts and before out_dir (given or the default) is made; the run never begins. (A bad
    target is refused when the run starts, before it writes anything: the test above.)"""
    monkeypatch.setattr("mvr.__main__.reconstruct", _no_work)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    out = tmp_path / "out"
    for args in (["target=sphere", f"out_dir={out}", override], ["target=sphere", override]):
        # Not QUIET: its own optim.max_passes and mesh_resolution would win over the override.
        line = expect_usage_error(main, [*RUNTIME, *args], monkeypatch, capsys, "sdfdiff-mvr")
        assert message in line, line
    assert not out.exists() and list(cwd.iterdir()) == []


def test_help_lists_the_shapes_and_both_groups(monkeypatch, capsys):
    """Item 18: --help names the built-in shapes and the mvr/noise and mvr/preset groups."""
    from mvr import SHAPES

    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:
        run_entry(main, ["--help"], monkeypatch)
    assert stop.value.code in (0, None)
    text = capsys.readouterr().out
    shapes = next(line for line in text.splitlines() if "sphere" in line and "torus" in line)
    assert all(name in shapes for name in SHAPES), shapes
    assert "mvr/preset: default, fine, paper" in text and "mvr/noise: camera, image, none" in text


def _stop_during(level_number: int, signum: int):
    """An ``optimise_level`` that stops the run as a signal would when level ``level_number`` (1-based)
    starts, and fits the others as usual."""
    import os
    import signal

    real = RECONSTRUCT_MODULE.optimise_level

    def fit(grid, losses, level, *args, **kwargs):
        if level + 1 == level_number:
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            os.kill(os.getpid(), signum)
            raise AssertionError("SIGTERM did not stop the run")
        return real(grid, losses, level, *args, **kwargs)

    return fit


def _stopped(args: list[str], monkeypatch, capsys) -> tuple[object, str]:
    """The exit status of ``main`` with ``args`` (or how it ended otherwise) and its stderr."""
    capsys.readouterr()
    try:
        run_entry(main, args, monkeypatch)
        code: object = "returned"
    except SystemExit as stop:
        code = stop.code
    except KeyboardInterrupt:  # not caught: pytest itself would stop
        code = "KeyboardInterrupt"
    return code, capsys.readouterr().err


@pytest.mark.parametrize("signame, status, said", [("SIGINT", 130, "Ctrl+C"), ("SIGTERM", 143, "SIGTERM")])
def test_a_stopped_run_says_so_in_one_line_and_a_rerun_resumes(signame, status, said, tmp_path, monkeypatch,
                                                                 capsys):
    """Item 16: Ctrl+C (SIGINT) or SIGTERM during a level is one line, no traceback, that names how
    to resume; exit status 130 / 143; the same command then resumes after the last finished level."""
    import signal

    def unhandled(*_):  # where mvr installs no handler, the test process must not die of the signal
        raise RuntimeError("SIGTERM reached the test's own handler")

    previous = signal.signal(signal.SIGTERM, unhandled)
    try:
        out = tmp_path / "run"
        args = ["target=sphere", f"out_dir={out}", *RUNTIME, "schedule.resolutions=[8,12]", "optim.max_passes=1",
                "target_settings.mesh_resolution=48", "evaluation.samples=500"]
        monkeypatch.setattr(RECONSTRUCT_MODULE, "optimise_level", _stop_during(2, getattr(signal, signame)))
        code, err = _stopped(args, monkeypatch, capsys)
        assert code == status, err[-3000:]
        assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1, err
        assert lines[0].startswith("sdfdiff-mvr: stopped by ") and said in lines[0], lines[0]
        # two levels, then the residual carve's refit (a stage of its own, on by default)
        assert "after level 1 of 3" in lines[0] and f"out_dir={out}" in lines[0] and "resume" in lines[0]
        assert signal.getsignal(signal.SIGTERM) is unhandled  # mvr's handler is gone again
        assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["level_01.pt"]
        monkeypatch.undo()  # the real optimise_level
        run_entry(main, args, monkeypatch)
        metrics = json.loads((out / "metrics.json").read_text())
        assert metrics["resumed_from_level"] == 1 and metrics["levels"] == 3
    finally:
        signal.signal(signal.SIGTERM, previous)
