"""Scores a finished training run the way the demo reports it: its last stage's checkpoint, its
coarse stage's and every baseline (``svr.evaluation.baselines``) on the same images by the benchmark
protocol (``score_run``), then the evaluation's files, once, beside the demo's pictures of
predictions and meshes (``RunScores.write``). The last stage's checkpoint is first calibrated on the
validation split (``svr.evaluation.calibration_search``), once: the choice is stored in the checkpoint,
so inference from it applies the same (the coarse stage's row goes through that calibration too); so
is a framing bank for photos (``bank_checkpoints``)."""
from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional

import torch
from hydra.utils import instantiate

import renderer
from svr.data.datamodules import SVRDataModule
from svr.evaluation.baselines import BASELINES
from svr.evaluation.calibration_search import search_calibration, store_calibration, stored_calibration
from svr.evaluation.protocol import add_baselines, evaluate
from svr.evaluation.tables import EvaluationResult, format_table, write_report
from svr.inference.framing_bank import build_framing_bank, store_framing_bank
from svr.inference.prediction import load_model
from svr.inference.showcase import showcase
from svr.nmr.metrics import IoUTable
from svr.training.run_folder import RunFolder
from svr.training.settings import TrainSettings


@dataclass(frozen=True)
class RunScores:
    """A finished run scored by the benchmark protocol.

    Attributes:
        result: the last stage's evaluation, with the baselines on the same images.
        label: the last stage's row name in the table.
        extra: more rows of the table (the coarse stage alone, when it is another checkpoint).
        calibrations: {stage: the calibration search's record} of the last stage's checkpoint (empty
            when none was applied; the coarse stage's row went through the same calibration).
        pictures: ``predictions.png`` and the meshes, already written.
    """

    result: EvaluationResult
    label: str
    extra: dict[str, IoUTable] = field(default_factory=dict)
    calibrations: dict[str, dict] = field(default_factory=dict)
    pictures: list[Path] = field(default_factory=list)

    @property
    def table(self) -> str:
        """The markdown table (``svr.evaluation.tables.format_table``)."""
        return format_table(self.result, self.extra, self.label)

    def write(self, out_dir: Path, fields: Optional[Mapping[str, Any]] = None) -> dict[str, Path]:
        """The evaluation's files in ``out_dir`` (``svr.evaluation.tables.write_report``), ``iou.json``
        holding the calibration searches (``"calibration_search"``) and ``fields``."""
        return write_report(self.result, out_dir, extra_rows=self.extra, label=self.label,
                            fields={"calibration_search": self.calibrations, **(fields or {})})


def calibrate_checkpoint(path: Path, datamodule: SVRDataModule, progress: bool = True, again: bool = False,
                         carving: bool = True, device: str = "auto", protocol_workers: int = 0) -> dict:
    """The calibration record of the checkpoint at ``path``: the stored one, else (or with ``again``,
    replacing it) one searched on the data module's validation split and stored
    (``svr.evaluation.calibration_search``). Without ``carving`` only the level is searched (the
    carvings read the input camera), and a stored record that carves is searched again. The search
    runs on ``device`` ("auto": CUDA when available), its voxelisation in ``protocol_workers``
    processes (0: this one)."""
    record = None if again else stored_calibration(path)
    if record is not None and not carving and record["settings"].get("carve", "none") != "none":
        print(f"{path} holds a calibration that carves; searching again without carving", flush=True)
        record = None
    if record is None:
        datamodule.prepare_split("val", progress=progress)
        search = search_calibration(load_model(path, device), datamodule.dataset("val"), carving=carving,
                                    progress=progress, workers=protocol_workers)
        store_calibration(path, search)
        record = search.record()
        print(f"calibrated {path} on the validation split in {search.seconds:.0f} s: {search.best.describe()} "
              f"(validation IoU {search.uncalibrated_iou:.4f} -> {search.best_iou:.4f})", flush=True)
    return record


