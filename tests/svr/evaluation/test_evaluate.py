"""svr.evaluate: the benchmark table of a checkpoint from a tiny training run (printed and written),
the paper's layout with reference rows for NMR ShapeNet, and clear errors.

The checkpoint comes from ``svr.training.stages.train`` on a two-category procedural dataset (a few
seconds); ``tiny_run`` is shared with tests/svr/inference/test_infer.py.
"""
from __future__ import annotations

import csv
import json
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch

from hydra import compose as hydra_compose
from hydra import initialize_config_module

from sdfcommon.tooling.commands import CONFIG_MODULE, compose
from sdfcommon.tooling.settings import PathSettings, build_settings
from svr.data.datamodules import ProceduralDataModule
from svr.evaluate import main
from svr.evaluation.protocol import evaluate
from svr.evaluation.settings import EvalSettings
from svr.evaluation.tables import EvaluationResult, format_table, table_rows, write_report
from svr.inference.prediction import load_model, predict
from svr.nmr.format import NMR_CATEGORIES, nmr_file
from svr.nmr.metrics import iou_protocol, iou_table
from svr.nmr.side_views import side_view_iou, side_views

from ...entry_points import expect_usage_error, run_entry
from ..data.test_data import CATS, write_fake_nmr

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = str(ROOT / "configs")
CATEGORIES = ("chair", "mug")
# The data overrides of the tiny run, for train.yaml and eval.yaml alike (data group "procedural").
DATA = {"categories": list(CATEGORIES), "train": 2, "val": 1, "test": 1, "supersample": 1}


@dataclass(frozen=True)
class TinyRun:
    """A checkpoint of a tiny coarse -> refine training run and the data it was trained on."""

    checkpoint: Path
    cache_dir: Path

    def datamodule(self) -> ProceduralDataModule:
        return ProceduralDataModule(cache_dir=self.cache_dir, progress=False, **DATA)

    def data_overrides(self) -> list[str]:
        return [f"data.cache_dir={self.cache_dir}", f"data.categories=[{','.join(CATEGORIES)}]",
                *(f"data.{k}={v}" for k, v in DATA.items() if k != "categories"), "data.progress=false"]


_RUNS: dict[str, TinyRun] = {}


def make_tiny_run(root: Path) -> TinyRun:
    """Trains the tiny model (2 coarse + 2 refine steps) once per test session."""
    if "run" in _RUNS:
        return _RUNS["run"]
    from hydra import compose, initialize_config_dir

    from svr.training.stages import train

    cache = root / "cache"
    overrides = [
        "model=tiny", "data=procedural", "data.batch_size=2",
        "stage.schedule=[coarse,refine]", "stage.coarse.max_steps=2", "stage.refine.max_steps=2",
        "stage.refine.optimizer.lr=0.01",  # so the refined SDF differs from the coarse one
        "loss.render_size=32", "trainer=cpu", "trainer.limit_val_batches=0", "trainer.enable_progress_bar=false",
        "trainer.enable_model_summary=false", "callbacks.image_logger=null", "callbacks.progress_bar=null",
        "callbacks.lr_monitor=null", "logger=csv",
    ]
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose("train", overrides=overrides + TinyRun(Path(), cache).data_overrides())
    result = train(build_settings(cfg), root / "run")
    _RUNS["run"] = TinyRun(result.checkpoint("refine", "final"), cache)
    return _RUNS["run"]


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory) -> TinyRun:
    return make_tiny_run(tmp_path_factory.mktemp("tiny-run"))


def run_main(entry, args: list[str], hydra_dir: Path, monkeypatch) -> None:
    """Calls a hydra entry point in this process with command-line overrides."""
    monkeypatch.setattr(sys, "argv", ["prog", *args, f"hydra.run.dir={hydra_dir}", "progress=false"])
    entry()


# ------------------------------------------------------------------------------------------------


