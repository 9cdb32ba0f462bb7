"""Stopping and resuming training: a SIGTERM saves a resumable checkpoint and exits non-zero; a
resumed run goes on in its own folder with its own config and ends with the weights of a run
that was never interrupted; stale temporary files are cleaned; bad step budgets are refused."""
from __future__ import annotations

import csv
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import pytorch_lightning as pl
import torch
from hydra import initialize_config_dir
from omegaconf import OmegaConf

from sdfcommon.tooling.settings import build_settings, settings_record
from svr.inference.checkpoints import load_checkpoint
from svr.training.resume import (requeued_run, resume_config, run_defaults, run_group_choices, slurm_run_folder,
                                 train_output_subdir, train_run_dir)
from svr.training.run_folder import RunFolder, run_folder_of
from svr.training.stages import TrainingStopped

from .test_train import BITWISE, CONFIGS, compose_train, state, tiny_overrides, train

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def data_overrides(tmp_path_factory) -> list[str]:
    """A tiny procedural dataset; 3 batches per epoch, so runs cross epochs."""
    cache = tmp_path_factory.mktemp("resume_cache")
    return [f"data.cache_dir={cache}", "data.categories=[chair,mug]", "data.train=2", "data.val=1", "data.test=1",
            "data.batch_size=2", "data.eval_batch_size=8", "data.val_views=[0]", "data.progress=false",
            "data.supersample=1", "data.samples_per_epoch=6"]


class TermAtStep(pl.Callback):
    """Sends this process a SIGTERM after training step ``step`` of ``stage`` (as ``kill`` would)."""

    def __init__(self, stage: str, step: int):
        self.stage, self.step = stage, step

    def on_train_batch_end(self, trainer, pl_module, *args) -> None:
        if pl_module.stage == self.stage and trainer.global_step == self.step:
            os.kill(os.getpid(), signal.SIGTERM)


class TermInValidation(pl.Callback):
    """Sends this process a SIGTERM in the middle of the validation after step ``step``."""

    def __init__(self, step: int):
        self.step = step

    def on_validation_batch_start(self, trainer, *args) -> None:
        if trainer.global_step == self.step and not trainer.sanity_checking:
            os.kill(os.getpid(), signal.SIGTERM)


def weights(path: Path) -> dict[str, torch.Tensor]:
    return state(path, "net.")


def assert_close(a: dict, b: dict, what: str) -> None:
    assert a.keys() == b.keys() and a
    for k in a:
        assert torch.allclose(a[k].float(), b[k].float(), rtol=1e-5, atol=1e-6), f"{what}: {k} differs"


def test_sigterm_saves_and_resume_equals_uninterrupted_run(tmp_path, data_overrides):
    """Fault injection: SIGTERM at random steps, three times, resuming each time: every stopped
    attempt raises TrainingStopped (exit status 143) with last.ckpt at the step reached, and the
    end matches an uninterrupted run's weights (stages coarse -> refine, epochs of 3 batches)."""
    base = tiny_overrides(data_overrides, 7, "stage.schedule=[coarse,refine]", "trainer.val_check_interval=3",
                          BITWISE)
    whole = train(compose_train(base), tmp_path / "whole")

    run = tmp_path / "stopped"
    rng = random.Random(17)
    s1, s2 = sorted(rng.sample(range(1, 7), 2))
    stops = [("coarse", s1), ("coarse", s2), ("refine", rng.randrange(1, 7))]
    for attempt, (stage, step) in enumerate(stops):
        cfg = compose_train([*base, *([f"ckpt_path={run}"] if attempt else [])])  # a folder: its latest checkpoint
        OmegaConf.set_struct(cfg, False)
        cfg.callbacks.terminator = {"_target_": f"{__name__}.TermAtStep", "stage": stage, "step": step}
        with pytest.raises(TrainingStopped) as stopped:
            train(cfg, run)
        assert stopped.value.code == 128 + signal.SIGTERM
        assert stopped.value.checkpoint == run / stage / "checkpoints" / "last.ckpt"
        assert load_checkpoint(stopped.value.checkpoint)["global_step"] == step
    resumed = train(compose_train([*base, f"ckpt_path={run}"]), run)
    for stage in ("coarse", "refine"):
        assert_close(weights(whole.checkpoint(stage, "final")), weights(run / stage / "checkpoints" / "final.ckpt"),
                     f"{stage} after stops at {stops}")
    # Best-checkpoint tracking survived the resumes: the best score is the best of all validations.
    with open(run / "refine" / "csv" / "metrics.csv") as f:
        ious = [float(r["val/iou"]) for r in csv.DictReader(f) if r.get("val/iou")]
    assert resumed.stages[-1].best_val_iou == pytest.approx(max(ious))
    steps = [int(float(r["step"])) for r in csv.DictReader(open(run / "coarse" / "csv" / "metrics.csv"))]
    assert steps == sorted(steps)  # one metrics file, each step once in order
    assert not list((run / "coarse" / "csv").glob("metrics.*.csv"))


