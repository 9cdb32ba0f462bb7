"""The torch Datasets over an NMR-format folder: ``NMRDataset`` holds a split's objects (all 24
views and the voxels of each), ``TrainViews`` and ``EvalViews`` turn it into the items a loader
batches (``svr.data.types.collate_batch``): keyed by (object, views) for training, one per (object,
view) in the order category, object, view for evaluation (V = 1: ``batch.images`` is
(B, 1, 4, 64, 64), ``batch.view_ids`` (B, 1)). Workers: the datasets hold no arrays when pickled;
each worker opens the prepared ``.npy`` files memory-mapped, so the page cache holds one copy
whatever ``num_workers`` or the number of processes of a node (tests/svr/test_distributed.py
measures it).
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from renderer import NMR_ELEVATION_DEG
from sdfcommon.tooling.checks import check_int
from svr.nmr.format import (BACKGROUND_MODES, KINDS, NUM_VIEWS, PathLike, check_npz, check_split, check_view_ids,
                            images_to_float, nmr_file, open_extra_views, open_prepared, read_npz,
                            resolve_categories)
from svr.nmr.views import view_rows


class NMRDataset(Dataset):
    """Objects of an NMR-format folder (any subset of categories, one split).

    Item ``n`` (objects in category order, then file order) is a dict:

    * ``images``: (24, 4, 64, 64) float32 RGBA in [0, 1], RGB on white (``images_to_float``);
    * ``view_ids``: (24,) long, 0..23; ``azimuth_deg``: (24,) float32, ``-15 * view``;
    * ``voxels``: (32, 32, 32) bool, NMR voxel frame;
    * ``category``: int index into ``categories``; ``category_id``, ``category_name``: str;
    * ``object_index``: int, the object's row in its category's files.

    ``views(n, view_ids)`` and ``voxels(n)`` read just what a training sample needs.

    Extra views (``svr.nmr.format.extra_view_files``, which the procedural data and the mesh builder
    write on request for the train split): ``extra_views`` = K of every object, addressed by the view
    ids 24 .. 23 + K of ``views``, ``images_uint8`` and ``cameras``; items of ``__getitem__`` (and
    the evaluation) keep to the 24.

    The arrays are opened lazily in each process (and dropped when the dataset is pickled to a
    worker), as memory maps of the prepared ``.npy`` files when present (validated against the npz
    headers), else by decompressing the npz into memory.

    Args:
        root: the folder. split: "train", "val" or "test".
        categories: ids or names (default: all, see ``resolve_categories``).
        prepared_dir: where the ``.npy`` files are (default: root).
        black_background: see ``images_to_float``.
        require_prepared: raise instead of falling back to the npz files.
    """

    def __init__(self, root: PathLike, split: str = "test", categories: Optional[Sequence[str]] = None,
                 prepared_dir: Optional[PathLike] = None, black_background: str = "composite",
                 require_prepared: bool = False):
        if root is None or str(root) in ("", "???"):
            raise ValueError("root must name the folder holding the NMR npz files (it is unset)")
        self.root = Path(root).expanduser()
        if not self.root.is_dir():
            raise FileNotFoundError(f"NMR data folder does not exist: {self.root}")
        check_split(split)
        if black_background not in BACKGROUND_MODES:
            raise ValueError(f"black_background must be one of {BACKGROUND_MODES}, got {black_background!r}")
        self.split = split
        self.black_background = black_background
        self.prepared_dir = Path(prepared_dir).expanduser() if prepared_dir is not None else self.root
        self.categories: list[tuple[str, str]] = resolve_categories(self.root, categories)
        self.counts: list[int] = []
        self.prepared = True
        for cid, _ in self.categories:
            n = check_npz(nmr_file(self.root, cid, split, "images"), "images")
            nv = check_npz(nmr_file(self.root, cid, split, "voxels"), "voxels")
            if n != nv:
                raise ValueError(f"{nmr_file(self.root, cid, split, 'images')} holds {n} objects but "
                                 f"{nmr_file(self.root, cid, split, 'voxels')} holds {nv}")
            self.counts.append(n)
            for kind in KINDS:
                npy = nmr_file(self.prepared_dir, cid, split, kind, "npy")
                if npy.exists():
                    open_prepared(npy, kind, n)  # validates now, so errors surface at construction
                else:
                    self.prepared = False
        if not self.prepared:
            if require_prepared:
                raise FileNotFoundError(f"prepared .npy files are missing in {self.prepared_dir}; "
                                        f"run `python data/prepare_nmr.py {self.root}` first")
            if split == "train":
                warnings.warn(f"{self.root}: no prepared .npy files for split {split!r}; decompressing the npz "
                              f"files into memory in every process (run data/prepare_nmr.py once to share "
                              f"one memory-mapped copy)", RuntimeWarning, stacklevel=2)
        self.offsets = np.concatenate([[0], np.cumsum(self.counts)]).astype(np.int64)
        extras = [open_extra_views(self.root, cid, split, n) for (cid, _), n in zip(self.categories, self.counts)]
        counts = {None if e is None else int(e[0].shape[1]) for e in extras}
        if len(counts) > 1:
            raise ValueError(f"{self.root}: the categories of split {split!r} hold different numbers of extra "
                             f"views ({sorted(counts, key=str)}); every category needs the same")
        self.extra_views: int = counts.pop() or 0
        self._arrays: Optional[list[tuple[np.ndarray, np.ndarray]]] = None
        self._extras: Optional[list[Optional[tuple[np.ndarray, np.ndarray]]]] = None

    # ------------------------------------------------------------------ arrays
    def _open(self) -> list[tuple[np.ndarray, np.ndarray]]:
        if self._arrays is None:
            arrays = []
            for (cid, _), n in zip(self.categories, self.counts):
                if self.prepared:
                    arrays.append(tuple(open_prepared(nmr_file(self.prepared_dir, cid, self.split, k, "npy"), k, n)
                                        for k in KINDS))
                else:
                    arrays.append(tuple(read_npz(nmr_file(self.root, cid, self.split, k), k) for k in KINDS))
            self._arrays = arrays
        return self._arrays

    def _open_extras(self) -> list[tuple[np.ndarray, np.ndarray]]:
        if self._extras is None:
            self._extras = [open_extra_views(self.root, cid, self.split, n)
                            for (cid, _), n in zip(self.categories, self.counts)]
        return self._extras

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_arrays"] = None  # workers reopen the memory maps instead of receiving copies
        state["_extras"] = None
        return state

    def _split_ids(self, view_ids: Sequence[int]) -> np.ndarray:
        ids = np.asarray(view_ids, dtype=np.int64).reshape(-1)
        if ids.size and not ((ids >= 0) & (ids < NUM_VIEWS + self.extra_views)).all():
            raise IndexError(f"view ids must lie in [0, {NUM_VIEWS + self.extra_views}) ({NUM_VIEWS} NMR views and "
                             f"{self.extra_views} extra), got {ids.tolist()}")
        return ids

    def cameras(self, index: int, view_ids: Sequence[int]) -> torch.Tensor:
        """(V, 2) float32 rows of (NMR view coordinate, elevation in degrees) of the views
        (``svr.nmr.views.view_cameras``): (k, 30) for NMR view k, ``svr.nmr.views.view_rows`` of an
        extra view's angles."""
        ids = self._split_ids(view_ids)
        out = np.stack([ids.astype(np.float32), np.full(len(ids), NMR_ELEVATION_DEG, np.float32)], axis=1)
        extra = ids >= NUM_VIEWS
        if extra.any():
            c, o = self.locate(index)
            angles = np.asarray(self._open_extras()[c][1][o][ids[extra] - NUM_VIEWS])
            out[extra] = view_rows(angles).numpy()
        return torch.from_numpy(out)

    # ------------------------------------------------------------------ indexing
    def __len__(self) -> int:
        return int(self.offsets[-1])

    def locate(self, index: int) -> tuple[int, int]:
        """(category index, object index within the category) of global object ``index``."""
        n = len(self)
        if not -n <= index < n:
            raise IndexError(f"object index {index} out of range for {n} objects")
        index = index % n
        c = int(np.searchsorted(self.offsets, index, side="right") - 1)
        return c, int(index - self.offsets[c])

    def images_uint8(self, index: int, view_ids: Optional[Sequence[int]] = None) -> np.ndarray:
        """(V, 4, 64, 64) uint8 views of object ``index`` exactly as stored (all 24 by default)."""
        c, o = self.locate(index)
        images = self._open()[c][0]
        if view_ids is None:
            return np.array(images[o])  # a copy: the memory map is read-only
        ids = self._split_ids(view_ids)
        if (ids < NUM_VIEWS).all():
            return np.asarray(images[o][ids])
        out = np.empty((len(ids), *images.shape[2:]), dtype=np.uint8)
        extra = ids >= NUM_VIEWS
        out[~extra] = images[o][ids[~extra]]
        out[extra] = self._open_extras()[c][0][o][ids[extra] - NUM_VIEWS]
        return out

    def silhouettes(self, view: int) -> np.ndarray:
        """(N, 64, 64) uint8 alpha channel of one view of every object, in dataset order (one strided
        read per category of the memory-mapped arrays)."""
        check_int(int(view) if isinstance(view, np.integer) else view, "view", 0, NUM_VIEWS - 1)
        parts = [np.asarray(images[:, int(view), 3]) for images, _ in self._open()]
        return np.concatenate(parts) if parts else np.zeros((0, 64, 64), np.uint8)

    def views(self, index: int, view_ids: Optional[Sequence[int]] = None) -> torch.Tensor:
        """(V, 4, 64, 64) float32 views of object ``index`` (RGB on white, see ``images_to_float``)."""
        return images_to_float(self.images_uint8(index, view_ids), self.black_background)

    def voxels(self, index: int) -> torch.Tensor:
        """(32, 32, 32) bool voxels of object ``index`` (NMR frame)."""
        c, o = self.locate(index)
        return torch.from_numpy(np.array(self._open()[c][1][o], dtype=bool))

    def category_of(self, index: int) -> int:
        return self.locate(index)[0]

    def __getitem__(self, index: int) -> dict:
        c, o = self.locate(index)
        views = torch.arange(NUM_VIEWS, dtype=torch.long)
        return {
            "images": self.views(index),
            "view_ids": views,
            "azimuth_deg": -15.0 * views.float(),
            "voxels": self.voxels(index),
            "category": c,
            "category_id": self.categories[c][0],
            "category_name": self.categories[c][1],
            "object_index": o,
        }


