"""sdfcommon.tooling.commands: one error handling for every hydra entry point, no leftovers of a failed run,
config getters that name the key; sdfcommon below svr and mvr."""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from sdfcommon.tooling.commands import USAGE_ERROR, hydra_entry, user_message
from sdfcommon.tooling.serialization import load_torch, scrub_unsafe_advice

from .entry_points import expect_usage_error, files_under, run_entry

ROOT = Path(__file__).resolve().parents[1]

TOY_YAML = """\
_target_: tests.test_cli.ToySettings
out: ???
mode: ok
nothing_here_but_missing: null
hydra:
  run:
    dir: ${out}
  job:
    name: toy
    chdir: false
  help:
    app_name: toy-cmd
  callbacks:
    run_folder_guard:
      _target_: sdfcommon.tooling.commands.RunFolderGuard
"""


@dataclass(frozen=True)
class ToySettings:
    out: str
    mode: str
    nothing_here_but_missing: Optional[str] = None


def toy_task(cfg: ToySettings):
    """Fails as ``cfg.mode`` says, after writing what a run writes (settings, a result)."""
    out = Path(cfg.out)
    if cfg.mode == "results":
        (out / "result.txt").write_text("partial")
    if cfg.mode in ("user", "results"):
        (out / "settings.json").write_text(json.dumps({"new": True}))
        raise ValueError("the thing named in the message is wrong")
    if cfg.mode == "notes":
        (out / "notes.txt").write_text("about this run")
        raise ValueError("refused")
    if cfg.mode == "bug":
        raise RuntimeError("a bug")
    if cfg.mode == "exit":
        raise SystemExit(143)
    (out / "result.txt").write_text("done")
    return 1.0


@pytest.fixture
def toy(tmp_path):
    conf = tmp_path / "conf"
    conf.mkdir()
    (conf / "toy.yaml").write_text(TOY_YAML)
    return hydra_entry("toy", toy_task, str(conf))