def test_sigterm_during_validation_resumes_exactly(tmp_path, data_overrides):
    """A SIGTERM in the middle of a validation: the stage stops after the next training step (the
    checkpoint is written where Lightning writes its own), and the resumed run still ends with the
    uninterrupted run's weights (stopping inside the validation skipped the step's learning-rate
    update: resumed runs were one scheduler step behind)."""
    base = tiny_overrides(data_overrides, 7, "stage=coarse", "trainer.val_check_interval=2",
                          "data.val_views=[0,6,12]", "data.eval_batch_size=1", BITWISE)
    whole = train(compose_train(base), tmp_path / "whole")
    run = tmp_path / "stopped"
    cfg = compose_train(base)
    OmegaConf.set_struct(cfg, False)
    cfg.callbacks.terminator = {"_target_": f"{__name__}.TermInValidation", "step": 4}
    with pytest.raises(TrainingStopped) as stopped:
        train(cfg, run)
    assert load_checkpoint(stopped.value.checkpoint)["global_step"] == 5  # the step after the validation
    train(compose_train([*base, f"ckpt_path={run}"]), run)
    assert_close(weights(whole.checkpoint("coarse", "final")), weights(run / "coarse" / "checkpoints" / "final.ckpt"),
                 "stopped during validation")


def test_a_resume_that_only_hides_the_progress_bars_warns_about_nothing(tmp_path, data_overrides, caplog):
    """`python -m svr.demo eval_only=true quiet=true` on a run trained with progress bars: the
    changes are logged, but as information, not as warnings; a real change still warns."""
    import logging

    from svr.demo import QUIET_OVERRIDES
    from svr.training.resume import continued_settings

    folder = RunFolder(tmp_path / "run")
    folder.root.mkdir()
    bars = ["trainer.enable_progress_bar=true", "data.progress=true"]  # the run was trained with them
    OmegaConf.save(compose_train(tiny_overrides(data_overrides, 5, *bars)), folder.config)
    quiet = [*QUIET_OVERRIDES]
    with caplog.at_level(logging.INFO, logger="svr.training.resume"):
        continued_settings(None, folder, quiet, compose_train([*tiny_overrides(data_overrides, 5), *quiet]))
    changed = [r for r in caplog.records if "with a changed setting" in r.getMessage()]
    assert changed and all(r.levelno == logging.INFO for r in changed)
    caplog.clear()
    longer = ["stage.coarse.max_steps=9", *quiet]
    with caplog.at_level(logging.INFO, logger="svr.training.resume"):
        continued_settings(None, folder, longer, compose_train([*tiny_overrides(data_overrides, 5), *longer]))
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "stage.coarse.max_steps: 5 -> 9" in warned[0]


def test_resume_config_keeps_the_run_and_names_what_may_not_change(data_overrides):
    saved = compose_train(tiny_overrides(data_overrides, 5))
    again = compose_train(tiny_overrides(data_overrides, 2))  # the defaults of a new command differ
    merged, changes = resume_config(saved, again, ["ckpt_path=x.ckpt"])
    assert merged.stage.coarse.max_steps == 5 and changes == []
    resuming = compose_train([*tiny_overrides(data_overrides, 2), "ckpt_path=x.ckpt"])
    merged, changes = resume_config(saved, resuming, ["ckpt_path=x.ckpt"])
    assert merged.ckpt_path == "x.ckpt" and changes == []  # resuming is not a changed setting to warn about
    longer = compose_train(tiny_overrides(data_overrides, 5, "stage.coarse.max_steps=9", "trainer.accelerator=cpu"))
    merged, changes = resume_config(saved, longer, ["stage.coarse.max_steps=9", "trainer.accelerator=cpu"])
    assert merged.stage.coarse.max_steps == 9 and merged.stage.refine.max_steps == 5
    assert any(c.startswith("stage.coarse.max_steps: 5 -> 9") for c in changes)
    with pytest.raises(ValueError, match="model"):
        resume_config(saved, compose_train(tiny_overrides(data_overrides, 5, "model=small")), ["model=small"])
    with pytest.raises(ValueError, match="loss.weights.eikonal"):
        resume_config(saved, compose_train(tiny_overrides(data_overrides, 5, "loss.weights.eikonal=0.5")),
                      ["loss.weights.eikonal=0.5"])


