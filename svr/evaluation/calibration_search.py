"""Chooses a checkpoint's calibration (``svr.inference.calibration``) on the validation split and
stores it in the checkpoint: every combination of a carving (none, the input view's silhouette, and
with the network's mirror axis also its mirror image; the exact cone unless ``carve_levels_voxels``
says more) and a level of the network's surface (0 to 1.5 voxels of its grid, in quarter voxels)
is scored by the benchmark protocol on the same predictions, and the best mean over categories of
per-category mean IoU wins. Both carvings project the grid into the input view with the dataset's
camera (the mirror carving's cone is the input view's cone, mirrored), so ``carving=False`` keeps
only the level: a calibration that reads nothing but the image. It reads only the validation
split's images, cameras and voxels, which NMR data holds; the test split is never seen."""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader
from tqdm.auto import tqdm

from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.outputs import write_torch
from sdfcommon.tooling.processes import OrderedJobs
from svr.data.datasets import EvalViews
from svr.data.types import collate_batch
from svr.inference.calibration import Calibration
from svr.inference.checkpoints import load_checkpoint
from svr.inference.prediction import LoadedModel, check_model, predict_sdf
from svr.models.checkpoint_layout import CHECKPOINT_KEY
from svr.nmr.metrics import voxel_iou, voxels_protocol
from svr.nmr.voxels import clip_to_box

LEVELS_VOXELS = (0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)
CARVE_LEVELS_VOXELS = (0.0,)
VIEWS = (0, 6, 12, 18)


@dataclass(frozen=True)
class CalibrationSearch:
    """The chosen calibration and what every candidate scored.

    Attributes:
        best: the candidate with the highest score (the first such in ``rows``' order).
        rows: per candidate ``{"carve", "level", "level_voxels", "carve_level", "carve_level_voxels",
            "iou"}``, iou the mean over categories of the per-category mean protocol IoU on the
            images searched.
        split, images, objects_per_category, views, seconds: what was searched and how long it took.
        carving: whether the carvings (which read the input camera) were candidates.
    """

    best: Calibration
    rows: tuple[dict, ...]
    split: str
    images: int
    objects_per_category: Optional[int]
    views: tuple[int, ...]
    seconds: float
    carving: bool = True

    @property
    def uncalibrated_iou(self) -> float:
        return float(self.rows[0]["iou"])

    @property
    def best_iou(self) -> float:
        return max(float(r["iou"]) for r in self.rows)

    def record(self) -> dict:
        """What ``store_calibration`` keeps in the checkpoint."""
        return {"settings": self.best.to_dict(), "split": self.split, "images": self.images,
                "objects_per_category": self.objects_per_category, "views": list(self.views),
                "carving": self.carving,
                "uncalibrated_iou": self.uncalibrated_iou, "calibrated_iou": self.best_iou,
                "candidates": [dict(r) for r in self.rows]}


def mirror_axis_of(model: LoadedModel) -> Optional[int]:
    """The network's mirror axis (its pixel-aligned head's), or None."""
    axis = getattr(getattr(model.net, "local", None), "mirror_axis", None)
    return int(axis) if axis in (0, 1, 2) else None


def _score_candidates(raw: torch.Tensor, cone: Optional[torch.Tensor], gt: torch.Tensor,
                      candidates: Sequence[Calibration], half_side: float) -> list[np.ndarray]:
    """Per candidate (all with the carving whose field is ``cone``), the (B,) protocol IoU of the
    calibrated grids ``raw`` (B, N, N, N) against ``gt``. A top-level function so that worker
    processes can run it."""
    out = []
    for cal in candidates:
        values = clip_to_box(cal.apply(raw, cone), -half_side, half_side)  # as predict_sdf closes them
        out.append(voxel_iou(voxels_protocol(values, -half_side, half_side), gt).numpy())
    return out


