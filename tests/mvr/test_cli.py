"""``python -m mvr``: a user's mistake is one line with exit status 2 (issue 17 items 7 and 9), and a
refused run leaves out_dir as it was (item 8)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from mvr.__main__ import main

from ..entry_points import expect_usage_error, files_under

# No process-wide runtime changes in the test process; tiny settings in case a run gets far.
QUIET = ["runtime.threads=null", "runtime.tune_malloc=false", "runtime.flush_denormal=false", "progress=false",
         "schedule.resolutions=[8]", "optim.max_passes=1", "target_settings.mesh_resolution=48",
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