def bank_checkpoints(paths, datamodule: SVRDataModule, progress: bool = True) -> Optional[int]:
    """Stores a framing bank of the data module's training split (``svr.inference.framing_bank``:
    how ``svr.infer`` frames a photo whose camera it estimates) in each checkpoint of ``paths``
    whose network has a camera head and that holds none, or one stored before banks kept their
    renders' views (replaced: the views vote for a photo's camera); built once. Returns the bank's
    size, or None where no checkpoint needed one."""
    def needs_bank(path) -> bool:
        model = load_model(path, "cpu")  # reads a stored bank too
        bank = model.framing_bank
        return getattr(model.net, "camera", None) is not None and (bank is None or bank.views is None)

    todo = [p for p in dict.fromkeys(paths) if needs_bank(p)]
    if not todo:
        return None
    datamodule.prepare_split("train", progress=progress)
    started = time.perf_counter()
    try:
        bank = build_framing_bank(datamodule.dataset("train"))
    except ValueError as err:  # e.g. every training silhouette touches the border
        print(f"no framing bank stored ({err}); svr.infer will frame photos by the camera head", flush=True)
        return None
    for p in todo:
        store_framing_bank(p, bank)
    if progress:
        print(f"stored a framing bank of {len(bank)} training renders in {len(todo)} checkpoint(s) "
              f"({time.perf_counter() - started:.0f} s)", flush=True)
    return len(bank)


def score_run(settings: TrainSettings, run: RunFolder, out_dir: Path, split: str = "test", progress: bool = True,
              protocol_workers: int = 0, calibrate: bool = True, recalibrate: bool = False,
              carving: bool = True, device: str = "auto") -> RunScores:
    """Scores a finished run with the benchmark protocol: its last stage's checkpoint, its coarse
    stage's and every baseline (``svr.evaluation.baselines``) on the same images; draws
    ``predictions.png`` and ``meshes/`` into ``out_dir`` (the tables are ``RunScores.write``'s). With
    ``calibrate`` the last stage's checkpoint is calibrated first (``calibrate_checkpoint``; with
    ``recalibrate`` searched again even where one is stored; without ``carving``, a level only) and
    both checkpoints are scored through its calibration; without, none is applied. Predictions run
    on ``device`` ("auto": CUDA when available); the protocol's voxelisation on the CPU, in
    ``protocol_workers`` processes for the calibration search and, where cores are spare, the
    evaluation (``_evaluation_workers``)."""
    dm = instantiate(settings.data)
    dm.prepare_data()
    schedule = list(settings.stage.schedule)
    final_ckpt, coarse_ckpt = run.best_or_final(schedule[-1]), run.best_or_final(schedule[0])
    calibrations = {}
    if calibrate:
        calibrations[schedule[-1]] = calibrate_checkpoint(final_ckpt, dm, progress, again=recalibrate, carving=carving,
                                                          device=device, protocol_workers=protocol_workers)
    bank_checkpoints([final_ckpt], dm, progress)
    model = load_model(final_ckpt, device)
    if not calibrate:
        model = dataclasses.replace(model, calibration=None)
    # The coarse stage's checkpoint goes through the full model's calibration (not a search of its
    # own: 25 s of the demo's 12 minutes), so its row differs from the full model's by the later
    # stages' training alone.
    coarse_model = (model if coarse_ckpt == final_ckpt else
                    dataclasses.replace(load_model(coarse_ckpt, device), calibration=model.calibration))
    kwargs = dict(progress=progress, protocol_workers=_evaluation_workers(protocol_workers, model.device))
    result = evaluate(model, dm, split, **kwargs)  # batches: the data's eval_batch_size
    extra = {}
    if coarse_ckpt != final_ckpt:
        # Only its voxel IoU row is shown: no side-view renders.
        extra["coarse stage alone"] = evaluate(coarse_model, dm, split, side_view_scores=False, **kwargs).table
    result = add_baselines(result, dm, BASELINES, model, progress=progress)
    scene = (dm.shading.scene(effects=("shading",)) if dm.shading is not None else
             renderer.Scene(effects=("shading",), background=(1.0, 1.0, 1.0)))
    pictures = showcase(model, coarse_model, dm.dataset(split), dm.categories, scene, out_dir)
    return RunScores(result, f"ours ({schedule[-1]} stage, {result.output})", extra, calibrations, list(pictures))


def _evaluation_workers(protocol_workers: int, device) -> int:
    """The voxelisation workers the evaluation gets: ``protocol_workers`` where the network leaves
    cores to them (it runs on a GPU, or the workers take at most half the cores), else none. On the
    2-core machine the evaluation of the demo's test split took 39 s without workers and 48 s with
    two (the network's torch threads and the workers contend), while the calibration search, which
    voxelises a score of candidates per prediction, took 23 s with two and 39 s without."""
    cores = os.cpu_count() or 1
    on_gpu = torch.device(device).type == "cuda"
    return protocol_workers if on_gpu or 2 * protocol_workers <= cores else 0


__all__ = ["RunScores", "bank_checkpoints", "calibrate_checkpoint", "score_run"]
