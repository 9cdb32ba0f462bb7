"""Lightning DataModules yielding ``SVRBatch`` from NMR-format folders (NMR ShapeNet or procedural).
Training (SPEC section 5): each batch element is a random object, then ``views_per_sample`` (V = 2)
distinct random views of it; view 0 is the network's input, all V supervise. The draws happen in the
main process (``ObjectViewSampler``, seeded by ``seed`` and the epoch), so they do not depend on the
number of workers. Evaluation (val and test): deterministic, one item per (object, view) in the
order category, object, view, with V = 1: ``batch.images`` is (B, 1, 4, 64, 64), ``batch.view_ids``
(B, 1). The test loader covers all 24 views of every test object (the benchmark counts each view as
one prediction); the validation loader can be thinned with ``val_views`` /
``val_objects_per_category``. Workers: the datasets hold no arrays when pickled; each worker opens
the prepared ``.npy`` files memory-mapped, so the page cache holds one copy whatever
``num_workers``. Several processes (DDP, ``trainer=ddp``): the samplers are rank-aware. Training:
every rank draws the same stream of an epoch (seeded by ``seed`` and the epoch) and takes every
world-size-th key of it, so the ranks see disjoint parts of one stream, and together the keys a
single process with a world-size-times larger batch would see (``samples_per_epoch`` counts all
ranks together; the last ``samples_per_epoch mod world size`` keys are dropped so that every rank
runs the same number of steps). Evaluation: each rank takes one contiguous block of the (object,
view) items, padded by wrapping around so that all ranks run the same number of batches (DDP's
forward pass is a collective); ``SVRLightningModule`` gathers the per-image IoU and counts each
image once. The processes of a node share the memory-mapped arrays as they share them between
workers: the page cache holds one copy whatever the number of processes
(tests/svr/test_distributed.py measures it).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Iterator, Optional, Sequence

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, Dataset
from torch.utils.data.distributed import DistributedSampler

from sdfcommon.tooling.checks import check_int
from svr.distributed import RankInfo, shard_indices
from svr.data.nmr import NUM_VIEWS, SPLITS, NMRDataset, check_view_ids, prepare_nmr, resolve_categories
from svr.data.procedural.generator import (ProceduralSettings, default_workers, ensure_procedural_dataset,
                         load_shading, procedural_dataset_dir)
from svr.data.types import ShadingModel, collate_batch

PathLike = str | os.PathLike


class RankShardedSampler(DistributedSampler):
    """Base of the rank-aware samplers of this module.

    It subclasses ``DistributedSampler`` so that Lightning uses it as it is: Lightning (with its
    default ``use_distributed_sampler=True``) wraps any other sampler in a
    ``DistributedSamplerWrapper``, which would shard it a second time and pad it with repeated
    items. ``DistributedSampler.__init__`` is not called: it wants a dataset, and a process group
    at construction, whereas these samplers read the ranks when they are iterated.

    Args:
        rank, world_size: this process and the number of processes; both None (the default): the
            default process group's when the sampler is iterated or measured (Lightning initialises
            it before it asks for the data loaders), or (0, 1) without one.
    """

    def __init__(self, rank: Optional[int] = None, world_size: Optional[int] = None):
        RankInfo.resolve(rank, world_size)  # checks them now
        self._rank = rank
        self._world_size = world_size
        self.epoch = 0
        self.shuffle = False
        self.drop_last = False

    @property
    def ranks(self) -> RankInfo:
        return RankInfo.resolve(self._rank, self._world_size)

    @property
    def rank(self) -> int:  # DistributedSampler's attribute
        return self.ranks.rank

    @property
    def num_replicas(self) -> int:  # DistributedSampler's attribute
        return self.ranks.world_size

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)


class ObjectViewSampler(RankShardedSampler):
    """Draws ``(object index, view ids)`` keys: per sample a random object (uniformly over objects,
    or over categories first with ``category_balanced``, as SoftRas's loader did), then V distinct
    random views.

    The stream of an epoch depends only on ``seed`` and the epoch (``set_epoch``; Lightning calls it),
    so a resumed run draws what the original would have. With W processes every rank draws the
    whole stream and yields keys ``rank, rank + W, rank + 2W, ...`` of its first
    ``W * (samples_per_epoch // W)``: disjoint parts, the same number on every rank, and together the
    keys one process would draw.

    Args:
        counts: objects per category, in the dataset's order.
        views_per_sample: V (1..24).
        samples_per_epoch: keys per epoch, all ranks together.
        rank, world_size: see ``RankShardedSampler`` (default: the process group's).
    """

    def __init__(self, counts: Sequence[int], views_per_sample: int = 2, samples_per_epoch: int = 1000,
                 seed: int = 0, category_balanced: bool = False, num_views: int = NUM_VIEWS,
                 rank: Optional[int] = None, world_size: Optional[int] = None):
        super().__init__(rank, world_size)
        self.counts = [int(c) for c in counts]
        if sum(self.counts) == 0:
            raise ValueError("the training split holds no objects")
        if not 1 <= views_per_sample <= num_views:
            raise ValueError(f"views_per_sample must be in [1, {num_views}], got {views_per_sample!r}")
        if samples_per_epoch < 1:
            raise ValueError(f"samples_per_epoch must be >= 1, got {samples_per_epoch!r}")
        self.views_per_sample = int(views_per_sample)
        self.samples_per_epoch = int(samples_per_epoch)
        self.seed = int(seed)
        self.category_balanced = bool(category_balanced)
        self.num_views = num_views
        self._resume: Optional[tuple[int, int]] = None  # (epoch, keys of this rank already trained on)

    def resume_at(self, epoch: int, keys: int) -> None:
        """Makes the next pass over ``epoch`` start after this rank's first ``keys`` keys (what a
        resumed run had already trained on), and sets the epoch. Other epochs are not affected."""
        if epoch < 0 or keys < 0:
            raise ValueError(f"the resume position (epoch, keys) must be >= 0, got {(epoch, keys)!r}")
        self.set_epoch(epoch)
        self._resume = (int(epoch), int(keys))

    def _per_rank(self) -> tuple[RankInfo, int]:
        ranks = self.ranks
        if self.samples_per_epoch < ranks.world_size:
            raise ValueError(f"samples_per_epoch ({self.samples_per_epoch}) must be at least the number of "
                             f"processes ({ranks.world_size})")
        return ranks, self.samples_per_epoch // ranks.world_size

    def __len__(self) -> int:
        return self._per_rank()[1]

    def stream(self) -> Iterator[tuple[int, tuple[int, ...]]]:
        """The epoch's whole stream of ``samples_per_epoch`` keys, before sharding."""
        rng = np.random.default_rng([self.seed, self.epoch])
        offsets = np.concatenate([[0], np.cumsum(self.counts)])
        nonempty = [c for c, n in enumerate(self.counts) if n > 0]
        total = int(offsets[-1])
        for _ in range(self.samples_per_epoch):
            if self.category_balanced:
                c = nonempty[int(rng.integers(len(nonempty)))]
                obj = int(offsets[c] + rng.integers(self.counts[c]))
            else:
                obj = int(rng.integers(total))
            views = rng.choice(self.num_views, size=self.views_per_sample, replace=False)
            yield obj, tuple(int(v) for v in views)

    def __iter__(self) -> Iterator[tuple[int, tuple[int, ...]]]:
        ranks, per_rank = self._per_rank()
        end = per_rank * ranks.world_size
        skip = 0
        if self._resume is not None and self._resume[0] == self.epoch:
            skip = self._resume[1]
        self._resume = None  # once: the next pass over any epoch is whole
        mine = 0
        for i, key in enumerate(self.stream()):  # drawn even when skipped: the stream stays the same
            if i >= end:
                break
            if i % ranks.world_size == ranks.rank:
                mine += 1
                if mine > skip:
                    yield key


class ResumableLoader(DataLoader):
    """A DataLoader over an ``ObjectViewSampler`` whose position within the epoch goes into the
    checkpoint: Lightning saves ``state_dict()`` with the loops and hands it to ``load_state_dict``
    before the resumed run iterates, so a resumed run trains on exactly the batches the
    uninterrupted one would have (without it the epoch would restart: batches replayed, others
    never seen).

    Args:
        position: returns how many batches of the current epoch have been trained on (the
            trainer's count: the loader itself runs ahead of training by its prefetch).
        The rest are DataLoader's; ``sampler`` must be an ``ObjectViewSampler``.
    """

    def __init__(self, *args, position: Callable[[], int], **kwargs):
        super().__init__(*args, **kwargs)
        if not isinstance(self.sampler, ObjectViewSampler):
            raise TypeError(f"ResumableLoader needs an ObjectViewSampler, got {type(self.sampler).__name__}")
        self._position = position

    def state_dict(self) -> dict[str, int]:
        return {"epoch": int(self.sampler.epoch), "batches": int(self._position())}

    def load_state_dict(self, state: dict[str, int]) -> None:
        self.sampler.resume_at(int(state["epoch"]), int(state["batches"]) * int(self.batch_size))


class EvalShardSampler(RankShardedSampler):
    """This rank's items of an evaluation set (``EvalViews``): one contiguous block per rank, in
    order (``svr.distributed.shard_indices``); one process: every item in order.

    Args:
        num_items: the set's size.
        pad: True (for Lightning's validation and test loops): every rank gets the same number of
            items, the last blocks wrapping around to the first items, so that all ranks run the same
            number of batches (the DDP forward pass is a collective); whoever gathers the results
            drops the repeats (``svr.distributed.gather_unique``). False: each item exactly once
            (ranks may differ by one item).
        rank, world_size: see ``RankShardedSampler``.
    """

    def __init__(self, num_items: int, pad: bool = True, rank: Optional[int] = None,
                 world_size: Optional[int] = None):
        super().__init__(rank, world_size)
        self.num_items = check_int(num_items, "num_items", minimum=0)
        self.pad = bool(pad)

    def indices(self) -> np.ndarray:
        """(K,) int64 item indices of this rank."""
        ranks = self.ranks
        return shard_indices(self.num_items, ranks.rank, ranks.world_size, self.pad)

    def __len__(self) -> int:
        return len(self.indices())

    def __iter__(self) -> Iterator[int]:
        return iter(self.indices().tolist())


class TrainViews(Dataset):
    """Training items keyed by ``(object index, view ids)`` (see ``ObjectViewSampler``).

    Item: images (V, 4, 64, 64) float32, view_ids (V,) long, voxels (32, 32, 32) bool, category,
    object_index (ints).
    """

    def __init__(self, objects: NMRDataset):
        self.objects = objects

    def __len__(self) -> int:
        return len(self.objects)

    def __getitem__(self, key) -> dict:
        obj, views = key
        c, o = self.objects.locate(int(obj))
        return {
            "images": self.objects.views(obj, views),
            "view_ids": torch.as_tensor(views, dtype=torch.long),
            "voxels": self.objects.voxels(obj),
            "category": c,
            "object_index": o,
        }


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


class NMRDataModule(pl.LightningDataModule):
    """Single-view data from an NMR-format folder.

    Attributes:
        categories: [(category id, name)], the order of ``SVRBatch.category`` indices.
        shading: the dataset's ShadingModel (from its metadata.json), None for NMR ShapeNet.

    Args:
        root: folder with ``{cid}_{split}_{images,voxels}.npz`` (required; must exist).
        categories: ids or names (default: all, see ``svr.data.nmr.resolve_categories``).
        batch_size: training objects per batch (B); each brings ``views_per_sample`` views.
        eval_batch_size: (object, view) items per validation/test batch.
        views_per_sample: V, distinct views per training object (SPEC: 2).
        samples_per_epoch: training samples per epoch, all processes together (default: the training
            images / V).
        category_balanced: draw a category first, then an object (SoftRas) instead of an object.
        val_views, val_objects_per_category: thin the validation set (default: everything).
        num_workers, pin_memory: DataLoader settings.
        seed: seeds the training draws.
        black_background: RGB fix for black-background images (``svr.data.nmr.images_to_float``).
        prepared_dir: where the memory-mapped ``.npy`` files are or go (default: root).
        prepare: ``prepare_data()`` converts missing ``.npy`` files (one-time, writes ~13 GB for the
            full NMR set).
    """

    def __init__(self, root: Optional[PathLike], categories: Optional[Sequence[str]] = None, batch_size: int = 32,
                 eval_batch_size: int = 64, views_per_sample: int = 2, samples_per_epoch: Optional[int] = None,
                 category_balanced: bool = False, val_views: Optional[Sequence[int]] = None,
                 val_objects_per_category: Optional[int] = None, num_workers: int = 0, pin_memory: bool = False,
                 seed: int = 0, black_background: str = "composite", prepared_dir: Optional[PathLike] = None,
                 prepare: bool = True):
        super().__init__()
        if root is None or str(root).strip() in ("", "???"):
            raise ValueError("root must name the folder with the NMR ShapeNet npz files "
                             "(set data.root=/path/to/NMR on the command line)")
        root = Path(root).expanduser()
        if not root.is_dir():
            raise FileNotFoundError(f"NMR data folder does not exist: {root} (check data.root)")
        self._init_common(batch_size, eval_batch_size, views_per_sample, samples_per_epoch, category_balanced,
                          val_views, val_objects_per_category, num_workers, pin_memory, seed, black_background,
                          prepared_dir, prepare)
        self.root = root
        self.categories: list[tuple[str, str]] = resolve_categories(root, categories)
        self._category_keys = [c for c, _ in self.categories]
        self.shading: Optional[ShadingModel] = load_shading(root)

    def _init_common(self, batch_size, eval_batch_size, views_per_sample, samples_per_epoch, category_balanced,
                     val_views, val_objects_per_category, num_workers, pin_memory, seed, black_background,
                     prepared_dir, prepare) -> None:
        check_int(batch_size, "batch_size", minimum=1)
        check_int(eval_batch_size, "eval_batch_size", minimum=1)
        check_int(views_per_sample, "views_per_sample", 1, NUM_VIEWS)
        if samples_per_epoch is not None:
            check_int(samples_per_epoch, "samples_per_epoch", minimum=1)
        check_int(num_workers, "num_workers", minimum=0)
        self.batch_size = batch_size
        self.eval_batch_size = eval_batch_size
        self.views_per_sample = views_per_sample
        self.samples_per_epoch = samples_per_epoch
        self.category_balanced = category_balanced
        self.val_views = None if val_views is None else [int(v) for v in val_views]
        self.val_objects_per_category = val_objects_per_category
        self.num_workers = num_workers
        self.pin_memory = pin_memory
        self.seed = int(seed)
        self.black_background = black_background
        self.prepared_dir = None if prepared_dir is None else Path(prepared_dir).expanduser()
        self.prepare = prepare
        self._sets: dict[str, NMRDataset] = {}
        self._sampler: Optional[ObjectViewSampler] = None

    # ------------------------------------------------------------------ lightning hooks
    def prepare_data(self) -> None:
        """Converts missing ``.npy`` files once (rank 0 only, as Lightning calls it)."""
        if self.prepare:
            prepare_nmr(self.root, self.prepared_dir, self._category_keys, SPLITS)

    def setup(self, stage: Optional[str] = None) -> None:
        splits = {"fit": ("train", "val"), "validate": ("val",), "test": ("test",), "predict": ("test",),
                  None: SPLITS}.get(stage, SPLITS)
        for split in splits:
            self.dataset(split)

    def dataset(self, split: str) -> NMRDataset:
        """The per-object NMRDataset of a split (opened on first use)."""
        if split not in self._sets:
            self._sets[split] = NMRDataset(self.root, split, self._category_keys, self.prepared_dir,
                                           self.black_background)
        return self._sets[split]

    def train_sampler(self) -> ObjectViewSampler:
        if self._sampler is None:
            ds = self.dataset("train")
            n = self.samples_per_epoch or max(1, len(ds) * NUM_VIEWS // self.views_per_sample)
            self._sampler = ObjectViewSampler(ds.counts, self.views_per_sample, n, self.seed, self.category_balanced)
        return self._sampler

    def _loader(self, dataset: Dataset, batch_size: int, loader: type = DataLoader, **kwargs) -> DataLoader:
        return loader(dataset, batch_size=batch_size, collate_fn=collate_batch, num_workers=self.num_workers,
                      pin_memory=self.pin_memory, persistent_workers=self.num_workers > 0, **kwargs)

    def batches_trained_this_epoch(self) -> int:
        """Training batches of the current epoch whose step has run (Lightning's count; 0 when no
        trainer is attached)."""
        trainer = getattr(self, "trainer", None)  # Lightning attaches it
        if trainer is None:
            return 0
        return int(trainer.fit_loop.epoch_loop.batch_progress.current.processed)

    def train_dataloader(self) -> DataLoader:
        """Batches of ``batch_size`` random objects x V random views (drop_last: BatchNorm-safe); with
        several processes, per process (the effective batch is ``batch_size`` x processes). A
        checkpoint records where in the epoch training was, and a resumed run goes on from there
        (``ResumableLoader``)."""
        return self._loader(TrainViews(self.dataset("train")), self.batch_size, loader=ResumableLoader,
                            sampler=self.train_sampler(), drop_last=len(self.train_sampler()) >= self.batch_size,
                            position=self.batches_trained_this_epoch)

    def val_dataloader(self) -> DataLoader:
        """Every (object, view) of the val split (thinned by val_views / val_objects_per_category), V = 1;
        with several processes this rank's padded block of them (``EvalShardSampler``)."""
        ds = EvalViews(self.dataset("val"), self.val_views, self.val_objects_per_category)
        return self._loader(ds, self.eval_batch_size, sampler=EvalShardSampler(len(ds), pad=True))

    def test_dataloader(self) -> DataLoader:
        """All 24 views of every test object, V = 1 (the benchmark's predictions); with several
        processes this rank's padded block of them."""
        ds = EvalViews(self.dataset("test"))
        return self._loader(ds, self.eval_batch_size, sampler=EvalShardSampler(len(ds), pad=True))


class ProceduralDataModule(NMRDataModule):
    """The built-in procedural dataset (``svr.data.procedural.generator``), generated on first use into
    ``<cache_dir>/procedural-<hash of the settings>`` and reused afterwards.

    Args:
        cache_dir: where generated datasets live; a relative path is taken from the working directory.
        categories: procedural category names or ids (default: the 13 NMR ShapeNet categories).
        train, val, test: objects per category and split.
        data_seed: the dataset's seed (which objects); ``seed`` seeds the training draws.
        supersample: anti-aliasing rays per pixel side.
        voxel_rule: "protocol" (default) or "centre" ground-truth voxels (``ProceduralSettings``).
        generation_workers: processes that generate the dataset when it is missing (0: this one;
            None: one per core). Not part of the dataset's identity.
        The other arguments are NMRDataModule's.
    """

    def __init__(self, cache_dir: PathLike = "data/cache", categories: Optional[Sequence[str]] = None,
                 train: int = 32, val: int = 4, test: int = 6, data_seed: int = 0, supersample: int = 3,
                 voxel_rule: str = "protocol", batch_size: int = 32, eval_batch_size: int = 64, views_per_sample: int = 2,
                 samples_per_epoch: Optional[int] = None, category_balanced: bool = False,
                 val_views: Optional[Sequence[int]] = None, val_objects_per_category: Optional[int] = None,
                 num_workers: int = 0, pin_memory: bool = False, seed: int = 0, progress: bool = True,
                 generation_workers: Optional[int] = None):
        pl.LightningDataModule.__init__(self)
        if generation_workers is None:
            generation_workers = default_workers()
        self.generation_workers = check_int(generation_workers, "generation_workers", minimum=0)
        self.settings = ProceduralSettings(tuple(categories or ()), train, val, test, int(data_seed), supersample,
                                           voxel_rule)
        cache = Path(cache_dir).expanduser()
        self.cache_dir = cache.resolve()  # relative: from the working directory, as every path of a command
        self._init_common(batch_size, eval_batch_size, views_per_sample, samples_per_epoch, category_balanced,
                          val_views, val_objects_per_category, num_workers, pin_memory, seed, "composite",
                          None, False)
        self.root = procedural_dataset_dir(self.cache_dir, self.settings)
        self.categories = self.settings.category_pairs()
        self._category_keys = [c for c, _ in self.categories]
        self.shading: Optional[ShadingModel] = None  # per-part colours: no single known albedo, as NMR
        self.progress = progress

    def prepare_data(self) -> None:
        """Generates the dataset if its cache folder does not exist yet."""
        ensure_procedural_dataset(self.cache_dir, self.settings, progress=self.progress, workers=self.generation_workers)

    def dataset(self, split: str) -> NMRDataset:
        if split not in self._sets and not self.root.exists():
            self.prepare_data()  # used outside a Trainer
        return super().dataset(split)


__all__ = ["RankShardedSampler", "ObjectViewSampler", "EvalShardSampler", "TrainViews", "EvalViews", "NMRDataModule",
           "ProceduralDataModule"]
