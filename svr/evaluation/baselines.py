"""Baselines of the single-view benchmark, scored on the same images and by the same protocol as a
model, since a learnt model's IoU means little alone: these rows bound it on the same data (SPEC
section 5; docs/svr_evaluation.md). ``mean_shape`` is one shape for every input, the training
objects' mean occupancy thresholded at the level whose protocol voxels fit them best;
``category_mean_shape`` is one shape per category, the mean of the category's training signed
distance grids (``svr.nmr.voxels.voxels_to_sdf`` of their voxels) at the iso-level that fits
them best, told the category, which the model is not (an optimistic version of the former);
``retrieval`` predicts, for each test image, the ground-truth voxels of the training object whose
stored silhouette in the same view is most similar to the input's alpha (``retrieve``), the
camera known as it is to the model and the category not, the bar a learnt model must clear to
show that it learnt shape rather than looked it up (published on NMR ShapeNet: 0.4766 mean IoU);
``retrieval_any_view`` is the same lookup without the camera (``retrieve_any_view``): the training
object with the most similar silhouette in any of its 24 views, as a method that reads only the
image can do (its ground truth is still predicted in the canonical frame, as every row's);
``oracle`` puts the exact (analytic) shape's SDF, sampled on the model's grid and clipped to the
object box as predictions are (``svr.nmr.voxels.clip_to_box``), through the protocol, the
ceiling of what a model with that grid can score (procedural data only, since it needs the
analytic shapes). ``score_baselines`` returns their per-image IoU, aligned with an
``svr.evaluation.tables.EvaluationResult``'s images; ``score_baselines_and_sides`` also their
side-view IoU (``svr.nmr.side_views``: the silhouettes from the views 90 degrees either side of
the input) where a baseline has side views to show (``SIDE_BASELINES``): a retrieved training
object its stored alpha in those views, a category's mean shape its render from them. That puts a
model's side views beside what looking the shape up, or knowing only the category, gives.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Optional, Sequence

import numpy as np
import torch
from tqdm.auto import tqdm

from sdfcommon.tooling.checks import check_int, check_shape
from svr.data.procedural.generator import dataset_shape, is_procedural_dataset
from svr.nmr.format import NUM_VIEWS
from svr.nmr.metrics import silhouette_features, soft_silhouette_iou, voxel_iou, voxels_protocol
from svr.nmr.side_views import render_silhouettes, side_views, silhouette_iou
from svr.nmr.voxels import clip_to_box, voxels_to_sdf

BASELINES: tuple[str, ...] = ("mean_shape", "category_mean_shape", "retrieval", "retrieval_any_view", "oracle")
# The baselines scored from the side too: one shape per image that can be seen from other views (the
# oracle's side views are the truth's; the global mean shape shows nothing a category's does not).
SIDE_BASELINES: tuple[str, ...] = ("category_mean_shape", "retrieval", "retrieval_any_view")
LABELS: Mapping[str, str] = {
    "mean_shape": "mean shape",
    "category_mean_shape": "category mean shape",
    "retrieval": "retrieval",
    "retrieval_any_view": "retrieval (any view)",
    "oracle": "oracle (exact shape)",
}
DESCRIPTIONS: Mapping[str, str] = {
    "mean_shape": "one shape for every input: the training objects' mean occupancy at the best threshold",
    "category_mean_shape": "the mean of the category's training SDFs (told the category: optimistic)",
    "retrieval": "the ground truth of the training object whose silhouette in the same view is most "
                 "similar to the input's (soft IoU of the alpha channels)",
    "retrieval_any_view": "as retrieval, but over every view of every training object: the camera not read",
    "oracle": "the exact shape's SDF sampled on the model's grid, through the protocol: the ceiling",
}
# What each row reads at test time besides the input image (the table's notes say it): the input
# camera is the NMR view index of the input image, which the benchmark's images come with.
READS: Mapping[str, str] = {
    "mean_shape": "nothing",
    "category_mean_shape": "the category",
    "retrieval": "the input camera",
    "retrieval_any_view": "nothing",
    "oracle": "the exact shape",
}
# Objects whose voxels are held in memory at once while a mean shape is accumulated or scored.
_CHUNK = 2048


def check_baselines(names: Optional[Sequence[str]]) -> tuple[str, ...]:
    """Validates a list of baseline names (``BASELINES``); None or empty -> ()."""
    if names is None:
        return ()
    if isinstance(names, str):
        raise ValueError(f"baselines must be a list of names from {list(BASELINES)}, got the string {names!r}")
    out = []
    for n in names:
        if n not in BASELINES:
            raise ValueError(f"baselines: unknown baseline {n!r}; expected some of {list(BASELINES)}")
        if n not in out:
            out.append(str(n))
    return tuple(out)


def _voxel_chunks(objects, indices: Sequence[int]):
    """Yields (N_k, 32, 32, 32) bool tensors of the objects' voxels, ``_CHUNK`` objects at a time."""
    indices = list(indices)
    for a in range(0, len(indices), _CHUNK):
        yield torch.stack([objects.voxels(int(i)) for i in indices[a:a + _CHUNK]])


