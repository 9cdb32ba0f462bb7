"""The single-view benchmark run on a loaded model: every (object, view) image of a split is one
prediction, its SDF grid becomes a marching-cubes mesh, the mesh 32^3 voxels by the benchmark's
rules (``svr.evaluation.metrics``) and IoU is taken against the object's voxels, in one process or
shared among the ranks of a ``torch.distributed`` group; ``add_baselines`` scores the baselines on the
same images. The functions take a ``LoadedModel`` (``svr.inference.prediction.load_model``) and a data
module whose split is on disk (``prepare_split``, the command's explicit step); the report is
``svr.evaluation.tables``'s: ``prepare_split(dm, "test")``, ``result = evaluate(model, dm, "test")``,
``write_report(result, folder)``."""
from __future__ import annotations

import dataclasses
import time
import warnings
from collections import deque
from typing import Any, Optional, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm.auto import tqdm

from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.processes import process_pool
from svr.data.datamodule import EvalShardSampler, EvalViews, ProceduralDataModule
from svr.data.nmr import NUM_VIEWS, SPLITS, prepare_nmr
from svr.data.procedural.generator import is_procedural_dataset
from svr.data.types import collate_batch
from svr.distributed import RankInfo, gather_uneven
from svr.evaluation.baselines import check_baselines, score_baselines
from svr.evaluation.metrics import voxel_iou, voxels_protocol
from svr.evaluation.tables import NMR_CATEGORY_IDS, EvaluationResult
from svr.inference.prediction import LoadedModel, check_model, predict_sdf


def _protocol_voxels(values: np.ndarray, half_side: float) -> np.ndarray:
    """(B, N, N, N) SDF grids over ``[-half_side, half_side]^3`` -> (B, 32, 32, 32) bool benchmark
    voxels (NMR frame). A top-level function so that worker processes can run it."""
    return voxels_protocol(torch.from_numpy(values), -half_side, half_side).numpy()


