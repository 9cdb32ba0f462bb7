"""svr.demo (what `make demo` runs) at toy size: the three stages, the evaluation table with the coarse
stage and every baseline in the evaluation script's format, pictures and meshes, and resuming a stopped run."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.settings import build_settings
from svr import scoring
from svr.demo import main, run
from svr.evaluation import protocol
from svr.training.run_folder import RunFolder

from ..entry_points import expect_usage_error

SCHEDULE = ("coarse", "refine", "joint")


def demo(args: list[str]) -> dict:
    """The demo with these command-line overrides, in this process (``run`` on configs/demo.yaml)."""
    return run(build_settings(compose("demo", args)), args)


def tiny(cache: Path) -> list[str]:
    return [f"data.cache_dir={cache}", "data.categories=[chair,mug]", "data.train=2", "data.val=1", "data.test=1",
            "data.batch_size=2", "data.eval_batch_size=8", "data.val_views=[0,12]", "data.supersample=1",
            "model=tiny", "loss.render_size=16", "loss.trace.max_steps=64", "stage.coarse.max_steps=2",
            "stage.refine.max_steps=2", "stage.joint.max_steps=2", "trainer.val_check_interval=2",
            "trainer.enable_model_summary=false", "callbacks.image_logger=null"]


def test_demo_trains_evaluates_and_resumes(tmp_path, capsys, monkeypatch):
    out = tmp_path / "demo"
    args = [f"out={out}", "quiet=true", "protocol_workers=0", *tiny(tmp_path / "cache")]
    side_scored = []
    real_side_view_iou = protocol.side_view_iou
    monkeypatch.setattr(protocol, "side_view_iou",
                        lambda sdf, *a, **k: side_scored.append(len(sdf)) or real_side_view_iou(sdf, *a, **k))
    scored_calibrations = []
    real_evaluate = scoring.evaluate
    monkeypatch.setattr(scoring, "evaluate",
                        lambda model, *a, **k: scored_calibrations.append(model.calibration) or real_evaluate(model, *a, **k))
    demo(args)
    printed = capsys.readouterr().out
    for row in ("ours (joint stage, refined)", "coarse stage alone", "mean shape", "category mean shape",
                "retrieval", "oracle (exact shape)", "ours - retrieval"):
        assert f"| {row}" in printed and f"| {row}" in (out / "table.md").read_text()
    summary = json.loads((out / "iou.json").read_text())
    assert summary["split"] == "test" and set(summary["categories"]) == {"chair", "mug"}
    assert set(summary["extra"]) == {"coarse stage alone"}
    assert set(summary["baselines"]) == {"mean_shape", "category_mean_shape", "retrieval", "retrieval_any_view",
                                        "oracle"}
    for name, row in [*summary["extra"].items(), *summary["baselines"].items()]:
        assert set(row["categories"]) == {"chair", "mug"} and 0.0 <= row["mean"] <= 1.0, name
    assert summary["num_images"] == 2 * 24 and summary["full_protocol"]
    # The main row is scored from the side too, the coarse stage's (a voxel IoU row only) not.
    assert set(summary["side_views"]["categories"]) == {"chair", "mug"} and sum(side_scored) == 2 * 24
    for f in ("table.csv", "per_object.csv", "per_image.csv", "predictions.png", "timings.json"):
        assert (out / f).is_file(), f
    assert len(list((out / "meshes").glob("*.ply"))) == 2
    timings = json.loads((out / "timings.json").read_text())
    assert timings["train_seconds"] > 0
    assert timings["steps"] == {s: {"planned": 2, "reached": 2} for s in ("coarse", "refine", "joint")}
    assert "steps (planned / reached): coarse 2 / 2, refine 2 / 2, joint 2 / 2" in printed
    # The last stage's checkpoint was calibrated on the validation split (the tiny model has no
    # mirror look: no carving, the input view, each at 7 levels), and the choice is kept in it; the
    # coarse stage's row went through the same calibration, searched once.
    record = summary["calibration_search"]["joint"]
    assert set(summary["calibration_search"]) == {"joint"}
    assert record["split"] == "val" and len(record["candidates"]) == 14
    assert record["calibrated_iou"] == max(c["iou"] for c in record["candidates"]) >= record["uncalibrated_iou"]
    assert printed.count("on the validation split in") == 1
    assert len(scored_calibrations) == 2 and scored_calibrations[0] is not None
    assert scored_calibrations[1] == scored_calibrations[0]  # the full model's, then the coarse stage's
    assert summary["calibration"].startswith("carve ")  # what the scored predictions went through

    # A finished run is evaluated again, not retrained.
    final = out / "train" / "joint" / "checkpoints" / "final.ckpt"
    stamp = final.stat().st_mtime_ns
    demo(args)
    printed = capsys.readouterr().out
    assert "holds a finished run" in printed and "on the validation split in" not in printed  # kept, not redone
    assert final.stat().st_mtime_ns == stamp
    # recalibrate=true searches again (and stores the new choice)
    demo([*args, "recalibrate=true"])
    assert capsys.readouterr().out.count("on the validation split in") == 1
    # calibrate_carving=false: the levels alone (the carvings read the input camera); the tiny network
    # reads no camera either, so the scored predictions read only the image
    demo([*args, "recalibrate=true", "calibrate_carving=false"])
    capsys.readouterr()
    summary = json.loads((out / "iou.json").read_text())
    record = summary["calibration_search"]["joint"]
    assert record["carving"] is False and {c["carve"] for c in record["candidates"]} == {"none"}
    assert summary["reads"] == "nothing" and summary["baselines"]["retrieval_any_view"]["reads"] == "nothing"
    assert "retrieval (any view): nothing" in (out / "table.md").read_text()
    with pytest.raises(ValueError, match="recalibrate=true needs calibrate=true"):
        demo([*args, "recalibrate=true", "calibrate=false"])
    stamp = final.stat().st_mtime_ns

    # A run stopped after the refine stage resumes there and trains only the joint stage.
    import shutil

    shutil.rmtree(out / "train" / "joint")
    refine_final = out / "train" / "refine" / "checkpoints" / "final.ckpt"
    assert RunFolder(out / "train").resume_point(["coarse", "refine", "joint"]) == (False, refine_final)
    coarse_stamp = (out / "train" / "coarse" / "checkpoints" / "final.ckpt").stat().st_mtime_ns
    demo(args)
    assert "resuming the unfinished run" in capsys.readouterr().out
    assert (out / "train" / "refine" / "csv" / "metrics.csv").is_file()  # the run's log, kept in place
    assert final.is_file()
    assert (out / "train" / "coarse" / "checkpoints" / "final.ckpt").stat().st_mtime_ns == coarse_stamp


def test_demo_stopped_by_sigterm_resumes_and_counts_the_whole_run(tmp_path, capsys, monkeypatch):
    """A SIGTERM during the demo's training exits with status 143; running the command again (from
    another working directory, with a relative out) resumes that run, and timings.json counts the
    training time of both parts; the steps planned and reached are in iou.json too."""
    monkeypatch.chdir(tmp_path)
    stop = ["+callbacks.terminator._target_=tests.svr.training.test_resume.TermAtStep",
            "+callbacks.terminator.stage=refine", "+callbacks.terminator.step=1"]
    args = ["out=rel/demo", "quiet=true", "protocol_workers=0", *tiny(tmp_path / "cache")]
    with pytest.raises(SystemExit) as stopped:
        demo([*args, *stop])
    assert stopped.value.code == 143
    assert "run the same command again" in capsys.readouterr().err
    run_dir = tmp_path / "rel" / "demo" / "train"  # out from the working directory
    first_part = RunFolder(run_dir).train_seconds(["coarse"])
    assert first_part > 0 and (run_dir / "refine" / "checkpoints" / "last.ckpt").is_file()
    result = demo([*args, *stop])  # the same command: resumes after refine's step 1
    assert "resuming the unfinished run" in capsys.readouterr().out
    timings = json.loads((tmp_path / "rel" / "demo" / "timings.json").read_text())
    assert timings["resumed"] and timings["train_seconds"] == pytest.approx(RunFolder(run_dir).train_seconds(SCHEDULE))
    assert timings["train_seconds"] > first_part
    steps = {s: {"planned": 2, "reached": 2} for s in SCHEDULE}
    assert timings["steps"] == steps and result.iou["steps"] == steps
    assert json.loads((tmp_path / "rel" / "demo" / "iou.json").read_text())["steps"] == steps


def test_resume_point_and_eval_only_errors(tmp_path):
    assert RunFolder(tmp_path).resume_point(["coarse", "refine"]) == (False, None)
    (tmp_path / "coarse" / "checkpoints").mkdir(parents=True)
    (tmp_path / "coarse" / "checkpoints" / "last.ckpt").write_bytes(b"x")
    assert RunFolder(tmp_path).resume_point(["coarse", "refine"]) == (False, tmp_path / "coarse" / "checkpoints" / "last.ckpt")
    with pytest.raises(ValueError, match="eval_only=true needs a finished run"):
        demo([f"out={tmp_path / 'nothing'}", "eval_only=true", "quiet=true"])


@pytest.mark.parametrize("override, message", [("model=nosuch", "model=nosuch: no such option"),
                                               ("stage.coarse.max_steps=0", "stage.coarse.max_steps must be"),
                                               ("protocol_workers=-1", "protocol_workers must be")])
def test_demo_mistakes_are_one_line(tmp_path, capsys, monkeypatch, override, message):
    """svr.demo is a hydra entry like the others: a mistake, a group option hydra cannot compose
    included, is one line, exit status 2, and leaves no folder behind."""
    line = expect_usage_error(main, [f"out={tmp_path / 'demo'}", "quiet=true",
                                     f"data.cache_dir={tmp_path / 'cache'}", override], monkeypatch, capsys,
                              prog="svr.demo")
    assert message in line
    assert not (tmp_path / "demo").exists()


@pytest.mark.parametrize("cores, device, expected", [(2, "cpu", 0), (4, "cpu", 2), (16, "cpu", 2), (2, "cuda", 2)])
def test_the_evaluation_gets_voxelisation_workers_only_where_cores_are_spare(monkeypatch, cores, device, expected):
    monkeypatch.setattr(scoring.os, "cpu_count", lambda: cores)
    assert scoring._evaluation_workers(2, device) == expected
    assert scoring._evaluation_workers(0, device) == 0