def test_main_prints_and_writes_the_table(tiny_run, tmp_path, capsys, monkeypatch):
    out = tmp_path / "eval"
    run_main(main, [f"ckpt_path={tiny_run.checkpoint}", f"output_dir={out}", "compare_coarse=true",
                    "batch_size=16", *tiny_run.data_overrides()], tmp_path / "hydra", monkeypatch)
    printed = capsys.readouterr().out
    assert "split: test" in printed and "split 'test'" in printed
    header = next(line for line in printed.splitlines() if line.startswith("| method"))
    assert [c.strip() for c in header.strip("|").split("|")] == ["method", "chair", "mug", "mean"]
    assert "ours (refined)" in printed and "ours (coarse)" in printed
    assert "(paper)" not in printed  # reference rows belong to NMR ShapeNet only

    summary = json.loads((out / "iou.json").read_text())
    assert summary["split"] == "test" and set(summary["categories"]) == set(CATEGORIES)
    assert summary["mean"] == pytest.approx(np.mean(list(summary["categories"].values())))
    assert summary["images"] == {"chair": 24, "mug": 24} and summary["full_protocol"]
    assert set(summary["coarse"]["categories"]) == set(CATEGORIES)
    assert f"{summary['mean']:.4f}" in printed
    with open(out / "table.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == ["method", "chair", "mug", "mean"] and rows[1][0] == "ours (refined)"
    table_md = (out / "table.md").read_text()
    assert table_md.count("| ours (") == 3 and "Side views: silhouette IoU" in table_md  # + the side-view table
    side = summary["side_views"]
    assert set(side["categories"]) == set(CATEGORIES) and 0.0 < side["mean"] <= 1.0
    assert side["mean"] == pytest.approx(np.mean(list(side["categories"].values())))
    # Every baseline is a row, scored on the same images, and ours minus retrieval is shown.
    assert set(summary["baselines"]) == {"mean_shape", "category_mean_shape", "retrieval", "retrieval_any_view",
                                        "oracle"}
    for row in summary["baselines"].values():
        assert set(row["categories"]) == set(CATEGORIES)
    minus = summary["ours_minus_retrieval"]["mean"]
    assert minus == pytest.approx(summary["mean"] - summary["baselines"]["retrieval"]["mean"])
    assert "| ours - retrieval" in printed and "| oracle (exact shape)" in printed
    with open(out / "per_object.csv") as f:
        objects = list(csv.DictReader(f))
    assert len(objects) == 2 and {o["category"] for o in objects} == set(CATEGORIES)
    assert float(objects[0]["iou_mean"]) <= float(objects[1]["iou_mean"])  # worst first
    with open(out / "per_image.csv") as f:
        images = list(csv.DictReader(f))
    assert len(images) == 48 and sorted({int(r["view"]) for r in images}) == list(range(24))
    assert np.mean([float(r["side_iou"]) for r in images if r["category"] == "chair"]) == pytest.approx(
        side["categories"]["chair"])
    assert "side_iou_mean" in objects[0]
    assert not list(out.glob(".*.tmp"))  # atomic writes leave no temporary files


def test_api_scores_every_view_by_the_protocol(tiny_run):
    model = load_model(tiny_run.checkpoint, "cpu")
    dm = tiny_run.datamodule()
    res = evaluate(model, dm, "test", views=[3, 17], keep_voxels=True, progress=False)
    assert len(res.iou) == 4 and not res.full_protocol and res.output == "refined"
    assert "Thinned run" in format_table(res)
    objects = dm.dataset("test")
    for i in range(len(res.iou)):
        obj = int(objects.offsets[res.category[i]]) + int(res.object_index[i])
        image = objects.views(obj, [int(res.view[i])])
        grid = predict(model, image)
        expected = iou_protocol(grid.values, objects.voxels(obj)[None], -model.half_side, model.half_side)
        assert res.iou[i] == pytest.approx(float(expected[0]), abs=1e-9)
        # From the views 90 degrees either side, against their stored alpha.
        view = torch.tensor([int(res.view[i])])
        alpha = objects.images_uint8(obj, side_views(view)[0].tolist())[:, 3]
        assert res.side_iou[i] == pytest.approx(float(side_view_iou(grid.values, model.half_side, view, alpha[None])[0]))
    assert res.voxels.shape == (4, 32, 32, 32) and res.voxels.dtype == bool
    assert evaluate(model, dm, "test", views=[3], progress=False, side_view_scores=False).side_iou is None


def fake_result(category_ids: list[str], split: str = "test") -> EvaluationResult:
    names = dict(NMR_CATEGORIES)
    cats = tuple((c, names.get(c, c)) for c in category_ids)
    n = len(cats)
    return EvaluationResult(split=split, dataset="NMR ShapeNet (fake)", categories=cats,
                            is_nmr_shapenet=all(c in names for c in category_ids), checkpoint="x.ckpt",
                            stage="joint", output="refined", category=np.repeat(np.arange(n), 2),
                            object_index=np.zeros(2 * n, dtype=np.int64), view=np.tile([0, 1], n),
                            iou=np.linspace(0.2, 0.8, 2 * n))


def test_nmr_table_has_the_paper_rows_in_the_paper_layout(tmp_path):
    res = fake_result(["03001627", "02691156"])  # chair, airplane: the columns follow the paper's order
    header, rows = table_rows(res)
    assert header == ["method", "airplane", "chair", "mean"]
    by_method = {r[0]: r[1:] for r in rows}
    assert by_method["SDFDiff (paper)"] == ["0.6874", "0.6436", "0.6674"]
    assert by_method["NMR (paper)"] == ["", "", "0.6015"]
    assert by_method["SoftRas, silhouettes (paper)"][-1] == "0.6234"
    assert by_method["SoftRas, full (paper)"][-1] == "0.6464"
    text = format_table(res)
    assert "means only" in text and "all 13" in text
    files = write_report(res, tmp_path / "out")
    summary = json.loads(files["json"].read_text())
    assert summary["reference"]["SDFDiff (paper)"]["categories"] == {"airplane": 0.6874, "chair": 0.6436}
    assert "val split" in format_table(fake_result(["02691156"], split="val"))


def test_extra_rows_share_the_table(tmp_path):
    """Drivers (e.g. a demo's baselines) add rows to the one table implementation."""
    res = fake_result(["02691156", "03001627"])
    baseline = iou_table(np.array([0.1, 0.3]), np.array([1, 1]), res.categories)  # chair only
    header, rows = table_rows(res, {"mean shape": baseline}, label="SDFDiff (ours)")
    assert rows[0][0] == "SDFDiff (ours)"
    assert ["mean shape", "", "0.2000", "0.2000"] in rows
    files = write_report(res, tmp_path, {"mean shape": baseline})
    assert json.loads(files["json"].read_text())["extra"]["mean shape"] == {"categories": {"chair": 0.2}, "mean": 0.2}
    with pytest.raises(TypeError, match="extra_rows"):
        table_rows(res, {"x": {"chair": 0.1}})


def test_every_nmr_category_gets_a_column_in_table_order():
    res = fake_result([c for c, _ in NMR_CATEGORIES])
    header, rows = table_rows(res)
    assert header[1:-1] == [n for _, n in NMR_CATEGORIES] and header[-1] == "mean"
    assert "all 13" not in format_table(res)


def test_errors_name_the_file_or_argument(tiny_run, tmp_path, capsys, monkeypatch):
    junk = tmp_path / "junk.ckpt"
    junk.write_bytes(b"not a checkpoint")
    data = [*tiny_run.data_overrides(), "progress=false"]
    assert "junk.ckpt" in expect_usage_error(main, [f"ckpt_path={junk}", f"output_dir={tmp_path / 'o1'}", *data],
                                             monkeypatch, capsys, "sdfdiff-evaluate")
    other = tmp_path / "other.ckpt"
    torch.save({"state_dict": {}}, other)
    with pytest.raises(ValueError, match="other.ckpt"):
        load_model(other, "cpu")
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    assert str(blocker) in expect_usage_error(main, [f"ckpt_path={tiny_run.checkpoint}",
                                                     f"output_dir={blocker / 'sub'}", *data], monkeypatch, capsys)
    assert "split must be one of" in expect_usage_error(
        main, [f"ckpt_path={tiny_run.checkpoint}", "split=testing", f"output_dir={tmp_path / 'o3'}", *data],
        monkeypatch, capsys)
    # The same check of view indices as svr.infer's, before any data is made.
    assert "views[0] must be an integer in [0, 23], got 99" in expect_usage_error(
        main, [f"ckpt_path={tiny_run.checkpoint}", "views=[99]", f"output_dir={tmp_path / 'o4'}", *data],
        monkeypatch, capsys)
    assert "batch_size must be an integer, got 'abc'" in expect_usage_error(
        main, [f"ckpt_path={tiny_run.checkpoint}", "batch_size=abc", f"output_dir={tmp_path / 'o5'}", *data],
        monkeypatch, capsys)
    assert "batch_size must be an integer >= 1, got 0" in expect_usage_error(
        main, [f"ckpt_path={tiny_run.checkpoint}", "batch_size=0", f"output_dir={tmp_path / 'o6'}", *data],
        monkeypatch, capsys)
    assert not any((tmp_path / f"o{k}").exists() for k in range(1, 7))  # refused runs leave nothing
    with pytest.raises(ValueError, match="output_dir"):
        write_report(fake_result(["02691156"]), blocker / "sub")
    with pytest.raises(ValueError, match="split"):
        evaluate(load_model(tiny_run.checkpoint, "cpu"), tiny_run.datamodule(), "testing")
    with pytest.raises(TypeError, match="model must be a LoadedModel"):  # a path is the command's to load
        evaluate(tiny_run.checkpoint, tiny_run.datamodule(), "test")


def test_settings_are_built_from_eval_yaml():
    """configs/eval.yaml becomes EvalSettings; the evaluation's batch is the data's eval_batch_size
    (one default), and the output folder defaults under paths.output_dir."""
    cfg = compose("eval", ["ckpt_path=x.ckpt"])
    settings = build_settings(cfg)
    assert isinstance(settings, EvalSettings) and isinstance(settings.paths, PathSettings)
    assert settings.batch_size == cfg.data.eval_batch_size == settings.data["eval_batch_size"]
    assert build_settings(compose("eval", ["ckpt_path=x.ckpt", "data.eval_batch_size=5"])).batch_size == 5
    assert settings.split == "test" and settings.views is None and settings.distributed == "auto"
    assert settings.data["_target_"].endswith("ProceduralDataModule")
    with initialize_config_module(CONFIG_MODULE, version_base="1.3"):
        full = hydra_compose("eval", ["ckpt_path=x.ckpt", "paths.output_dir=/elsewhere"], return_hydra_config=True)
    assert str(full.hydra.run.dir).startswith("/elsewhere/eval/")
    with pytest.raises(ValueError, match="nonsense: unknown setting"):
        build_settings(compose("eval", ["ckpt_path=x.ckpt", "+nonsense=1"]))
    with pytest.raises(TypeError, match="compare_coarse must be"):
        build_settings(compose("eval", ["ckpt_path=x.ckpt", "compare_coarse=maybe"]))


def refused_before_any_folder(entry, args: list[str], prog: str, tmp_path: Path, monkeypatch, capsys) -> list[str]:
    """Runs a command refused for its settings twice, with ``output_dir`` given and with the default
    run folder (under ``paths.output_dir``, from a fresh working directory), and checks that neither
    made a folder; returns the two error lines."""
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    out = tmp_path / "out"
    lines = [expect_usage_error(entry, [*args, *where], monkeypatch, capsys, prog)
             for where in ([f"output_dir={out}"], [])]
    assert not out.exists() and list(cwd.iterdir()) == []
    return lines


@pytest.mark.parametrize("override, message", [("+nonsense=1", "nonsense: unknown setting"),
                                               ("compare_coarse=maybe", "compare_coarse must be"),
                                               ("num_workers=-1", "num_workers must be an integer >= 0")])
def test_a_bad_key_or_value_is_one_line_and_makes_no_folder(override, message, tmp_path, monkeypatch, capsys):
    """Checked when the settings are built: before the run folder, the model or the data."""
    lines = refused_before_any_folder(main, ["ckpt_path=missing.ckpt", override], "sdfdiff-evaluate", tmp_path,
                                      monkeypatch, capsys)
    assert all(message in line for line in lines), lines


@pytest.mark.slow
def test_worker_processes_give_the_same_numbers(tiny_run):
    """protocol_workers (spawned processes for the voxelisation) and DataLoader workers change nothing."""
    model = load_model(tiny_run.checkpoint, "cpu")
    dm = tiny_run.datamodule()
    serial = evaluate(model, dm, "test", views=[0, 9], compare_coarse=True, progress=False)
    pooled = evaluate(model, dm, "test", views=[0, 9], compare_coarse=True, protocol_workers=2, num_workers=1,
                      batch_size=1, progress=False)
    assert np.array_equal(serial.iou, pooled.iou) and np.array_equal(serial.iou_coarse, pooled.iou_coarse)
    assert np.array_equal(serial.view, pooled.view) and np.array_equal(serial.category, pooled.category)


def test_output_dir_is_the_run_folder(tiny_run, tmp_path, monkeypatch, capsys):
    """Issue 17 item 13: with output_dir given, nothing is made in the working directory."""
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    monkeypatch.chdir(cwd)
    out = tmp_path / "out"
    run_entry(main, [f"ckpt_path={tiny_run.checkpoint}", f"output_dir={out}", "views=[0]", "baselines=[]",
                     "progress=false", *tiny_run.data_overrides()], monkeypatch)
    assert list(cwd.iterdir()) == []
    assert (out / "iou.json").is_file() and (out / ".hydra" / "config.yaml").is_file()


def _fake_nmr(root: Path, empty_split: str = "") -> list[str]:
    """A two-category NMR-format folder (airplane, chair; ``empty_split`` with no objects) and the
    data overrides that evaluate it."""
    write_fake_nmr(root)
    for cid in CATS if empty_split else ():
        np.savez_compressed(nmr_file(root, cid, empty_split, "images"), np.zeros((0, 24, 4, 64, 64), np.uint8))
        np.savez_compressed(nmr_file(root, cid, empty_split, "voxels"), np.zeros((0, 32, 32, 32), bool))
    return ["data=nmr", f"data.root={root}", "data.categories=[airplane,chair]", "data.num_workers=0"]


def test_an_empty_split_is_one_line_naming_the_split_and_the_folder(tiny_run, tmp_path, monkeypatch, capsys):
    """Issue 40 item 3: an empty split (a builder's val = 0) is an error, not an empty table."""
    data = _fake_nmr(tmp_path / "nmr", empty_split="val")
    out = tmp_path / "out"
    line = expect_usage_error(main, [f"ckpt_path={tiny_run.checkpoint}", "split=val", f"output_dir={out}",
                                     "progress=false", *data], monkeypatch, capsys, "sdfdiff-evaluate")
    assert "split 'val'" in line and str(tmp_path / "nmr") in line, line
    assert not out.exists()


def test_other_categories_than_trained_are_one_warning_line(tiny_run, tmp_path, monkeypatch, capsys):
    """Issue 40 item 21: a checkpoint trained on chair and mug, evaluated on airplane and chair:
    one warning line naming both, no Python warning with its source line."""
    out = tmp_path / "out"
    run_entry(main, [f"ckpt_path={tiny_run.checkpoint}", f"output_dir={out}", "views=[0]", "baselines=[]",
                     "progress=false", *_fake_nmr(tmp_path / "nmr")], monkeypatch)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "warning" in line.lower()]
    assert len(lines) == 1 and lines[0].startswith("sdfdiff-evaluate: warning: "), err
    assert "airplane" in lines[0] and "mug" in lines[0], lines[0]
    assert "UserWarning" not in err and "warnings.warn" not in err, err
    assert (out / "iou.json").is_file()