def test_sdfcommon_imports_neither_svr_nor_mvr():
    code = ("import sys, sdfcommon, sdfcommon.tooling.commands, sdfcommon.tooling.checks, sdfcommon.tooling.serialization, sdfcommon.tooling.processes\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('svr', 'mvr')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_a_users_mistake_is_one_line_with_status_2_and_leaves_nothing(toy, tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    line = expect_usage_error(toy, [f"out={run}", "mode=user"], monkeypatch, capsys, "toy-cmd")
    assert line == "toy-cmd: error: the thing named in the message is wrong"
    assert not run.exists()  # .hydra, toy.log, settings.json and the folder itself are gone
    # A required setting left unset (???) is refused before anything is made.
    line = expect_usage_error(toy, [f"out={run}", "nothing_here_but_missing=???"], monkeypatch, capsys, "toy-cmd")
    assert "nothing_here_but_missing" in line and not run.exists()
    # So are an unknown key and a value of the wrong type.
    line = expect_usage_error(toy, [f"out={run}", "+nonsense=1"], monkeypatch, capsys)
    assert line == "toy-cmd: error: nonsense: unknown setting (ToySettings has: out, mode, nothing_here_but_missing)"
    line = expect_usage_error(toy, [f"out={run}", "mode=[1,2]"], monkeypatch, capsys)
    assert line == "toy-cmd: error: mode must be a string, got [1, 2]" and not run.exists()
    # Folders made to hold a new run folder go too (as outputs/infer/ would), not the ones before.
    expect_usage_error(toy, [f"out={tmp_path / 'outputs' / 'toy' / 'run'}", "mode=user"], monkeypatch, capsys)
    assert not (tmp_path / "outputs").exists() and tmp_path.is_dir()


def test_a_bug_keeps_its_traceback_and_system_exit_its_code(toy, tmp_path, monkeypatch, capsys):
    with pytest.raises(SystemExit) as stop:
        run_entry(toy, [f"out={tmp_path / 'bug'}", "mode=bug"], monkeypatch)
    err = capsys.readouterr().err
    assert stop.value.code == 1 and "RuntimeError: a bug" in err and "error: a bug" not in err
    with pytest.raises(SystemExit) as stop:
        run_entry(toy, [f"out={tmp_path / 'stopped'}", "mode=exit"], monkeypatch)
    assert stop.value.code == 143
    assert (tmp_path / "stopped" / ".hydra" / "config.yaml").is_file()  # a stopped run keeps its record


def test_what_existed_before_is_never_removed_nor_rewritten(toy, tmp_path, monkeypatch, capsys):
    run = tmp_path / "existing"
    (run / ".hydra").mkdir(parents=True)
    (run / ".hydra" / "config.yaml").write_text("out: old\nmode: ok\n")
    (run / "settings.json").write_text('{"old": true}')
    (run / "toy.log").write_text("an earlier run's line\n")
    (run / "result.txt").write_text("earlier results")
    before = files_under(run)
    expect_usage_error(toy, [f"out={run}", "mode=user"], monkeypatch, capsys)
    assert files_under(run) == before
    # A run that succeeds rewrites its record and keeps no empty log it made.
    run_entry(toy, [f"out={tmp_path / 'fine'}"], monkeypatch)
    assert sorted(files_under(tmp_path / "fine")) == [".hydra/config.yaml", ".hydra/hydra.yaml",
                                                      ".hydra/overrides.yaml", "result.txt"]


def test_a_failed_run_that_wrote_results_keeps_them(toy, tmp_path, monkeypatch, capsys):
    run = tmp_path / "partial"
    expect_usage_error(toy, [f"out={run}", "mode=results"], monkeypatch, capsys)
    assert (run / "result.txt").read_text() == "partial" and (run / ".hydra" / "config.yaml").is_file()


def test_an_entry_names_its_own_records(tmp_path, monkeypatch, capsys):
    conf = tmp_path / "conf"
    conf.mkdir()
    for records, kept in ((("notes.txt",), False), ((), True)):
        (conf / "toy.yaml").write_text(TOY_YAML + f"      records: {list(records)}\n")
        entry = hydra_entry("toy", toy_task, str(conf))
        run = tmp_path / f"run{len(records)}"
        expect_usage_error(entry, [f"out={run}", "mode=notes"], monkeypatch, capsys)
        assert run.exists() == kept


def test_an_unwritable_run_folder_is_one_line(toy, tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    line = expect_usage_error(toy, [f"out={blocker / 'run'}"], monkeypatch, capsys)
    assert str(blocker) in line and blocker.read_text() == "x"
    line = expect_usage_error(toy, ["out=${nope}"], monkeypatch, capsys)  # a run folder that cannot resolve
    assert line == "toy-cmd: error: hydra.run.dir: Interpolation key 'nope' not found"


@dataclass(frozen=True)
class Toy:
    lr: float = 0.1
    steps: int = 3
    sizes: tuple[int, ...] = (1, 2)

    def __post_init__(self):
        if not self.lr > 0:  # meets a string with "'>' not supported"
            raise ValueError("lr must be positive")


def test_instantiation_errors_are_unwrapped_and_named_by_key():
    from hydra.utils import instantiate

    cfg = OmegaConf.create({"toy": {"_target_": f"{__name__}.Toy", "lr": -1.0}})
    with pytest.raises(Exception) as err:
        instantiate(cfg.toy)
    assert user_message(err.value) == "toy: lr must be positive"
    cfg = OmegaConf.create({"toy": {"_target_": "no.such.Thing"}})
    with pytest.raises(Exception) as err:
        instantiate(cfg.toy)
    assert "no.such.Thing" in user_message(err.value) and "\n" not in user_message(err.value)
    assert user_message(RuntimeError("a bug")) is None
    assert user_message(FileNotFoundError(2, "No such file or directory", "/x/y.ckpt")) == \
        "/x/y.ckpt: No such file or directory"


def test_random_bytes_never_get_the_advice_to_load_unsafely(tmp_path):
    junk = tmp_path / "random.ckpt"
    junk.write_bytes(np.random.default_rng(0).bytes(300))
    with pytest.raises(Exception) as raw:
        torch.load(junk, weights_only=True)
    assert "weights_only" in str(raw.value)  # what torch itself says
    with pytest.raises(ValueError) as ours:
        load_torch(junk)
    assert "random.ckpt" in str(ours.value) and "weights_only" not in str(ours.value)
    assert "\n" not in str(ours.value)
    wrapped = f"x.ckpt: not a readable checkpoint (UnpicklingError: {raw.value})"
    assert "weights_only" not in scrub_unsafe_advice(wrapped) and scrub_unsafe_advice(wrapped).endswith(")")
    assert USAGE_ERROR == 2


@pytest.mark.parametrize("module, own, foreign", [
    ("svr.infer", ["ckpt_path:", "images:", "render_size:", "sdfdiff-infer"],
     ["stage", "trainer", "model:", "mvr/noise", "data:", "callbacks", "logger"]),
    ("svr.evaluate", ["ckpt_path:", "protocol_workers:", "data: nmr, procedural, procedural_bench", "sdfdiff-evaluate"],
     ["stage", "trainer", "model:", "mvr/noise", "callbacks", "logger"]),
    ("mvr.__main__", ["target:", "optim:", "mvr/noise: camera, image, none", "sdfdiff-mvr"],
     ["stage", "trainer", "model:", "data:", "callbacks", "logger"]),
])
def test_help_lists_the_commands_own_settings_only(module, own, foreign, monkeypatch, capsys):
    """Issue 17 item 17: ``sdfdiff-infer --help`` no longer lists training's and mvr's config groups."""
    import importlib

    main = importlib.import_module(module).main
    monkeypatch.setattr(sys, "argv", ["prog", "--help"])
    try:
        main()
    except SystemExit as stop:
        assert not stop.code
    text = capsys.readouterr().out
    for word in own:
        assert word in text, word
    for word in foreign:
        assert word not in text, word