def _best_shape(candidates: Sequence[torch.Tensor], objects, indices: Sequence[int]) -> tuple[torch.Tensor, int]:
    """The candidate voxel shape with the highest mean IoU over the given objects, and its index."""
    totals = np.zeros(len(candidates))
    for gt in _voxel_chunks(objects, indices):
        for k, cand in enumerate(candidates):
            totals[k] += float(voxel_iou(cand.expand_as(gt), gt).sum())
    k = int(np.argmax(totals))
    return candidates[k], k


def protocol_voxels_of_voxels(voxels) -> torch.Tensor:
    """What the benchmark protocol makes of a voxel shape predicted as an SDF: its signed distance
    grid (``svr.nmr.voxels.voxels_to_sdf``) -> marching cubes -> the benchmark's voxelisation.

    Args:
        voxels: (32, 32, 32) bool (NMR frame).
    Returns:
        (32, 32, 32) bool (NMR frame).
    """
    values, lo, hi = voxels_to_sdf(np.asarray(voxels, dtype=bool))
    return voxels_protocol(torch.from_numpy(values), lo, hi)[0]


MEAN_SHAPE_THRESHOLDS = tuple(float(t) for t in np.linspace(0.05, 0.95, 19))


def mean_shape(train) -> tuple[torch.Tensor, float]:
    """The best single prediction for every input, scored like a network's: the training objects'
    mean occupancy thresholded at the level (``MEAN_SHAPE_THRESHOLDS``) whose protocol voxels have
    the highest mean IoU over the training objects. Memory: one chunk of voxels at a time.

    Args:
        train: the training split (``svr.data.datasets.NMRDataset``: ``len``, ``voxels(i)``).
    Returns:
        ((32, 32, 32) bool protocol voxels of that shape, the threshold).
    """
    n = len(train)
    if n == 0:
        raise ValueError("mean_shape needs a non-empty training split")
    counts = None
    for gt in _voxel_chunks(train, range(n)):
        c = gt.sum(0, dtype=torch.int64)
        counts = c if counts is None else counts + c
    occupancy = counts.double() / n
    candidates = [protocol_voxels_of_voxels(occupancy >= t) for t in MEAN_SHAPE_THRESHOLDS]
    shape, k = _best_shape(candidates, train, range(n))
    return shape, MEAN_SHAPE_THRESHOLDS[k]


# Iso-levels tried for a mean SDF, in voxels of the 32^3 grid (0 = the mean's own zero level).
CATEGORY_MEAN_LEVELS = tuple(float(x) for x in np.arange(-1.5, 1.51, 0.25))


def category_mean_shapes(train) -> dict[int, torch.Tensor]:
    """Per category of the training split: the mean of its objects' signed distance grids
    (``voxels_to_sdf``), meshed at the level (``CATEGORY_MEAN_LEVELS``) whose protocol voxels have the
    highest mean IoU over the category's training objects.

    Returns:
        {category index: (32, 32, 32) bool protocol voxels}, for the categories with objects.
    """
    out = {}
    for c, count in enumerate(train.counts):
        if count == 0:
            continue
        idx = range(int(train.offsets[c]), int(train.offsets[c + 1]))
        total, lo, hi = None, -1.0, 1.0
        for i in idx:
            values, lo, hi = voxels_to_sdf(train.voxels(i).numpy())
            total = values if total is None else total + values
        mean = torch.from_numpy(total / count)
        voxel = 1.0 / 31.0
        candidates = [voxels_protocol(mean - level * voxel, lo, hi)[0] for level in CATEGORY_MEAN_LEVELS]
        out[c], _ = _best_shape(candidates, train, idx)
    return out