def evaluate_objects(model: LoadedModel, objects, categories: Sequence[tuple[str, str]], split: str,
                     batch_size: int, dataset: str = "", views: Optional[Sequence[int]] = None,
                     max_objects_per_category: Optional[int] = None, num_workers: int = 0,
                     compare_coarse: bool = False, protocol_workers: int = 0, keep_voxels: bool = False,
                     progress: bool = True, distributed: bool = False,
                     nmr_shapenet: Optional[bool] = None) -> EvaluationResult:
    """Runs the benchmark protocol over the (object, view) images of a split's objects.

    Args:
        model: the network and its checkpoint's facts (``svr.inference.prediction.load_model``).
        objects: the split's per-object dataset (``svr.data.nmr.NMRDataset``, e.g. ``datamodule.dataset(split)``).
        categories: (id, name) pairs, the order of the dataset's category indices.
        split: the split's name (reported).
        batch_size: images per forward pass.
        dataset: a description of the data (reported).
        views, max_objects_per_category: thin the evaluation (default: every view of every object,
            the protocol); a thinned run is marked ``full_protocol=False``.
        num_workers: DataLoader workers.
        compare_coarse: also score the coarse SDF (the refiner's gain).
        protocol_workers: processes for the CPU-bound mesh voxelisation (0: in this process); they
            die with this process (``sdfcommon.tooling.processes.process_pool``), killed or not.
        keep_voxels: keep every predicted voxel grid in the result (32 KiB per image).
        progress: a tqdm progress bar over the images.
        distributed: share the images among the ranks of the initialised default process group
            (``torch.distributed``): this process evaluates its contiguous block of them
            (``svr.distributed.shard_indices``, without padding), then every rank's per-image
            results are gathered in rank order, which is the single-process order. A collective:
            every rank must call it with the same arguments; every rank returns the whole result.
        nmr_shapenet: whether the data is real NMR ShapeNet (the paper's reference rows apply);
            None: when every category id is an NMR ShapeNet id and ``objects`` is not a generated
            procedural dataset.
    Raises:
        TypeError naming ``model`` unless it is a LoadedModel; ValueError naming ``distributed``
        when it is True without an initialised process group, or the setting out of range.
    """
    check_model(model)
    check_int(batch_size, "batch_size", 1)
    check_int(num_workers, "num_workers", 0)
    check_int(protocol_workers, "protocol_workers", 0)
    ranks = _distributed_ranks(distributed)
    categories = tuple((str(c), str(n)) for c, n in categories)
    items = EvalViews(objects, views, max_objects_per_category)
    with_coarse = bool(compare_coarse) and model.uses_refiner
    if compare_coarse and not model.uses_refiner:
        warnings.warn("compare_coarse: the checkpoint is from the coarse stage (no trained refiner); "
                      "its output already is the coarse SDF", UserWarning, stacklevel=2)
    if model.categories is not None and {c for c, _ in model.categories} != {c for c, _ in categories}:
        warnings.warn(f"the checkpoint was trained on categories {[n for _, n in model.categories]}, the data has "
                      f"{[n for _, n in categories]}", UserWarning, stacklevel=2)
    shard = EvalShardSampler(len(items), pad=False, rank=ranks.rank, world_size=ranks.world_size)
    loader = DataLoader(items, batch_size=batch_size, sampler=shard, num_workers=num_workers,
                        collate_fn=collate_batch, pin_memory=model.device.type == "cuda")
    pool = process_pool(protocol_workers) if protocol_workers > 0 else None
    cats, objs, vws, ious, ious_c, kept = [], [], [], [], [], []
    pending: deque = deque()

    def finish(bar: Any) -> None:
        batch, job = pending.popleft()
        vox = job.result() if pool is not None else job
        b = len(batch)
        gt = batch.voxels.cpu()
        ious.append(voxel_iou(torch.from_numpy(vox[:b]), gt).numpy())
        if with_coarse:
            ious_c.append(voxel_iou(torch.from_numpy(vox[b:]), gt).numpy())
        if keep_voxels:
            kept.append(vox[:b])
        cats.append(batch.category.numpy())
        objs.append(batch.object_index.numpy())
        vws.append(batch.view_ids[:, 0].numpy())
        bar.update(b)

    start = time.perf_counter()
    try:
        with tqdm(total=len(shard), desc=f"evaluate {split}", unit="img", disable=not progress) as bar:
            for batch in loader:
                pred = predict_sdf(model, batch.images[:, 0], batch_size=len(batch), views=batch.view_ids[:, 0])
                grids = [pred.final] + ([pred.coarse] if with_coarse else [])
                values = torch.cat(grids).detach().float().cpu().numpy()
                job = (pool.submit(_protocol_voxels, values, model.half_side) if pool is not None
                       else _protocol_voxels(values, model.half_side))
                pending.append((batch, job))
                while len(pending) > (2 * protocol_workers if pool is not None else 0):
                    finish(bar)
            while pending:
                finish(bar)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)

    def cat(parts: list, dtype: Any, shape: tuple = ()) -> np.ndarray:
        local = np.concatenate(parts).astype(dtype) if parts else np.zeros((0, *shape), dtype)
        return gather_uneven(torch.from_numpy(local)).numpy() if ranks.world_size > 1 else local

    result = EvaluationResult(
        split=split, dataset=dataset, categories=categories,
        is_nmr_shapenet=_is_nmr_shapenet(objects, categories) if nmr_shapenet is None else bool(nmr_shapenet),
        checkpoint=str(model.checkpoint) if model.checkpoint is not None else None, stage=model.stage,
        output=model.output_name,
        category=cat(cats, np.int64), object_index=cat(objs, np.int64), view=cat(vws, np.int64),
        iou=cat(ious, np.float64), iou_coarse=cat(ious_c, np.float64) if with_coarse else None,
        voxels=cat(kept, bool, (32, 32, 32)) if keep_voxels else None,
        views_per_object=len(items.views),
        full_protocol=len(items.views) == NUM_VIEWS and max_objects_per_category is None,
        seconds=time.perf_counter() - start,
        calibration=(model.calibration.describe() if model.calibration is not None
                     and not model.calibration.is_identity else None),
    )
    if len(result.iou) != len(items):
        raise RuntimeError(f"gathered {len(result.iou)} per-image results for {len(items)} images")
    return result


