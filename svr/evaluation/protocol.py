"""The single-view benchmark run on a loaded model: every (object, view) image of a split is one
prediction, its SDF grid becomes a marching-cubes mesh, the mesh 32^3 voxels by the benchmark's
rules (``svr.nmr.metrics``) and IoU is taken against the object's voxels, in one process or
shared among the ranks of a ``torch.distributed`` group; ``add_baselines`` scores the baselines on the
same images. The functions take a ``LoadedModel`` (``svr.inference.prediction.load_model``) and a data
module whose split is on disk (``SVRDataModule.prepare_split``, the command's explicit step); the
report is ``svr.evaluation.tables``'s: ``dm.prepare_split("test")``, ``result = evaluate(model, dm, "test")``,
``write_report(result, folder)``."""
from __future__ import annotations

import dataclasses
import functools
import time
import warnings
from typing import Any, Optional, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm.auto import tqdm

from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.processes import OrderedJobs
from svr.data.datamodules import SVRDataModule
from svr.data.datasets import EvalViews
from svr.data.samplers import EvalShardSampler
from svr.data.types import SVRBatch, collate_batch
from svr.distributed import RankInfo, gather_uneven
from svr.evaluation.baselines import check_baselines, score_baselines_and_sides
from svr.evaluation.tables import EvaluationResult
from svr.inference.prediction import LoadedModel, check_model, predict_sdf
from svr.nmr.format import NUM_VIEWS, check_split, is_nmr_shapenet
from svr.nmr.metrics import voxel_iou, voxels_protocol
from svr.nmr.side_views import side_view_iou, side_views


def _protocol_voxels(values: np.ndarray, half_side: float) -> np.ndarray:
    """(B, N, N, N) SDF grids over ``[-half_side, half_side]^3`` -> (B, 32, 32, 32) bool benchmark
    voxels (NMR frame). A top-level function so that worker processes can run it."""
    return voxels_protocol(torch.from_numpy(values), -half_side, half_side).numpy()