def search_calibration(model: LoadedModel, objects, split: str = "val", views: Sequence[int] = VIEWS,
                       max_objects_per_category: Optional[int] = 20, batch_size: int = 32,
                       levels_voxels: Sequence[float] = LEVELS_VOXELS,
                       carve_levels_voxels: Sequence[float] = CARVE_LEVELS_VOXELS,
                       carving: bool = True, progress: bool = True, workers: int = 0) -> CalibrationSearch:
    """Scores every candidate calibration on a split's images (``EvalViews``) and returns the best.

    Args:
        model: the network (its own calibration, if any, is not applied to the predictions searched).
        objects: the split's per-object dataset (``datamodule.dataset(split)``), usually validation.
        split: its name (recorded).
        views, max_objects_per_category: which images (default: 4 views of at most 20 objects per category).
        levels_voxels: the levels tried, in voxels of the network's grid (>= 0).
        carve_levels_voxels: the carving cone's levels tried with each carving, in voxels.
        carving: try the carvings (they read the input camera); False: only "none", at each level.
        workers: processes for the CPU-bound protocol voxelisation (0: this one), one torch thread
            each; each batch's carvings are scored in parallel while the next batch is predicted.
            Same result.
    """
    check_model(model)
    check_int(batch_size, "batch_size", minimum=1)
    check_int(workers, "workers", minimum=0)
    if not levels_voxels or any(not np.isfinite(v) or v < 0 for v in levels_voxels):
        raise ValueError(f"levels_voxels must be non-negative numbers, got {list(levels_voxels)}")
    if not carve_levels_voxels or any(not np.isfinite(v) for v in carve_levels_voxels):
        raise ValueError(f"carve_levels_voxels must be finite numbers, got {list(carve_levels_voxels)}")
    items = EvalViews(objects, views, max_objects_per_category)
    loader = DataLoader(items, batch_size=batch_size, collate_fn=collate_batch)
    hs, n = model.half_side, model.grid_resolution
    voxel = 2.0 * hs / (n - 1)
    axis = mirror_axis_of(model)
    carves = [("none", None)]
    if carving:
        carves += [("view", None)] + ([("view+mirror", axis)] if axis is not None else [])
    candidates = [Calibration(carve=c, mirror_axis=a, level=round(lv * voxel, 6), carve_level=round(cv * voxel, 6))
                  for c, a in carves for cv in (carve_levels_voxels if c != "none" else (0.0,))
                  for lv in levels_voxels]
    scores: list[list[np.ndarray]] = [[] for _ in candidates]
    by_carve = {c: [k for k, cal in enumerate(candidates) if cal.carve == c] for c, _ in carves}
    cats = []

    def finish(tag: tuple[list[int], int], ious: list[np.ndarray]) -> None:
        ks, count = tag
        for k, iou in zip(ks, ious):
            scores[k].append(iou)
        bar.update(count)

    start = time.perf_counter()
    with tqdm(total=len(items), desc=f"calibrate on {split}", unit="img", disable=not progress) as bar, \
            OrderedJobs(workers, finish, torch.set_num_threads, (1,)) as jobs:
        for batch in loader:
            images, vw = batch.images[:, 0], batch.view_ids[:, 0]
            raw = predict_sdf(model, images, batch_size=len(images), views=vw, clip=False,
                              calibrated=False).final.detach().float().cpu()
            for i, (c, a) in enumerate(carves):
                cone = Calibration(carve=c, mirror_axis=a).cone(images, vw, n, hs)
                jobs.submit(_score_candidates, raw, cone.cpu() if cone is not None else None, batch.voxels.cpu(),
                            [candidates[k] for k in by_carve[c]], hs,
                            tag=(by_carve[c], len(images) if i == len(carves) - 1 else 0))
            cats.append(batch.category.numpy())
    category = np.concatenate(cats)
    rows = []
    for cal, s in zip(candidates, scores):
        per_image = np.concatenate(s)
        iou = float(np.mean([per_image[category == c].mean() for c in np.unique(category)]))
        rows.append({"carve": cal.carve, "level": cal.level, "level_voxels": round(cal.level / voxel, 4),
                     "carve_level": cal.carve_level, "carve_level_voxels": round(cal.carve_level / voxel, 4),
                     "iou": iou})
    best = max(range(len(rows)), key=lambda k: (rows[k]["iou"], -k))
    return CalibrationSearch(best=candidates[best], rows=tuple(rows), split=split, images=len(items),
                             objects_per_category=max_objects_per_category, views=tuple(int(v) for v in views),
                             seconds=time.perf_counter() - start, carving=bool(carving))


def stored_calibration(path) -> Optional[dict]:
    """The calibration record a checkpoint holds (``store_calibration``), or None."""
    return load_checkpoint(path)[CHECKPOINT_KEY].get("calibration")


def store_calibration(path, search: CalibrationSearch) -> Path:
    """Writes ``search.record()`` into the checkpoint at ``path`` (atomically; the rest unchanged),
    where ``svr.inference.prediction.load_model`` finds it."""
    ckpt = load_checkpoint(path)
    ckpt[CHECKPOINT_KEY]["calibration"] = search.record()
    return write_torch(Path(path), ckpt)


__all__ = ["CARVE_LEVELS_VOXELS", "LEVELS_VOXELS", "VIEWS", "CalibrationSearch", "mirror_axis_of", "search_calibration",
           "stored_calibration", "store_calibration"]