def test_resume_config_takes_the_defaults_of_settings_a_saved_run_lacks():
    """A run saved before a setting existed goes on with that setting's default; a node the run
    switched off (null) stays off however the defaults look."""
    saved = OmegaConf.create({"seed": 0, "callbacks": {"progress_bar": None}})
    requested = OmegaConf.create({"seed": 0, "callbacks": {"progress_bar": {"_target_": "Bar", "rate": 10}},
                                  "paths": {"output_dir": "outputs"}})
    merged, changes = resume_config(saved, requested, [])
    assert OmegaConf.to_container(merged) == {"seed": 0, "callbacks": {"progress_bar": None},
                                              "paths": {"output_dir": "outputs"}}
    assert changes == []
    # The same under a global group on the command line (the demo's experiment=demo), which names
    # every setting but not the new ones.
    saved = OmegaConf.create({"seed": 0, "loss": {"weights": {"voxel": 0.0}}})
    requested = OmegaConf.create({"seed": 0, "loss": {"weights": {"voxel": 0.0, "voxel_kind": "distance"}}})
    merged, changes = resume_config(saved, requested, ["experiment=demo"])
    assert merged.loss.weights.voxel_kind == "distance" and changes == []
    with pytest.raises(ValueError, match="voxel_kind"):  # named on the command line: a change
        resume_config(saved, requested, ["loss.weights.voxel_kind=distance"])


def test_resume_config_takes_no_default_of_another_data_group(tmp_path, data_overrides):
    """Issue 40 item 1: an NMR run resumed by a command line whose default data group is the
    procedural one goes on with its NMR data node, none of the procedural data's keys in it."""
    nmr = ["data=nmr", f"data.root={tmp_path}", "data.categories=[airplane,chair]"]
    saved = OmegaConf.create(settings_record(build_settings(compose_train(tiny_overrides(nmr, 2)))))
    merged, changes = resume_config(saved, compose_train(tiny_overrides(data_overrides, 2)), [f"ckpt_path={tmp_path}"])
    assert OmegaConf.to_container(merged.data) == OmegaConf.to_container(saved.data) and changes == []
    assert build_settings(merged).data["_target_"] == "svr.data.datamodules.NMRDataModule"


def test_a_resumed_runs_defaults_come_from_its_own_config_groups(tmp_path):
    """Issue 40 item 1: the defaults of settings a saved run lacks are composed with the config
    groups hydra recorded for the run (data=nmr), a group the command line names keeping its own."""
    run = RunFolder(tmp_path / "run")
    run.hydra_record.parent.mkdir(parents=True)
    OmegaConf.save({"hydra": {"runtime": {"choices": {"data": "nmr", "model": "tiny", "experiment": None,
                                                      "hydra/launcher": "basic"}}}}, run.hydra_record)
    assert run_group_choices(run) == {"data": "nmr", "model": "tiny"}
    small = compose_train(["model=small"]).model
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        defaults = run_defaults(run, [f"ckpt_path={run.root}", "model=small"])
        assert run_defaults(RunFolder(tmp_path / "bare"), []) is None  # no record of the run
    assert defaults.data._target_ == "svr.data.datamodules.NMRDataModule" and "cache_dir" not in defaults.data
    assert defaults.model == small
    assert run_defaults(run, []) is None  # outside a hydra command


def test_run_folder_and_latest_checkpoint(tmp_path):
    run = tmp_path / "run"
    (run / "coarse" / "checkpoints").mkdir(parents=True)
    ckpt = run / "coarse" / "checkpoints" / "last.ckpt"
    ckpt.write_bytes(b"x")
    assert run_folder_of(ckpt) is None  # no config.yaml: not a run folder
    (run / "config.yaml").write_text("seed: 0\n")
    assert run_folder_of(ckpt) == RunFolder(run.resolve())
    assert RunFolder(run).latest_checkpoint(["coarse", "refine"]) == ckpt
    final = run / "coarse" / "checkpoints" / "final.ckpt"
    final.write_bytes(b"y")
    os.utime(ckpt, ns=(1, 1))
    assert RunFolder(run).latest_checkpoint(["coarse", "refine"]) == final
    # A resume runs in the run's own folder (a checkpoint's or the folder itself) with no new .hydra/.
    assert train_run_dir(str(ckpt), "outputs", "outputs/train/new") == str(run.resolve())
    assert train_run_dir(str(run), "outputs", "outputs/train/new") == str(run.resolve())
    assert train_run_dir(None, "outputs", "outputs/train/new") == "outputs/train/new"
    assert train_output_subdir(str(ckpt), str(run), "outputs") is None
    assert train_output_subdir(str(ckpt), str(tmp_path / "elsewhere"), "outputs") == ".hydra"  # hydra.run.dir given: a new folder
    cfg = compose_train([f"ckpt_path={ckpt}"], hydra=True)
    assert cfg.hydra.run.dir == str(run.resolve()) and cfg.hydra.output_subdir is None
    cfg = compose_train([f"ckpt_path={ckpt}", f"hydra.run.dir={tmp_path / 'elsewhere'}"], hydra=True)
    assert cfg.hydra.output_subdir == ".hydra"