def _is_nmr_shapenet(objects, categories: Sequence[tuple[str, str]]) -> bool:
    """Real NMR ShapeNet: the 13 benchmark ids, and not our procedural data (which uses the same ids)."""
    return bool(categories) and all(c in NMR_CATEGORY_IDS for c, _ in categories) and not (
        hasattr(objects, "root") and is_procedural_dataset(objects.root))


def _distributed_ranks(distributed: bool) -> RankInfo:
    """The process group's RankInfo when ``distributed``, else a single process."""
    if not isinstance(distributed, bool):
        raise TypeError(f"distributed must be a bool, got {type(distributed).__name__}")
    if not distributed:
        return RankInfo()
    if not torch.distributed.is_available() or not torch.distributed.is_initialized():
        raise ValueError("distributed=True needs an initialised torch.distributed process group "
                         "(launch with torchrun or srun; the command line joins it by itself)")
    return RankInfo.current()


def _check_datamodule(datamodule) -> None:
    if not hasattr(datamodule, "dataset") or not hasattr(datamodule, "categories"):
        raise TypeError(f"datamodule must have categories and dataset(split) (an NMRDataModule), "
                        f"got {type(datamodule).__name__}")


def _check_split(split: str) -> None:
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")


def prepare_split(datamodule, split: str, progress: bool = True) -> None:
    """Puts a data module's split on disk before an evaluation reads it: a procedural dataset is
    generated when missing; NMR files are converted to memory-mapped ``.npy`` for this split only
    (when the data module's ``prepare`` is on). A command's explicit step, on one process (rank 0)
    while the others wait."""
    _check_split(split)
    _check_datamodule(datamodule)
    if isinstance(datamodule, ProceduralDataModule):
        datamodule.prepare_data()
    elif getattr(datamodule, "prepare", False):
        prepare_nmr(datamodule.root, getattr(datamodule, "prepared_dir", None),
                    [c for c, _ in datamodule.categories], (split,), progress=progress)


def evaluate(model: LoadedModel, datamodule, split: str = "test", batch_size: Optional[int] = None,
             distributed: bool = False, **kwargs: Any) -> EvaluationResult:
    """``evaluate_objects`` on a data module's split (``svr.data.datamodule.NMRDataModule`` or
    ``ProceduralDataModule``; anything with ``categories``, ``eval_batch_size`` and ``dataset(split)``)
    whose files are on disk (``prepare_split``).

    Args:
        batch_size: images per forward pass; None: the data module's ``eval_batch_size``.
        distributed: as ``evaluate_objects``'s.
        kwargs: as ``evaluate_objects``'s (views, compare_coarse, protocol_workers, progress, ...).
    """
    check_model(model)
    _check_split(split)
    _check_datamodule(datamodule)
    _distributed_ranks(distributed)  # refused before the data is opened
    return evaluate_objects(model, datamodule.dataset(split), datamodule.categories, split,
                            datamodule.eval_batch_size if batch_size is None else batch_size,
                            describe_data(datamodule), distributed=distributed, **kwargs)


def add_baselines(result: EvaluationResult, datamodule, names: Sequence[str], model: LoadedModel,
                  progress: bool = True) -> EvaluationResult:
    """The result with the baselines (``svr.evaluation.baselines``) scored on the same images and split.

    Args:
        datamodule: the evaluated data module (its training split feeds the baselines).
        names: baselines (``svr.evaluation.baselines.BASELINES``); "oracle" is left out on real NMR data.
        model: the evaluated model (the oracle samples the exact shapes on its grid).
    """
    check_model(model)
    names = check_baselines(names)
    if not names:
        return result
    scores = score_baselines(names, result, datamodule.dataset(result.split), datamodule.dataset("train"),
                             model.half_side, model.grid_resolution, progress=progress)
    return dataclasses.replace(result, baselines={**result.baselines, **scores})


def describe_data(datamodule) -> str:
    """A short description of a data module: its kind and folder."""
    root = getattr(datamodule, "root", None)
    if isinstance(datamodule, ProceduralDataModule):
        return f"procedural ({root})"
    cats = getattr(datamodule, "categories", None) or []
    kind = "NMR ShapeNet" if cats and all(c in NMR_CATEGORY_IDS for c, _ in cats) else "NMR-format data"
    return f"{kind} ({root})"


__all__ = ["evaluate", "evaluate_objects", "add_baselines", "describe_data", "prepare_split"]