def _alpha_features(alpha_uint8: np.ndarray) -> torch.Tensor:
    """(N, 64, 64) uint8 alpha -> (N, 1024) float32 in [0, 1], 2x2 box-averaged to 32^2
    (``svr.nmr.metrics.silhouette_features``)."""
    return silhouette_features(torch.from_numpy(np.ascontiguousarray(alpha_uint8)).float().div_(255.0))


def retrieve(train, queries: np.ndarray, views: np.ndarray, chunk: int = 1024,
             progress: Optional[Callable[[int], None]] = None) -> np.ndarray:
    """Nearest training object by silhouette, per query image.

    For each query, the training object (any category) whose alpha in the query's view has the
    highest soft IoU ``<a, b> / (|a| + |b| - <a, b>)`` with the query's alpha; ties go to the lower
    index. Per view, the training silhouettes of that view are read once (N x 1024 float32) and the
    queries compared in chunks, so memory stays at one view's features plus a chunk x N block.

    Args:
        train: the training split (``NMRDataset``: ``silhouettes(view)``).
        queries: (Q, 64, 64) uint8 alpha of the query images.
        views: (Q,) int view index (0..23) of each query.
        progress: called with the number of queries done after each chunk.
    Returns:
        (Q,) int64 global training object indices.
    """
    queries = np.asarray(queries)
    views = np.asarray(views, dtype=np.int64).reshape(-1)
    check_shape(queries, "queries", f"{len(views)}, H, W")  # one view per query
    if len(train) == 0:
        raise ValueError("retrieval needs a non-empty training split")
    out = np.full(len(views), -1, dtype=np.int64)
    for v in np.unique(views):
        bank = _alpha_features(train.silhouettes(int(v)))
        rows = np.flatnonzero(views == v)
        for a in range(0, len(rows), chunk):
            sel = rows[a:a + chunk]
            out[sel] = torch.argmax(soft_silhouette_iou(_alpha_features(queries[sel]), bank), dim=1).numpy()
            if progress is not None:
                progress(len(sel))
    return out


def retrieve_any_view(train, queries: np.ndarray, chunk: int = 1024,
                      progress: Optional[Callable[[int], None]] = None) -> np.ndarray:
    """Nearest training object by silhouette in any view, per query image: the camera not read.

    For each query, the training object (any category) with the highest soft IoU ``<a, b> / (|a| +
    |b| - <a, b>)`` between the query's alpha and its alpha in any of its views (the same
    similarity as ``retrieve``); ties go to the lower object index. The best (score, object) per
    query is kept over the views, so memory stays at one view's training features (N x 1024
    float32) plus a chunk x N block, whatever the number of views.

    Args:
        train: the training split (``NMRDataset``: ``silhouettes(view)``).
        queries: (Q, 64, 64) uint8 alpha of the query images.
        chunk: queries compared at once.
        progress: called with 1 after each training view has been compared with every query.
    Returns:
        (Q,) int64 global training object indices.
    """
    queries = np.asarray(queries)
    if queries.ndim != 3:
        raise ValueError(f"queries must be (Q, H, W) alpha, got shape {tuple(queries.shape)}")
    check_int(chunk, "chunk", minimum=1)
    if len(train) == 0:
        raise ValueError("retrieval needs a non-empty training split")
    best = torch.full((len(queries),), -1.0)
    found = torch.zeros(len(queries), dtype=torch.int64)
    features = [_alpha_features(queries[a:a + chunk]) for a in range(0, len(queries), chunk)]
    for v in range(NUM_VIEWS):
        bank = _alpha_features(train.silhouettes(v))
        for a, q in zip(range(0, len(queries), chunk), features):
            iou = soft_silhouette_iou(q, bank)
            index = torch.argmax(iou, dim=1)  # the first of equal scores: the lower object index
            score = iou.gather(1, index[:, None])[:, 0]
            sl = slice(a, a + len(q))
            better = (score > best[sl]) | ((score == best[sl]) & (index < found[sl]))
            best[sl] = torch.where(better, score, best[sl])
            found[sl] = torch.where(better, index, found[sl])
        if progress is not None:
            progress(1)
    return found.numpy()


def oracle_voxels(root, category_id: str, split: str, index: int, half_side: float,
                  grid_resolution: int) -> torch.Tensor:
    """The protocol voxels of a procedural object's exact SDF sampled on a model's grid.

    Args:
        root: the generated procedural dataset's folder (its metadata.json has the seeds).
        half_side, grid_resolution: the model's grid, ``grid_resolution``^3 samples over
            ``[-half_side, half_side]^3``.
    Returns:
        (32, 32, 32) bool (NMR frame).
    """
    shape = dataset_shape(root, category_id, split, index)
    axis = np.linspace(-half_side, half_side, grid_resolution)
    values = torch.from_numpy(shape.sdf_numpy(np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1)))
    return voxels_protocol(clip_to_box(values, -half_side, half_side), -half_side, half_side)[0]