WORKERS_SCRIPT = """
import json, os, sys, time
from sdfcommon.tooling.processes import process_pool
pool = process_pool(2)
pids = sorted({f.result() for f in [pool.submit(os.getpid) for _ in range(16)]})
print(json.dumps(pids), flush=True)
time.sleep(120)
"""


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ")[1][0] != "Z"  # a zombie is dead, only not reaped
    except (FileNotFoundError, IndexError):
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGKILL])
def test_protocol_workers_die_with_a_killed_parent(sig):
    """Issue 17 item 4: svr.evaluate's voxelisation workers (protocol_workers) end with their parent,
    killed by SIGTERM or SIGKILL, instead of waiting on their queue forever."""
    proc = subprocess.Popen([sys.executable, "-c", WORKERS_SCRIPT], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        pids = json.loads(proc.stdout.readline())
        assert pids and all(_alive(p) for p in pids)
        proc.send_signal(sig)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 10
        while any(_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(p) for p in pids)
    finally:
        proc.kill()
        proc.wait()


def test_stored_calibration_is_applied_unless_turned_off(tiny_run, tmp_path, capsys, monkeypatch):
    """A checkpoint holding a calibration is scored with it (the line and the table say so), and
    ``calibrated=false`` scores the network's raw output."""
    from types import SimpleNamespace

    from svr.evaluation.calibration_search import store_calibration
    from svr.inference.calibration import Calibration

    ckpt = tmp_path / "calibrated.ckpt"
    shutil.copy(tiny_run.checkpoint, ckpt)
    store_calibration(ckpt, SimpleNamespace(record=lambda: {"settings": Calibration(level=0.05).to_dict()}))
    means = {}
    for flag in ("true", "false"):
        out = tmp_path / f"eval_{flag}"
        run_main(main, [f"ckpt_path={ckpt}", f"output_dir={out}", f"calibrated={flag}", "views=[0,6]", "baselines=[]",
                        *tiny_run.data_overrides()], tmp_path / f"hydra_{flag}", monkeypatch)
        printed = capsys.readouterr().out
        summary = json.loads((out / "iou.json").read_text())
        means[flag] = summary["mean"]
        if flag == "true":
            assert "calibration: carve none, level +0.0500" in printed
            assert summary["calibration"] == "carve none, level +0.0500"
            assert "Our predictions are calibrated (carve none, level +0.0500" in (out / "table.md").read_text()
        else:
            assert "calibration:" not in printed and summary["calibration"] is None
    assert means["true"] != means["false"]
