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


# ------------------------------------------------------------------------------------------------
# Issue 40 item 6: an override hydra cannot compose is one line with status 2, in every command

COMMANDS = {"svr.train": "sdfdiff-train", "svr.evaluate": "sdfdiff-evaluate", "svr.infer": "sdfdiff-infer",
            "svr.demo": "svr.demo", "mvr.__main__": "sdfdiff-mvr", "svr.data.build.__main__": "sdfdiff-build"}


def _main(module: str):
    import importlib

    return importlib.import_module(module).main


@pytest.mark.parametrize("module, args, expected", [
    ("svr.train", ["foo=1"], "foo: unknown setting (TrainSettings has: seed, ckpt_path, "),
    ("svr.train", ["model=bogus"], "model=bogus: no such option (model has: paper, pixel, pixel_prior, small, tiny)"),
    ("svr.train", ["mvr/noise=bogus"], "mvr/noise: sdfdiff-train has no config group mvr/noise (its groups: "),
    ("svr.evaluate", ["foo=1"], "foo: unknown setting (EvalSettings has: ckpt_path, split, "),
    ("svr.evaluate", ["data=bogus"], "data=bogus: no such option (data has: nmr, procedural, procedural_bench)"),
    ("svr.infer", ["foo=1"], "foo: unknown setting (InferSettings has: ckpt_path, images, "),
    ("svr.infer", ["model=bogus"], "model: sdfdiff-infer has no config group model (its groups: paths)"),
    ("svr.demo", ["foo=1"], "foo: unknown setting (DemoSettings has: "),
    ("svr.demo", ["model=bogus"], "model=bogus: no such option (model has: paper, pixel, pixel_prior, small, tiny)"),
    ("mvr.__main__", ["foo=1"], "foo: unknown setting (MVRSettings has: "),
    ("mvr.__main__", ["mvr/noise=bogus"], "mvr/noise=bogus: no such option (mvr/noise has: camera, image, none)"),
    ("svr.data.build.__main__", ["foo=1"], "foo: unknown setting (BuildSettings has: input, out, "),
    ("svr.data.build.__main__", ["hydra/launcher=bogus"], "hydra/launcher=bogus: no such option (hydra/launcher has: "),
])
def test_an_unknown_key_or_group_option_is_one_line_in_every_command(module, args, expected, tmp_path, monkeypatch,
                                                                     capsys):
    monkeypatch.chdir(tmp_path)
    line = expect_usage_error(_main(module), args, monkeypatch, capsys, COMMANDS[module])
    assert line.startswith(f"{COMMANDS[module]}: error: {expected}"), line
    assert list(tmp_path.iterdir()) == []  # refused before hydra made a folder or a log