def _query_alphas(objects, glob: np.ndarray, views: np.ndarray) -> np.ndarray:
    """(M, 64, 64) uint8 alpha of each evaluated image (object ``glob[i]``, view ``views[i]``), read
    one object at a time."""
    out = None
    for g in np.unique(glob):
        rows = np.flatnonzero(glob == g)
        alpha = objects.images_uint8(int(g), [int(v) for v in views[rows]])[:, 3]
        if out is None:
            out = np.empty((len(glob), *alpha.shape[1:]), dtype=np.uint8)
        out[rows] = alpha
    return out


def _retrieved_iou(train, found: np.ndarray, glob: np.ndarray, gt: Mapping[int, torch.Tensor]) -> np.ndarray:
    """(M,) IoU of each retrieved training object's voxels (``found``) against the image's truth.
    Compared as they are: they are already in the benchmark's voxel form."""
    cache: dict[tuple[int, int], float] = {}
    ious = np.empty(len(glob), dtype=np.float64)
    for k, (g, t) in enumerate(zip(glob, found)):
        key = (int(g), int(t))
        if key not in cache:
            cache[key] = float(voxel_iou(train.voxels(int(t)), gt[int(g)]))
        ious[k] = cache[key]
    return ious


def _side_iou(objects, glob: np.ndarray, views: np.ndarray,
              predicted: Callable[[int, np.ndarray], torch.Tensor]) -> np.ndarray:
    """(M,) mean silhouette IoU over each image's two side views (``svr.nmr.side_views``) of a
    baseline's silhouettes, ``predicted(view, rows)`` -> (len(rows), S, S) bool for the images
    ``rows`` seen from ``view``, against the stored alpha of the images' objects (at 0.5). One side
    view of every object of the split in memory at a time."""
    sides = side_views(torch.as_tensor(np.asarray(views, dtype=np.int64))).numpy()
    out = np.zeros(len(glob), dtype=np.float64)
    for s in np.unique(sides):
        rows = np.flatnonzero((sides == s).any(axis=1))  # a view is one side of an image, never both
        true = torch.from_numpy(objects.silhouettes(int(s))[glob[rows]] >= 128)
        out[rows] += silhouette_iou(predicted(int(s), rows), true).numpy()
    return out / 2.0


def _stored_side_iou(train, objects, found: np.ndarray, glob: np.ndarray, views: np.ndarray) -> np.ndarray:
    """(M,) side-view IoU of each retrieved training object (``found``): its stored alpha in the
    image's two side views."""
    return _side_iou(objects, glob, views, lambda s, rows: torch.from_numpy(train.silhouettes(s)[found[rows]] >= 128))


def _rendered_side_iou(shapes: Mapping[int, torch.Tensor], category: np.ndarray, objects, glob: np.ndarray,
                       views: np.ndarray) -> np.ndarray:
    """(M,) side-view IoU of one voxel shape per category (``shapes``, NMR frame; ``category`` the
    image's): its signed distance grid rendered from the image's side views, as a prediction is, at
    the stored images' size."""
    if not len(glob):
        return np.zeros(0, dtype=np.float64)
    size = objects.silhouettes(0).shape[-1]
    renders = {}
    for c, vox in shapes.items():
        values, _, hi = voxels_to_sdf(vox.numpy())
        sdf = torch.from_numpy(values).float()[None]
        renders[c] = render_silhouettes(sdf, hi, torch.arange(NUM_VIEWS)[None], image_size=size)[0]  # (24, S, S)
    return _side_iou(objects, glob, views, lambda s, rows: torch.stack([renders[int(c)][s] for c in category[rows]]))


@dataclass(frozen=True)
class BaselineScores:
    """Per-image scores of the baselines on an evaluation's images.

    Attributes:
        iou: baseline name -> (M,) float64 benchmark IoU.
        side_iou: baseline name (of ``SIDE_BASELINES``) -> (M,) float64 side-view silhouette IoU.
    """

    iou: dict[str, np.ndarray]
    side_iou: dict[str, np.ndarray] = field(default_factory=dict)


