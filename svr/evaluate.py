"""Benchmark evaluation of a checkpoint: per-category 3D IoU in the paper's layout (``python -m svr.evaluate``).

Command line (configs/eval.yaml; hydra overrides)::

    python -m svr.evaluate ckpt_path=RUN/joint/checkpoints/best.ckpt                # procedural test split
    python -m svr.evaluate ckpt_path=X.ckpt data=nmr data.root=/data/NMR_ShapeNet   # the paper's benchmark
    python -m svr.evaluate ckpt_path=X.ckpt split=val compare_coarse=true device=cuda protocol_workers=8

The protocol (SPEC section 5, ``svr.evaluation.metrics``): every one of the 24 views of every object of the
split is one prediction; its SDF grid becomes a marching-cubes mesh, the mesh 32^3 voxels by the
benchmark's rules, and IoU is taken against the object's voxels; a category's IoU is the mean over
its images, the reported mean the unweighted mean over the categories.

It prints the table (categories as columns, mean last; for NMR ShapeNet with the paper's reference
rows) and writes into ``output_dir`` (each file atomically): ``table.md``, ``table.csv``,
``iou.json`` (``{"split", "categories": {name: iou}, "mean", ...}``), ``per_object.csv`` (worst
objects first) and ``per_image.csv``. ``output_dir`` is also hydra's run folder (nothing is made in
the working directory); without it, ``outputs/eval/<time>``. A mistake in the settings or files is
one line ``sdfdiff-evaluate: error: ...`` with exit status 2 (``sdfcommon.tooling.commands``). The
``protocol_workers`` processes die with the command, however it is stopped.

Python API (reused by drivers such as a demo, so there is one implementation of the table; the
report is ``svr.evaluation.tables``'s)::

    result = evaluate(load_model("best.ckpt"), datamodule, split="test")   # svr.inference.prediction.load_model
    print(format_table(result)); write_report(result, "eval_out")         # svr.evaluation.tables

Several processes (one machine or many): start the same command under torchrun or srun; each
process evaluates one contiguous block of the images (no image twice, none left out), the
per-image results are gathered (gloo) into the same table a single process makes, and only rank 0
prints and writes::

    torchrun --standalone --nproc_per_node=4 -m svr.evaluate ckpt_path=X.ckpt output_dir=eval_out
    srun --ntasks=8 python -m svr.evaluate ckpt_path=X.ckpt output_dir=eval_out     (SLURM)

(``distributed=false`` evaluates everything in each process instead.) With GPUs each process takes
the GPU of its local rank. In Python: ``evaluate(..., distributed=True)`` inside an initialised
``torch.distributed`` process group, called by every rank.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import sys
import time
import warnings
from collections import deque
from typing import Optional, Sequence, Union

import numpy as np
import torch

from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.commands import config_bool, config_choice, config_float, config_int, config_ints, config_value, hydra_entry
from sdfcommon.tooling.processes import process_pool

from sdfcommon.tooling.outputs import ensure_output_dir

from svr.data.nmr import NUM_VIEWS, SPLITS, check_view_ids
from svr.distributed import RankInfo, barrier, gather_uneven, local_rank, process_group_from_environment
from svr.evaluation.metrics import voxel_iou, voxels_protocol
from svr.inference.prediction import ModelLike, as_model, load_model, predict_sdf
from svr.evaluation.tables import NMR_CATEGORY_IDS, EvaluationResult, format_iou, format_table, write_report

log = logging.getLogger(__name__)

PathLike = Union[str, os.PathLike]


# ------------------------------------------------------------------------------------------------
# Evaluation


def _protocol_voxels(values: np.ndarray, half_side: float) -> np.ndarray:
    """(B, N, N, N) SDF grids over ``[-half_side, half_side]^3`` -> (B, 32, 32, 32) bool benchmark
    voxels (NMR frame). A top-level function so that worker processes can run it."""
    return voxels_protocol(torch.from_numpy(values), -half_side, half_side).numpy()


def evaluate_objects(model: ModelLike, objects, categories: Sequence[tuple[str, str]], split: str,
                     dataset: str = "", views: Optional[Sequence[int]] = None,
                     max_objects_per_category: Optional[int] = None, batch_size: int = 32, num_workers: int = 0,
                     compare_coarse: bool = False, protocol_workers: int = 0, keep_voxels: bool = False,
                     progress: bool = True, distributed: bool = False,
                     nmr_shapenet: Optional[bool] = None) -> EvaluationResult:
    """Runs the benchmark protocol over the (object, view) images of a split's objects.

    Args:
        model: LoadedModel, SVRNet or checkpoint path (``svr.inference.prediction.as_model``).
        objects: the split's per-object dataset (``svr.data.nmr.NMRDataset``, e.g. ``datamodule.dataset(split)``).
        categories: (id, name) pairs, the order of the dataset's category indices.
        split: the split's name (reported).
        dataset: a description of the data (reported).
        views, max_objects_per_category: thin the evaluation (default: every view of every object,
            the protocol); a thinned run is marked ``full_protocol=False``.
        batch_size: images per forward pass; num_workers: DataLoader workers.
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
        ValueError naming ``distributed`` when it is True without an initialised process group.
    """
    from torch.utils.data import DataLoader
    from tqdm.auto import tqdm

    from svr.data.datamodule import EvalShardSampler, EvalViews
    from svr.data.types import collate_batch

    check_int(batch_size, "batch_size", 1)
    check_int(num_workers, "num_workers", 0)
    check_int(protocol_workers, "protocol_workers", 0)
    m = as_model(model)
    categories = tuple((str(c), str(n)) for c, n in categories)
    items = EvalViews(objects, views, max_objects_per_category)
    with_coarse = bool(compare_coarse) and m.uses_refiner
    if compare_coarse and not m.uses_refiner:
        warnings.warn("compare_coarse: the checkpoint is from the coarse stage (no trained refiner); "
                      "its output already is the coarse SDF", UserWarning, stacklevel=2)
    if m.categories is not None and {c for c, _ in m.categories} != {c for c, _ in categories}:
        warnings.warn(f"the checkpoint was trained on categories {[n for _, n in m.categories]}, the data has "
                      f"{[n for _, n in categories]}", UserWarning, stacklevel=2)
    ranks = _distributed_ranks(distributed)
    shard = EvalShardSampler(len(items), pad=False, rank=ranks.rank, world_size=ranks.world_size)
    loader = DataLoader(items, batch_size=batch_size, sampler=shard, num_workers=num_workers,
                        collate_fn=collate_batch, pin_memory=m.device.type == "cuda")
    pool = process_pool(protocol_workers) if protocol_workers > 0 else None
    cats, objs, vws, ious, ious_c, kept = [], [], [], [], [], []
    pending: deque = deque()

    def finish(bar) -> None:
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
                pred = predict_sdf(m, batch.images[:, 0], batch_size=len(batch))
                grids = [pred.final] + ([pred.coarse] if with_coarse else [])
                values = torch.cat(grids).detach().float().cpu().numpy()
                job = (pool.submit(_protocol_voxels, values, m.half_side) if pool is not None
                       else _protocol_voxels(values, m.half_side))
                pending.append((batch, job))
                while len(pending) > (2 * protocol_workers if pool is not None else 0):
                    finish(bar)
            while pending:
                finish(bar)
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)

    def cat(parts, dtype, shape=()):
        local = np.concatenate(parts).astype(dtype) if parts else np.zeros((0, *shape), dtype)
        return gather_uneven(torch.from_numpy(local)).numpy() if ranks.world_size > 1 else local

    result = EvaluationResult(
        split=split, dataset=dataset, categories=categories,
        is_nmr_shapenet=_is_nmr_shapenet(objects, categories) if nmr_shapenet is None else bool(nmr_shapenet),
        checkpoint=str(m.checkpoint) if m.checkpoint is not None else None, stage=m.stage, output=m.output_name,
        category=cat(cats, np.int64), object_index=cat(objs, np.int64), view=cat(vws, np.int64),
        iou=cat(ious, np.float64), iou_coarse=cat(ious_c, np.float64) if with_coarse else None,
        voxels=cat(kept, bool, (32, 32, 32)) if keep_voxels else None,
        views_per_object=len(items.views),
        full_protocol=len(items.views) == NUM_VIEWS and max_objects_per_category is None,
        seconds=time.perf_counter() - start,
    )
    if len(result.iou) != len(items):
        raise RuntimeError(f"gathered {len(result.iou)} per-image results for {len(items)} images")
    return result


def _is_nmr_shapenet(objects, categories: Sequence[tuple[str, str]]) -> bool:
    """Real NMR ShapeNet: the 13 benchmark ids, and not our procedural data (which uses the same ids)."""
    from svr.data.procedural.generator import is_procedural_dataset

    return bool(categories) and all(c in NMR_CATEGORY_IDS for c, _ in categories) and not (
        hasattr(objects, "root") and is_procedural_dataset(objects.root))


def add_baselines(result: EvaluationResult, datamodule, names: Sequence[str], model: ModelLike,
                  progress: bool = True) -> EvaluationResult:
    """The result with the baselines (``svr.evaluation.baselines``) scored on the same images and split.

    Args:
        datamodule: the evaluated data module (its training split feeds the baselines).
        names: baselines (``svr.evaluation.baselines.BASELINES``); "oracle" is left out on real NMR data.
        model: the evaluated model (the oracle samples the exact shapes on its grid).
    """
    from svr.evaluation.baselines import check_baselines, score_baselines

    names = check_baselines(names)
    if not names:
        return result
    m = as_model(model)
    scores = score_baselines(names, result, datamodule.dataset(result.split), datamodule.dataset("train"),
                             m.half_side, m.grid_resolution, progress=progress)
    return dataclasses.replace(result, baselines={**result.baselines, **scores})


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


def describe_data(datamodule) -> str:
    """A short description of a data module: its kind and folder."""
    from svr.data.datamodule import ProceduralDataModule

    root = getattr(datamodule, "root", None)
    if isinstance(datamodule, ProceduralDataModule):
        return f"procedural ({root})"
    cats = getattr(datamodule, "categories", None) or []
    kind = "NMR ShapeNet" if cats and all(c in NMR_CATEGORY_IDS for c, _ in cats) else "NMR-format data"
    return f"{kind} ({root})"


def evaluate(model: ModelLike, datamodule, split: str = "test", **kwargs) -> EvaluationResult:
    """``evaluate_objects`` on a data module's split (``svr.data.datamodule.NMRDataModule`` or
    ``ProceduralDataModule``; anything with ``categories`` and ``dataset(split)``).

    A procedural dataset is generated if missing; NMR files are converted to memory-mapped ``.npy``
    for this split only (when the data module's ``prepare`` is on). With ``distributed=True`` rank 0
    does that while the others wait.

    Args:
        kwargs: as ``evaluate_objects`` (views, batch_size, compare_coarse, distributed, ...).
    """
    from svr.data.datamodule import ProceduralDataModule
    from svr.data.nmr import prepare_nmr

    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if not hasattr(datamodule, "dataset") or not hasattr(datamodule, "categories"):
        raise TypeError(f"datamodule must have categories and dataset(split) (an NMRDataModule), "
                        f"got {type(datamodule).__name__}")
    if _distributed_ranks(kwargs.get("distributed", False)).is_zero:
        if isinstance(datamodule, ProceduralDataModule):
            datamodule.prepare_data()
        elif getattr(datamodule, "prepare", False):
            prepare_nmr(datamodule.root, getattr(datamodule, "prepared_dir", None),
                        [c for c, _ in datamodule.categories], (split,), progress=kwargs.get("progress", True))
    if kwargs.get("distributed", False):
        barrier()
    return evaluate_objects(model, datamodule.dataset(split), datamodule.categories, split,
                            describe_data(datamodule), **kwargs)


# ------------------------------------------------------------------------------------------------
# Entry point

DISTRIBUTED_MODES = ("auto", True, False)


def _device_of_rank(device, ranks: RankInfo):
    """With several processes, "auto"/"cuda" become this process's GPU (its local rank)."""
    if ranks.world_size > 1 and str(device) in ("auto", "cuda") and torch.cuda.is_available():
        return f"cuda:{local_rank() % torch.cuda.device_count()}"
    return device


def run(cfg) -> EvaluationResult:
    """The body of ``main``: a composed configs/eval.yaml -> evaluate, print, write.

    ``distributed`` ("auto", the default): join the process group that torchrun or srun describe
    when they started several processes; each evaluates its share, rank 0 prints and writes.
    """
    mode = config_choice(cfg, "distributed", DISTRIBUTED_MODES)
    if mode is False:
        return _run(cfg, RankInfo())
    with process_group_from_environment(timeout_s=config_float(cfg, "distributed_timeout_s", minimum=1)) as ranks:
        return _run(cfg, ranks)


def _optional_int(cfg, key: str, minimum: int) -> Optional[int]:
    return None if config_value(cfg, key) is None else config_int(cfg, key, minimum=minimum)


def _run(cfg, ranks: RankInfo) -> EvaluationResult:
    from hydra.core.hydra_config import HydraConfig
    from hydra.utils import instantiate


    split = config_choice(cfg, "split", SPLITS)
    views = config_ints(cfg, "views", allow_null=True)
    settings = dict(views=None if views is None else list(check_view_ids(views, allow_empty=False)),
                    max_objects_per_category=_optional_int(cfg, "max_objects_per_category", 1),
                    batch_size=config_int(cfg, "batch_size", minimum=1),
                    num_workers=config_int(cfg, "num_workers", minimum=0),
                    compare_coarse=config_bool(cfg, "compare_coarse"),
                    protocol_workers=config_int(cfg, "protocol_workers", minimum=0),
                    progress=config_bool(cfg, "progress") and ranks.is_zero,
                    distributed=ranks.world_size > 1)
    baselines = config_value(cfg, "baselines")
    # The output folder is output_dir, else hydra's run folder (eval.yaml makes them one); checked
    # before the long run.
    out = config_value(cfg, "output_dir") or HydraConfig.get().runtime.output_dir
    folder = ensure_output_dir(out, "output_dir") if ranks.is_zero else None
    datamodule = instantiate(cfg.data)
    model = load_model(config_value(cfg, "ckpt_path"), _device_of_rank(config_value(cfg, "device"), ranks))
    say = print if ranks.is_zero else (lambda *args, **kwargs: None)
    say(f"evaluating {model.checkpoint} ({model.stage} stage, {model.output_name} output) on {model.device}"
        + (f" and {ranks.world_size - 1} more processes" if ranks.world_size > 1 else ""))
    say(f"data: {describe_data(datamodule)}; split: {split}")
    result = evaluate(model, datamodule, split, **settings)
    if not ranks.is_zero:
        return result
    result = add_baselines(result, datamodule, baselines, model, progress=config_bool(cfg, "progress"))
    print()
    print(format_table(result))
    files = write_report(result, folder)
    print(f"split '{result.split}': mean IoU {format_iou(result.mean)} over {len(result.present)} categories, "
          f"{len(result.iou)} images, {result.seconds:.1f} s")
    print("wrote " + ", ".join(str(p) for p in files.values()))
    return result


_main = hydra_entry("sdfdiff-evaluate", "eval", run)


def main() -> None:
    """``python -m svr.evaluate`` / ``sdfdiff-evaluate``: hydra reads configs/eval.yaml and the overrides."""
    from svr.distributed import launch_rank_is_zero

    if not launch_rank_is_zero():
        # As Lightning does for its DDP processes: one process writes hydra's .hydra/ folder.
        sys.argv.append("hydra.output_subdir=null")
    _main()


if __name__ == "__main__":
    main()


__all__ = ["evaluate", "evaluate_objects", "add_baselines", "describe_data", "run", "main"]