def evaluate_objects(model: LoadedModel, objects, categories: Sequence[tuple[str, str]], split: str,
                     batch_size: int, dataset: str = "", views: Optional[Sequence[int]] = None,
                     max_objects_per_category: Optional[int] = None, num_workers: int = 0,
                     compare_coarse: bool = False, protocol_workers: int = 0, keep_voxels: bool = False,
                     progress: bool = True, distributed: bool = False,
                     nmr_shapenet: Optional[bool] = None, side_view_scores: bool = True) -> EvaluationResult:
    """Runs the benchmark protocol over the (object, view) images of a split's objects.

    Args:
        model: the network and its checkpoint's facts (``svr.inference.prediction.load_model``).
        objects: the split's per-object dataset (``svr.data.datasets.NMRDataset``, e.g. ``datamodule.dataset(split)``).
        categories: (id, name) pairs, the order of the dataset's category indices.
        split: the split's name (reported).
        batch_size: images per forward pass.
        dataset: a description of the data (reported).
        views, max_objects_per_category: thin the evaluation (default: every view of every object,
            the protocol); a thinned run is marked ``full_protocol=False``.
        num_workers: DataLoader workers.
        compare_coarse: also score the coarse SDF (the refiner's gain).
        protocol_workers: processes for the CPU-bound mesh voxelisation (0: in this process); they
            die with this process (``sdfcommon.tooling.processes.OrderedJobs``), killed or not.
        keep_voxels: keep every predicted voxel grid in the result (32 KiB per image).
        progress: a tqdm progress bar over the images.
        distributed: share the images among the ranks of the initialised default process group
            (``torch.distributed``): this process evaluates its contiguous block of them
            (``svr.distributed.shard_indices``, without padding), then every rank's per-image
            results are gathered in rank order, which is the single-process order. A collective:
            every rank must call it with the same arguments; every rank returns the whole result.
        nmr_shapenet: whether the data is real NMR ShapeNet (the paper's reference rows apply);
            None: as ``svr.nmr.format.is_nmr_shapenet`` tells from the folder (generated or built
            data is not).
        side_view_scores: also score each prediction's silhouettes from the views 90 degrees either
            side of its input view against their stored alpha (``svr.nmr.side_views``).
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
    if len(items) == 0:
        raise ValueError(f"split {split!r} of {getattr(objects, 'root', None) or dataset or 'the data'} holds no "
                         f"objects of the categories {', '.join(n for _, n in categories)}: nothing to evaluate")
    with_coarse = _scores_coarse(model, compare_coarse)
    _warn_if_other_categories(model, categories)
    shard = EvalShardSampler(len(items), pad=False, rank=ranks.rank, world_size=ranks.world_size)
    loader = DataLoader(items, batch_size=batch_size, sampler=shard, num_workers=num_workers,
                        collate_fn=collate_batch, pin_memory=model.device.type == "cuda")
    start = time.perf_counter()
    scores = _ImageScores(with_coarse, keep_voxels, objects if side_view_scores else None)
    with tqdm(total=len(shard), desc=f"evaluate {split}", unit="img", disable=not progress) as bar:
        _score_batches(model, loader, scores, protocol_workers, bar)
    gather = functools.partial(_gathered, world_size=ranks.world_size)
    result = EvaluationResult(
        split=split, dataset=dataset, categories=categories,
        is_nmr_shapenet=(is_nmr_shapenet(objects.root, [c for c, _ in categories]) if nmr_shapenet is None
                         else bool(nmr_shapenet)),
        checkpoint=str(model.checkpoint) if model.checkpoint is not None else None, stage=model.stage,
        output=model.output_name,
        category=gather(scores.category, np.int64), object_index=gather(scores.object_index, np.int64),
        view=gather(scores.view, np.int64), iou=gather(scores.iou, np.float64),
        iou_coarse=gather(scores.iou_coarse, np.float64) if with_coarse else None,
        side_iou=gather(scores.side_iou, np.float64) if side_view_scores else None,
        voxels=gather(scores.voxels, bool, (32, 32, 32)) if keep_voxels else None,
        views_per_object=len(items.views),
        full_protocol=len(items.views) == NUM_VIEWS and max_objects_per_category is None,
        seconds=time.perf_counter() - start,
        calibration=(model.calibration.describe() if model.calibration is not None
                     and not model.calibration.is_identity else None),
        reads=model_reads(model),
    )
    if len(result.iou) != len(items):
        raise RuntimeError(f"gathered {len(result.iou)} per-image results for {len(items)} images")
    return result


def model_reads(model: LoadedModel) -> str:
    """What a model's scored predictions read besides the input image: "the input camera" (the NMR
    view index) where its network has a pixel-aligned head or a shape prior (which compares the
    input with the training objects' silhouettes in its view) or its calibration carves, else
    "nothing"."""
    why = (["its pixel-aligned head"] if model.net.needs_views else []) + (
        ["its shape prior"] if getattr(model.net, "prior", None) is not None else []) + (
        ["its calibration's carving"] if model.calibration is not None and model.calibration.carve != "none" else [])
    listed = " and ".join(why) if len(why) < 3 else f"{', '.join(why[:-1])} and {why[-1]}"
    return f"the input camera ({listed})" if why else "nothing"


def _scores_coarse(model: LoadedModel, compare_coarse: bool) -> bool:
    """Whether the coarse SDF is scored beside the output: asked for, and the checkpoint has a trained
    refiner (else a warning: its output already is the coarse SDF)."""
    if compare_coarse and not model.uses_refiner:
        warnings.warn("compare_coarse: the checkpoint is from the coarse stage (no trained refiner); "
                      "its output already is the coarse SDF", UserWarning, stacklevel=3)
    return bool(compare_coarse) and model.uses_refiner


def _warn_if_other_categories(model: LoadedModel, categories: Sequence[tuple[str, str]]) -> None:
    """Warns when the data holds categories the checkpoint was not trained on (when it records
    its own): their scores measure generalisation to unseen categories, not the benchmark."""
    if model.categories is None:
        return
    trained = {c for c, _ in model.categories}
    unseen = [n for c, n in categories if c not in trained]
    if unseen:
        warnings.warn(f"the checkpoint was trained on categories {', '.join(n for _, n in model.categories)}; "
                      f"the data's {', '.join(unseen)} {'is' if len(unseen) == 1 else 'are'} not among them, so "
                      f"the scores there are of unseen categories", UserWarning, stacklevel=3)


class _ImageScores:
    """Per-image results of this process, batch by batch, in the loader's order: category, object
    and view of each image, the IoU of its predicted voxels (and of the coarse SDF's), the voxels,
    and with ``objects`` (the split's dataset) the side-view silhouette IoU of its prediction."""

    def __init__(self, with_coarse: bool, keep_voxels: bool, objects=None):
        self.with_coarse, self.keep_voxels, self.objects = with_coarse, keep_voxels, objects
        self.category, self.object_index, self.view, self.iou, self.iou_coarse, self.voxels = [], [], [], [], [], []
        self.side_iou = []

    def score_sides(self, batch: SVRBatch, final: torch.Tensor, half_side: float) -> None:
        """The side-view silhouette IoU of one batch's final SDF grids (B, N, N, N)."""
        if self.objects is None:
            return
        sides = side_views(batch.view_ids[:, 0]).tolist()
        alpha = np.stack([self.objects.images_uint8(int(self.objects.offsets[c]) + o, s)[:, 3] for c, o, s in
                          zip(batch.category.tolist(), batch.object_index.tolist(), sides)])
        self.side_iou.append(side_view_iou(final, half_side, batch.view_ids[:, 0], alpha).numpy())

    def add(self, batch: SVRBatch, voxels: np.ndarray) -> None:
        """One batch's (B, ...) items and its predicted voxels: (B, 32, 32, 32) bool, followed by the
        coarse SDF's B when ``with_coarse``."""
        b = len(batch)
        gt = batch.voxels.cpu()
        self.iou.append(voxel_iou(torch.from_numpy(voxels[:b]), gt).numpy())
        if self.with_coarse:
            self.iou_coarse.append(voxel_iou(torch.from_numpy(voxels[b:]), gt).numpy())
        if self.keep_voxels:
            self.voxels.append(voxels[:b])
        self.category.append(batch.category.numpy())
        self.object_index.append(batch.object_index.numpy())
        self.view.append(batch.view_ids[:, 0].numpy())


def _score_batches(model: LoadedModel, loader: DataLoader, scores: _ImageScores, protocol_workers: int,
                   bar: Any) -> None:
    """Predicts every batch of ``loader`` and voxelises the predictions by the protocol into
    ``scores``. With ``protocol_workers`` the voxelisation runs in worker processes while the next
    batches are predicted (at most two batches per worker wait), each worker with one torch thread
    (the voxelisation is single-threaded: more threads only contend for the cores); they die with
    this process (``sdfcommon.tooling.processes.OrderedJobs``), killed or not."""

    def finish(batch: SVRBatch, voxels: np.ndarray) -> None:
        scores.add(batch, voxels)
        bar.update(len(batch))

    with OrderedJobs(protocol_workers, finish, torch.set_num_threads, (1,)) as jobs:
        for batch in loader:
            pred = predict_sdf(model, batch.images[:, 0], batch_size=len(batch), views=batch.view_ids[:, 0])
            scores.score_sides(batch, pred.final, model.half_side)
            grids = [pred.final] + ([pred.coarse] if scores.with_coarse else [])
            jobs.submit(_protocol_voxels, torch.cat(grids).detach().float().cpu().numpy(), model.half_side,
                        tag=batch)


def _gathered(parts: list, dtype: Any, shape: tuple = (), world_size: int = 1) -> np.ndarray:
    """This process's parts concatenated, then every rank's gathered in rank order (one process:
    its own)."""
    local = np.concatenate(parts).astype(dtype) if parts else np.zeros((0, *shape), dtype)
    return gather_uneven(torch.from_numpy(local)).numpy() if world_size > 1 else local


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
    if not isinstance(datamodule, SVRDataModule):
        raise TypeError(f"datamodule must be an SVRDataModule (NMRDataModule or ProceduralDataModule), "
                        f"got {type(datamodule).__name__}")


def evaluate(model: LoadedModel, datamodule, split: str = "test", batch_size: Optional[int] = None,
             distributed: bool = False, **kwargs: Any) -> EvaluationResult:
    """``evaluate_objects`` on a data module's split (``svr.data.datamodules.NMRDataModule`` or
    ``ProceduralDataModule``) whose files are on disk (``SVRDataModule.prepare_split``).

    Args:
        batch_size: images per forward pass; None: the data module's ``eval_batch_size``.
        distributed: as ``evaluate_objects``'s.
        kwargs: as ``evaluate_objects``'s (views, compare_coarse, protocol_workers, progress, ...).
    """
    check_model(model)
    check_split(split)
    _check_datamodule(datamodule)
    _distributed_ranks(distributed)  # refused before the data is opened
    return evaluate_objects(model, datamodule.dataset(split), datamodule.categories, split,
                            datamodule.eval_batch_size if batch_size is None else batch_size,
                            datamodule.describe(), distributed=distributed, **kwargs)


def add_baselines(result: EvaluationResult, datamodule, names: Sequence[str], model: LoadedModel,
                  progress: bool = True) -> EvaluationResult:
    """The result with the baselines (``svr.evaluation.baselines``) scored on the same images and split,
    and from the side (``SIDE_BASELINES``) where the result's side views are scored.

    Args:
        datamodule: the evaluated data module (its training split feeds the baselines).
        names: baselines (``svr.evaluation.baselines.BASELINES``); "oracle" is left out on real NMR data.
        model: the evaluated model (the oracle samples the exact shapes on its grid).
    """
    check_model(model)
    names = check_baselines(names)
    if not names:
        return result
    scores = score_baselines_and_sides(names, result, datamodule.dataset(result.split), datamodule.dataset("train"),
                                       model.half_side, model.grid_resolution, progress=progress,
                                       sides=result.side_iou is not None)
    return dataclasses.replace(result, baselines={**result.baselines, **scores.iou},
                               baseline_side_iou={**result.baseline_side_iou, **scores.side_iou})


__all__ = ["evaluate", "evaluate_objects", "add_baselines", "model_reads"]