class TrainViews(Dataset):
    """Training items keyed by ``(object index, view ids)`` (see ``ObjectViewSampler``).

    Item: images (V, 4, 64, 64) float32, view_ids (V,) long, voxels (32, 32, 32) bool, category,
    object_index (ints); with an extra view among the ids (>= 24) also cameras (V, 2)
    (``NMRDataset.cameras``), and view_ids then holds the nearest NMR views.
    """

    def __init__(self, objects: NMRDataset):
        self.objects = objects

    def __len__(self) -> int:
        return len(self.objects)

    def __getitem__(self, key) -> dict:
        obj, views = key
        c, o = self.objects.locate(int(obj))
        item = {
            "images": self.objects.views(obj, views),
            "view_ids": torch.as_tensor(views, dtype=torch.long),
            "voxels": self.objects.voxels(obj),
            "category": c,
            "object_index": o,
        }
        if max(views) >= NUM_VIEWS:  # an extra view: its camera, and the nearest NMR view as its id
            item["cameras"] = self.objects.cameras(obj, views)
            item["view_ids"] = torch.round(item["cameras"][:, 0]).long() % NUM_VIEWS
        return item


class EvalViews(Dataset):
    """Deterministic evaluation items: one per (object, view), ordered by category, object, view.

    Item: images (1, 4, 64, 64) float32, view_ids (1,) long, voxels, category, object_index.

    Args:
        objects: the split's objects.
        views: which views of each object (default all 24).
        max_objects_per_category: keep only the first objects of each category (default all).
    """

    def __init__(self, objects: NMRDataset, views: Optional[Sequence[int]] = None,
                 max_objects_per_category: Optional[int] = None):
        self.objects = objects
        self.views = list(range(NUM_VIEWS)) if views is None else list(check_view_ids(views, allow_empty=False))
        if max_objects_per_category is not None and max_objects_per_category < 1:
            raise ValueError(f"max_objects_per_category must be >= 1 or None, got {max_objects_per_category!r}")
        keep = []
        for c, n in enumerate(objects.counts):
            m = n if max_objects_per_category is None else min(n, max_objects_per_category)
            keep.extend(int(objects.offsets[c]) + o for o in range(m))
        self.object_ids = np.asarray(keep, dtype=np.int64)

    def __len__(self) -> int:
        return len(self.object_ids) * len(self.views)

    def __getitem__(self, index: int) -> dict:
        if not 0 <= index < len(self):
            raise IndexError(f"index {index} out of range for {len(self)} items")
        obj = int(self.object_ids[index // len(self.views)])
        view = self.views[index % len(self.views)]
        c, o = self.objects.locate(obj)
        return {
            "images": self.objects.views(obj, [view]),
            "view_ids": torch.tensor([view], dtype=torch.long),
            "voxels": self.objects.voxels(obj),
            "category": c,
            "object_index": o,
        }


__all__ = ["NMRDataset", "TrainViews", "EvalViews"]
