"""The training command on one's own data and settings (issue 40): an NMR-format run stopped by
SIGTERM resumes with the command the stop prints, finishes and is evaluated; a run that fails
before its first checkpoint leaves nothing that blocks a retry or a resume."""
from __future__ import annotations

import json
import shlex
import signal
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from sdfcommon.tooling.outputs import write_text
from sdfcommon.tooling.settings import build_settings, settings_record
from svr.evaluate import main as evaluate_main
from svr.inference.checkpoints import load_checkpoint
from svr.train import main as train_main
from svr.training.run_folder import RunFolder

from ...entry_points import expect_usage_error, run_entry
from ..data.test_data import write_fake_nmr
from .test_resume import TermAtStep, data_overrides  # noqa: F401 (a fixture)
from .test_train import compose_train, tiny_overrides


def test_nmr_run_stops_resumes_with_the_printed_command_and_is_evaluated(tmp_path, monkeypatch, capsys):
    """Issue 40 item 1: data=nmr on a folder of one's own; SIGTERM at step 2 of 4; the printed
    resume command finishes the run in its folder (before: NMRDataModule got the procedural
    data's cache_dir); the evaluation scores its categories."""
    root = tmp_path / "nmr"
    write_fake_nmr(root)
    data = ["data=nmr", f"data.root={root}", "data.categories=[airplane,chair]", "data.num_workers=0",
            "data.batch_size=2", "data.eval_batch_size=8", "data.val_views=[0]"]
    run = tmp_path / "run"
    stop = f"+callbacks.terminator={{_target_:{TermAtStep.__module__}.TermAtStep,stage:coarse,step:2}}"
    with pytest.raises(SystemExit) as stopped:
        run_entry(train_main, [*tiny_overrides(data, 4, "stage=coarse"), stop, f"hydra.run.dir={run}"], monkeypatch)
    assert stopped.value.code == 128 + signal.SIGTERM
    printed = capsys.readouterr().err
    command = shlex.split(next(line for line in printed.splitlines() if "Resume with: " in line)
                          .split("Resume with: ", 1)[1])
    assert command[:2] == ["python", "train.py"], command

    run_entry(train_main, command[2:], monkeypatch)
    final = run / "coarse" / "checkpoints" / "final.ckpt"
    assert load_checkpoint(final)["global_step"] == 4
    saved = OmegaConf.load(run / "config.yaml").data
    assert saved._target_ == "svr.data.datamodules.NMRDataModule" and "cache_dir" not in saved

    out = tmp_path / "eval"
    run_entry(evaluate_main, [f"ckpt_path={final}", *data[:3], "views=[0]", "baselines=[]", "progress=false",
                              f"output_dir={out}"], monkeypatch)
    summary = json.loads((out / "iou.json").read_text())
    assert set(summary["categories"]) == {"airplane", "chair"} and summary["mean"] is not None
    assert "warning" not in capsys.readouterr().err  # the checkpoint's own categories


def test_a_run_failing_before_its_first_checkpoint_leaves_nothing(tmp_path, data_overrides, monkeypatch, capsys):
    """Issue 40 item 4: a setting error found inside the first stage (after its loggers wrote
    their files) is one line, and the run folder is gone, so the same command may run again."""
    run = tmp_path / "run"
    expect_usage_error(train_main, [*tiny_overrides(data_overrides, 2, "stage=coarse"), "stage.coarse.optimizer.lr=-1",
                                    f"hydra.run.dir={run}"], monkeypatch, capsys, "sdfdiff-train")
    assert not run.exists()


def test_a_folder_without_checkpoints_is_retried_and_resumed(tmp_path, data_overrides, monkeypatch):
    """Issue 40 item 4: what a run killed before its first checkpoint leaves (config.yaml, logs, a
    stage folder) neither refuses a new run in that folder nor a resume, which starts it over."""
    cfg = compose_train(tiny_overrides(data_overrides, 2, "stage=coarse"))
    for name in ("retried", "resumed"):
        folder = RunFolder(tmp_path / name)
        (folder.stage_dir("coarse") / "csv").mkdir(parents=True)
        (folder.stage_dir("coarse") / "csv" / "metrics.csv").write_text("step,train/total\n0,1.0\n")
        write_text(folder.config, OmegaConf.to_yaml(settings_record(build_settings(cfg))))
    run_entry(train_main, [*tiny_overrides(data_overrides, 2, "stage=coarse"), f"hydra.run.dir={tmp_path / 'retried'}"],
              monkeypatch)
    run_entry(train_main, [f"ckpt_path={tmp_path / 'resumed'}"], monkeypatch)
    for name in ("retried", "resumed"):
        assert load_checkpoint(RunFolder(tmp_path / name).final("coarse"))["global_step"] == 2, name