def score_baselines(names: Sequence[str], result, objects, train, half_side: float, grid_resolution: int,
                    progress: bool = True) -> dict[str, np.ndarray]:
    """Per-image IoU of each baseline on the images an evaluation scored: ``score_baselines_and_sides``'s
    IoU alone (the arguments are its)."""
    return score_baselines_and_sides(names, result, objects, train, half_side, grid_resolution, progress,
                                     sides=False).iou


def score_baselines_and_sides(names: Sequence[str], result, objects, train, half_side: float, grid_resolution: int,
                              progress: bool = True, sides: bool = True) -> BaselineScores:
    """Per-image IoU of each baseline on the images an evaluation scored.

    The two mean shapes are predicted as SDFs and go through the protocol (marching cubes, the
    benchmark's voxelisation) like a model's output. Retrieval's prediction is a training object's
    ground truth, already in the benchmark's voxel form, so it is compared as it is: voxelising it
    again would dilate it by the protocol's surface voxels.

    Args:
        names: baselines to score (``BASELINES``); "oracle" is skipped where the data is not a
            generated procedural dataset (``svr.data.procedural.generator.is_procedural_dataset``: real NMR data).
        result: ``svr.evaluation.tables.EvaluationResult`` (its category, object_index and view arrays).
        objects: the evaluated split's dataset; train: the training split of the same data
            (same categories, same order).
        half_side, grid_resolution: the model's grid (for the oracle).
        sides: also the side-view IoU of the ``SIDE_BASELINES`` among ``names``.
    Returns:
        the scores; each array has M = the result's images entries, in its order.
    """
    names = check_baselines(names)
    if [c for c, _ in getattr(train, "categories", [])] != [c for c, _ in result.categories]:
        raise ValueError("the training split's categories differ from the evaluated data's")
    glob = np.asarray(objects.offsets)[result.category] + result.object_index
    uniq = np.unique(glob)
    gt = {int(g): objects.voxels(int(g)) for g in uniq}
    out: dict[str, np.ndarray] = {}
    side: dict[str, np.ndarray] = {}

    def per_object(pred_of: Callable[[int], torch.Tensor]) -> np.ndarray:
        score = {g: float(voxel_iou(pred_of(g), gt[g])) for g in gt}
        return np.array([score[int(g)] for g in glob], dtype=np.float64)

    for name in names:
        if name == "mean_shape":
            shape, _ = mean_shape(train)
            out[name] = per_object(lambda g: shape)
        elif name == "category_mean_shape":
            shapes = category_mean_shapes(train)
            out[name] = per_object(lambda g: shapes[objects.category_of(g)])
            if sides:
                side[name] = _rendered_side_iou(shapes, np.asarray(result.category), objects, glob, result.view)
        elif name == "retrieval":
            found = np.empty(len(glob), dtype=np.int64)
            with tqdm(total=len(glob), desc="retrieval baseline", unit="img", disable=not progress) as bar:
                for v in np.unique(result.view):  # one view's queries in memory at a time
                    sel = np.flatnonzero(result.view == v)
                    queries = np.stack([objects.images_uint8(int(g), [int(v)])[0, 3] for g in glob[sel]])
                    found[sel] = retrieve(train, queries, result.view[sel], progress=bar.update)
            out[name] = _retrieved_iou(train, found, glob, gt)
            if sides:
                side[name] = _stored_side_iou(train, objects, found, glob, result.view)
        elif name == "retrieval_any_view":
            queries = _query_alphas(objects, glob, result.view)
            with tqdm(total=NUM_VIEWS, desc="retrieval (any view) baseline", unit="view",
                      disable=not progress) as bar:
                found = retrieve_any_view(train, queries, progress=bar.update)
            out[name] = _retrieved_iou(train, found, glob, gt)
            if sides:
                side[name] = _stored_side_iou(train, objects, found, glob, result.view)
        elif name == "oracle":
            if not is_procedural_dataset(objects.root):
                continue
            split = objects.split

            def oracle(g: int) -> torch.Tensor:
                c, o = objects.locate(g)
                return oracle_voxels(objects.root, result.categories[c][0], split, o, half_side, grid_resolution)

            out[name] = per_object(oracle)
    return BaselineScores(out, side)


__all__ = ["BASELINES", "SIDE_BASELINES", "BaselineScores", "score_baselines_and_sides", "LABELS", "DESCRIPTIONS", "READS", "check_baselines", "protocol_voxels_of_voxels", "mean_shape",
           "category_mean_shapes", "retrieve", "retrieve_any_view", "oracle_voxels", "score_baselines"]