def test_every_override_hydra_cannot_compose_is_named(toy, tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    for args, expected in (
            (["mode=[1,"], "cannot read the override 'mode=[1,': "),
            (["+mode=x"], "+mode=x: mode is in the config already: set it with mode=x"),
            (["~nope"], "~nope: nope is not in the config"),
            (["mode=a,b"], "Ambiguous value for argument 'mode=a,b': a list is key=[a,b], a string key='a,b', "
                           "a sweep needs --multirun"),
            (["mode.deeper=1"], "mode.deeper: mode is a value, not a group of settings"),
            (["hydra/launcher=bogus"], "hydra/launcher=bogus: no such option (hydra/launcher has: basic")):
        line = expect_usage_error(toy, [f"out={run}", *args], monkeypatch, capsys, "toy-cmd")
        assert line.startswith(f"toy-cmd: error: {expected}"), line
        assert not run.exists()


def test_every_value_of_a_sweep_is_composed_before_any_job_runs(toy, tmp_path, monkeypatch, capsys):
    line = expect_usage_error(toy, ["-m", f"out={tmp_path / 'sweep'}", "mode=ok,ok,ok", "hydra/launcher=basic,bogus"],
                              monkeypatch, capsys, "toy-cmd")
    assert "hydra/launcher=bogus: no such option" in line
    line = expect_usage_error(toy, ["-m", f"out={tmp_path / 'sweep'}", "mode=ok,fine", "nope=1,2"], monkeypatch, capsys)
    assert line == "toy-cmd: error: nope: unknown setting (ToySettings has: out, mode, nothing_here_but_missing)"
    assert not (tmp_path / "sweep").exists() and not (tmp_path / "multirun").exists()


# ------------------------------------------------------------------------------------------------
# Issue 40 item 18: --help shows each setting's comment from the YAML files


@pytest.mark.parametrize("module, setting, comment", [
    ("svr.train", "seed: 0", "# seeds weights, sampling and each stage"),
    ("svr.train", "    eikonal: 0.02", "# paper: lambda_1 = 0.02"),  # from the loss group's file
    ("svr.train", "data:", "# data=procedural"),
    ("svr.evaluate", "split: test", "# test (the benchmark's) | val | train"),
    ("svr.infer", "ckpt_path: ???", "# one of our checkpoints"),
    ("svr.demo", "quiet: false", "# true: no progress bars"),
    ("svr.demo", "  views_per_sample: 8", "# ours: 8 supervised views"),  # from experiment=demo
    ("mvr.__main__", "  start: 8", "# paper: 8^3 initial grid"),
    ("svr.data.build.__main__", "views: 24", "# SPEC 5 (NMR): 24 views"),
])
def test_help_shows_the_comments_of_the_settings(module, setting, comment, monkeypatch, capsys):
    with pytest.raises(SystemExit) as stop:
        run_entry(_main(module), ["--help"], monkeypatch)
    assert not stop.value.code
    lines = [line for line in capsys.readouterr().out.splitlines() if line.split("#", 1)[0].rstrip() == setting]
    assert lines and comment in lines[0], lines


def test_help_follows_the_command_line_and_keeps_continued_comments(tmp_path, monkeypatch, capsys):
    conf = tmp_path / "conf"
    (conf / "size").mkdir(parents=True)
    (conf / "toy.yaml").write_text(TOY_YAML.replace("mode: ok\n", "mode: ok        # ok | user | bug\n"
                                                    "                # (what the toy does)\n")
                                   .replace("_target_: tests", "defaults:\n  - _self_\n  - size: small\n_target_: tests")
                                   .replace("  help:\n", "  help:\n    template: 'toy help: $CONFIG'\n"))
    (conf / "size" / "small.yaml").write_text("side: 1    # the side\n")
    (conf / "size" / "big.yaml").write_text("# @package size\nside: 9    # a big side\n")
    entry = hydra_entry("toy", toy_task, str(conf))
    with pytest.raises(SystemExit):
        run_entry(entry, ["--help", "size=big"], monkeypatch)
    text = capsys.readouterr().out
    assert "toy help" in text and "mode: ok" in text and "# ok | user | bug" in text
    assert "# (what the toy does)" in text and "size:" in text and "# size=big" in text
    assert "side: 9" in text and "# a big side" in text and "# the side" not in text
    with pytest.raises(SystemExit) as stop:  # a bad override with --help is the same one line
        run_entry(entry, ["--help", "size=huge"], monkeypatch)
    assert stop.value.code == USAGE_ERROR and "size=huge: no such option" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------
# Issue 40 items 5 and 7: settings the machine cannot run, or out of range, are one line before work

needs_no_gpu = pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without a GPU")


@pytest.mark.parametrize("module, args, expected", [
    pytest.param("svr.train", ["trainer=gpu"], "trainer.accelerator='gpu' needs a CUDA GPU and torch sees none here: "
                 "train on the CPU with trainer=cpu", marks=needs_no_gpu),
    pytest.param("svr.train", ["experiment=paper_nmr", "data.root=nowhere"],
                 "trainer.accelerator='gpu' needs a CUDA GPU", marks=needs_no_gpu),
    pytest.param("svr.demo", ["trainer=gpu"], "trainer.accelerator='gpu' needs a CUDA GPU", marks=needs_no_gpu),
    pytest.param("svr.train", ["loss.backend=cuda"], "loss.backend 'cuda' cannot run here: torch sees no CUDA GPU",
                 marks=needs_no_gpu),
    pytest.param("svr.infer", ["ckpt_path=x.ckpt", "images=x.png", "backend=cuda"],
                 "backend 'cuda' cannot run here: torch sees no CUDA GPU", marks=needs_no_gpu),
    pytest.param("mvr.__main__", ["target=torus", "backend=cuda"], "backend", marks=needs_no_gpu),
    ("svr.train", ["stage.coarse.max_time=abc"], "stage.coarse.max_time must be a duration 'DD:HH:MM:SS'"),
    ("svr.train", ["stage.joint.max_time='00:00:00:00'"], "stage.joint.max_time must be a duration"),
    ("svr.train", ["seed=-1"], "seed must be an integer in [0, 4294967293], got -1"),
    ("svr.train", ["loss.render_size=100000"], "loss.render_size must divide the images' side 64 "
                                               "(1, 2, 4, 8, 16, 32, 64), got 100000"),
    ("svr.infer", ["ckpt_path=x.ckpt", "images=x.png", "render_size=100000"],
     "render_size must be at most 512 (the previews of a batch are rendered at once), got 100000"),
])
def test_a_setting_this_machine_cannot_run_is_one_line_before_any_work(module, args, expected, tmp_path, monkeypatch,
                                                                       capsys):
    monkeypatch.chdir(tmp_path)
    line = expect_usage_error(_main(module), args, monkeypatch, capsys, COMMANDS[module])
    assert line.startswith(f"{COMMANDS[module]}: error: {expected}"), line
    if module == "mvr.__main__":
        assert "cuda" in line, line
    assert list(tmp_path.iterdir()) == []  # refused before the run folder was made