def test_slurm_batch_jobs_get_a_folder_their_requeue_resumes(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    env = {"SLURM_JOB_ID": "77", "SLURM_JOB_NAME": "train.sbatch"}
    assert slurm_run_folder(env, "outputs") == RunFolder(Path("outputs/train/slurm-77"))
    assert slurm_run_folder({**env, "SLURM_JOB_NAME": "interactive"}, "outputs") is None  # salloc/srun --pty
    assert slurm_run_folder({}, "outputs") is None
    arr = {**env, "SLURM_ARRAY_JOB_ID": "70", "SLURM_ARRAY_TASK_ID": "3"}
    assert slurm_run_folder(arr, "outputs") == RunFolder(Path("outputs/train/slurm-70_3"))
    requeued = {**env, "SLURM_RESTART_COUNT": "1"}
    assert requeued_run(requeued, "outputs") is None  # nothing to resume yet
    for key, value in requeued.items():
        monkeypatch.setenv(key, value)
    assert train_run_dir(None, "outputs", "outputs/train/new") == "outputs/train/slurm-77"
    assert train_output_subdir(None, "outputs/train/slurm-77", "outputs") == ".hydra"
    run = tmp_path / "outputs" / "train" / "slurm-77"
    (run / "coarse").mkdir(parents=True)
    (run / "config.yaml").write_text("seed: 0\n")
    assert requeued_run(requeued, "outputs") == RunFolder(Path("outputs/train/slurm-77"))
    assert train_output_subdir(None, "outputs/train/slurm-77", "outputs") is None  # the requeued job goes on in place
    assert requeued_run(env, "outputs") is None  # not requeued: no resume
    hpc = run / "coarse" / "hpc_ckpt_1.ckpt"  # Lightning's SIGUSR1 checkpoint
    hpc.write_bytes(b"x")
    assert RunFolder(run).latest_checkpoint(["coarse", "refine"]) == hpc
    assert run_folder_of(hpc) == RunFolder(run.resolve())


@pytest.mark.parametrize("steps, error, message", [
    ("-1", ValueError, r"stage.coarse.max_steps must be an integer >= 1, got -1"),
    ("0", ValueError, r"stage.coarse.max_steps must be an integer >= 1, got 0"),
    ("abc", TypeError, r"stage.coarse.max_steps must be an integer, got 'abc'")])
def test_step_budget_must_be_positive(tmp_path, data_overrides, steps, error, message):
    cfg = compose_train(tiny_overrides(data_overrides, 2, f"stage.coarse.max_steps={steps}"))
    with pytest.raises(error, match=message):
        train(cfg, tmp_path / "run")


def test_stale_temporaries_are_removed(tmp_path, data_overrides):
    run = tmp_path / "run"
    left = run / "coarse" / "checkpoints" / ".last.ckpt.0123456789abcdef.tmp"  # the checkpoint writer's
    left.parent.mkdir(parents=True)
    left.write_bytes(b"half a checkpoint")
    left_too = run / ".config.yaml.ab_12xyz.tmp"  # mkstemp's (sdfcommon.tooling.outputs.atomic_write)
    left_too.write_text("half")
    keep = run / "notes.tmp"  # not an atomic writer's name
    keep.write_text("mine")
    train(compose_train(tiny_overrides(data_overrides, 1, "stage=coarse")), run)
    assert not left.exists() and not left_too.exists() and keep.exists()


def _train_command(overrides: list[str]) -> list[str]:
    return [sys.executable, str(REPO / "train.py"), *overrides]


@pytest.mark.slow
def test_command_line_sigterm_exits_nonzero_and_resumes_in_place(tmp_path, data_overrides):
    """train.py killed with SIGTERM at random moments exits 143 each time; resuming with docs/svr_training.md's
    command continues in the same folder, with its config, and ends where an uninterrupted run ends.
    `slow` (four training processes, about 30 s): in the default suite a SIGTERM's checkpoint and the
    resume that equals an uninterrupted run are ``test_sigterm_saves_and_resume_equals_uninterrupted_run``'s,
    the command's exit status 143 and resume ``tests/svr/test_demo.py``'s."""
    # 60 steps: each kill lands a few steps after a new last.ckpt appears (about 8 steps here), so
    # three kills stay well inside the stage; a kill after its last step would find the run done.
    base = tiny_overrides(data_overrides, 60, "stage=coarse", "callbacks.image_logger=null")
    whole = tmp_path / "whole"
    done = subprocess.run(_train_command([*base, f"hydra.run.dir={whole}"]), cwd=REPO, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    run = tmp_path / "run"
    first = [*base, f"hydra.run.dir={run}"]
    rng = random.Random(3)
    last = run / "coarse" / "checkpoints" / "last.ckpt"
    for attempt in range(3):
        cmd = _train_command(first if attempt == 0 else [f"ckpt_path={run}", "trainer.enable_progress_bar=false"])
        proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        reached = load_checkpoint(last)["global_step"] if last.is_file() else 0
        deadline = time.time() + 300
        while time.time() < deadline and not (last.is_file() and load_checkpoint(last)["global_step"] > reached):
            time.sleep(0.2)
        time.sleep(rng.uniform(0, 0.3))
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 143, err[-2000:]
        assert "stopped by SIGTERM" in err
    resumed = subprocess.run(_train_command([f"ckpt_path={last}"]), cwd=tmp_path, capture_output=True, text=True,
                             timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run", "whole"]  # nothing written elsewhere
    assert OmegaConf.load(run / "config.yaml").stage.coarse.max_steps == 60
    assert_close(weights(whole / "coarse" / "checkpoints" / "final.ckpt"),
                 weights(run / "coarse" / "checkpoints" / "final.ckpt"), "command-line resume")


def test_command_line_errors_are_one_line_and_leave_the_run_as_it_was(tmp_path, data_overrides):
    """train.py on the shared entry-point error handling: a bad setting or a refused resume is one
    line with exit status 2; a new run leaves nothing, a resumed run's folder is unchanged."""
    bad = subprocess.run(_train_command([*tiny_overrides(data_overrides, 2), "stage.coarse.max_steps=-1",
                                         f"hydra.run.dir={tmp_path / 'bad'}"]),
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == ["sdfdiff-train: error: stage.coarse.max_steps must be an integer "
                                               ">= 1, got -1"]
    assert not (tmp_path / "bad").exists()

    run = tmp_path / "run"
    train(compose_train(tiny_overrides(data_overrides, 1, "stage=coarse")), run)
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    refused = subprocess.run(_train_command([f"ckpt_path={run}", "model=small"]), cwd=tmp_path,
                             capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sdfdiff-train: error: resuming a run keeps its config.yaml") \
        and "model." in lines[0]
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before


def test_training_console_has_no_known_noise(tmp_path, data_overrides):
    """Issue 17 item 17: a training run prints no cloud-logger advertisement, no deprecation from
    inside Lightning, no warning about the stages' deliberately frozen (eval-mode) modules, and no
    weights_only notice; resuming adds no warnings about its own folder."""
    overrides = [*tiny_overrides(data_overrides, 2, "stage.schedule=[coarse,refine]"), "trainer.enable_model_summary=false"]
    first = subprocess.run(_train_command([*overrides, f"hydra.run.dir={tmp_path / 'run'}"]), cwd=tmp_path,
                           capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr[-2000:]
    again = subprocess.run(_train_command([f"ckpt_path={tmp_path / 'run'}", "stage.refine.max_steps=3"]),
                           cwd=tmp_path, capture_output=True, text=True, timeout=300)  # resume to train longer
    assert again.returncode == 0, again.stderr[-2000:]
    assert "with a changed setting: stage.refine.max_steps: 2 -> 3" in again.stdout + again.stderr  # said loudly
    assert (tmp_path / "run" / "train.log").is_file()  # hydra's log is named after the command
    for out in (first.stdout + first.stderr, again.stdout + again.stderr):
        for noise in ("Tip:", "LeafSpec", "in eval mode", "weights_only", "exists and is not empty"):
            assert noise not in out, f"{noise!r} printed"
