"""Scores a finished training run the way the demo reports it: its last stage's checkpoint, its
coarse stage's and every baseline (``svr.evaluation.baselines``) on the same images by the benchmark
protocol, written as the evaluation's files beside the demo's pictures of predictions and meshes.
Each checkpoint is first calibrated on the validation split (``svr.evaluation.calibration``), once:
the choice is stored in the checkpoint, so inference from it applies the same."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from hydra.utils import instantiate

import renderer
from svr.evaluation.baselines import BASELINES
from svr.evaluation.benchmark import add_baselines, evaluate, prepare_split
from svr.evaluation.calibration import search_calibration, store_calibration, stored_calibration
from svr.evaluation.tables import format_table, write_report
from svr.inference.prediction import load_model
from svr.inference.showcase import showcase
from svr.training.run_folder import RunFolder
from svr.training.settings import TrainSettings


def calibrate_checkpoint(path: Path, datamodule, progress: bool = True, again: bool = False) -> dict:
    """The calibration record of the checkpoint at ``path``: the stored one, else (or with ``again``,
    replacing it) one searched on the data module's validation split and stored
    (``svr.evaluation.calibration``)."""
    record = None if again else stored_calibration(path)
    if record is None:
        prepare_split(datamodule, "val", progress=progress)
        search = search_calibration(load_model(path, "cpu"), datamodule.dataset("val"), progress=progress)
        store_calibration(path, search)
        record = search.record()
        print(f"calibrated {path} on the validation split in {search.seconds:.0f} s: {search.best.describe()} "
              f"(validation IoU {search.uncalibrated_iou:.4f} -> {search.best_iou:.4f})", flush=True)
    return record


def score_run(settings: TrainSettings, run: RunFolder, out_dir: Path, split: str = "test", progress: bool = True,
              protocol_workers: int = 0, calibrate: bool = True, recalibrate: bool = False) -> dict:
    """Scores a finished run with the benchmark protocol: its last stage's checkpoint, its coarse
    stage's and every baseline (``svr.evaluation.baselines``) on the same images; writes the
    evaluation's files, ``predictions.png`` and ``meshes/`` into ``out_dir``. With ``calibrate``
    each checkpoint is calibrated first (``calibrate_checkpoint``; with ``recalibrate`` searched
    again even where one is stored); without, none is applied.

    Returns:
        ``{"table": markdown, "iou": the iou.json dict, "files": [paths], "calibration": {stage: record}}``.
    """
    dm = instantiate(settings.data)
    dm.prepare_data()
    schedule = list(settings.stage.schedule)
    final_ckpt, coarse_ckpt = run.best_or_final(schedule[-1]), run.best_or_final(schedule[0])
    calibrations = {}
    if calibrate:
        for stage, path in ((schedule[-1], final_ckpt), (schedule[0], coarse_ckpt)):
            if stage not in calibrations:
                calibrations[stage] = calibrate_checkpoint(path, dm, progress, again=recalibrate)

    def load(path: Path):
        model = load_model(path, "cpu")
        return model if calibrate else dataclasses.replace(model, calibration=None)

    kwargs = dict(progress=progress, protocol_workers=protocol_workers)  # batches: the data's eval_batch_size
    model = load(final_ckpt)
    result = evaluate(model, dm, split, **kwargs)
    coarse_model = load(coarse_ckpt)
    extra = {}
    if coarse_ckpt != final_ckpt:
        extra["coarse stage alone"] = evaluate(coarse_model, dm, split, **kwargs).table
    result = add_baselines(result, dm, BASELINES, model, progress=progress)
    label = f"ours ({schedule[-1]} stage, {result.output})"
    files = write_report(result, out_dir, extra_rows=extra, label=label)

    scene = (dm.shading.scene(effects=("shading",)) if dm.shading is not None else
             renderer.Scene(effects=("shading",), background=(1.0, 1.0, 1.0)))
    pictures = showcase(model, coarse_model, dm.dataset(split), dm.categories, scene, out_dir)
    summary = json.loads(Path(files["json"]).read_text())
    return {"table": format_table(result, extra, label), "iou": summary, "calibration": calibrations,
            "files": [str(p) for p in files.values()] + [str(p) for p in pictures]}


__all__ = ["score_run"]
