"""Lightning DataModules yielding ``SVRBatch`` from NMR-format folders: ``NMRDataModule`` (NMR
ShapeNet or a folder ``svr.data.build`` made) and ``ProceduralDataModule`` (the built-in procedural
data, generated on first use), both ``SVRDataModule``s, the contract that training, evaluation and
the baselines read. Training batches: per element a random object and ``views_per_sample`` (V = 2)
distinct random views of it; view 0 is the network's input, all V supervise (SPEC section 5;
``svr.data.samplers``). Evaluation (val and test): deterministic, one item per (object, view)
(``svr.data.datasets.EvalViews``); the test loader covers all 24 views of every test object (the
benchmark counts each view as one prediction), the validation loader can be thinned with
``val_views`` / ``val_objects_per_category``.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional, Sequence

import pytorch_lightning as pl
from torch.utils.data import DataLoader, Dataset

from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.commands import default_data_dir
from svr.data.datasets import EvalViews, NMRDataset, TrainViews
from svr.data.procedural.generator import (METADATA_FILE, ProceduralSettings, default_workers,
                                           ensure_procedural_dataset, load_shading, procedural_dataset_dir)
from svr.data.samplers import EvalShardSampler, ObjectViewSampler, ResumableLoader
from svr.data.types import ShadingModel, collate_batch
from svr.nmr.format import NUM_VIEWS, SPLITS, PathLike, check_split, is_nmr_shapenet, prepare_nmr, resolve_categories


class SVRDataModule(pl.LightningDataModule):
    """The loaders of an NMR-format folder, and what every single-view data module offers the
    training, the evaluation and the baselines: a subclass sets ``root``, ``categories`` and
    ``shading`` (``_set_data``) and may change how a split gets on disk (``prepare_split``) and
    what the data is called (``describe``).

    Attributes:
        root: the NMR-format folder.
        categories: [(category id, name)], the order of ``SVRBatch.category`` indices.
        shading: the dataset's ShadingModel (from its metadata.json), None where no single albedo
            is known (NMR ShapeNet, the procedural data).

    Args:
        batch_size: training objects per batch (B); each brings ``views_per_sample`` views.
        eval_batch_size: (object, view) items per validation/test batch.
        views_per_sample: V, distinct views per training object (SPEC: 2).
        samples_per_epoch: training samples per epoch, all processes together (default: the training
            images / V).
        category_balanced: draw a category first, then an object (SoftRas) instead of an object.
        val_views, val_objects_per_category: thin the validation set (default: everything).
        num_workers, pin_memory: DataLoader settings.
        seed: seeds the training draws.
        black_background: RGB fix for black-background images (``svr.nmr.format.images_to_float``).
        prepared_dir: where the memory-mapped ``.npy`` files are or go (default: root).
        prepare: ``prepare_data()`` converts missing ``.npy`` files (one-time, writes ~13 GB for the
            full NMR set).
        extra_view_share: the probability that a drawn training view is one of the training
            split's extra views (any azimuth, other elevations: ``svr.data.datasets.NMRDataset``);
            0: the 24 NMR views only. NMR ShapeNet has none; the procedural data's ``extra_views``
            and the mesh builder make them.
    """

    root: Path
    categories: list[tuple[str, str]]
    shading: Optional[ShadingModel]

    def __init__(self, batch_size: int = 32, eval_batch_size: int = 64, views_per_sample: int = 2,
                 samples_per_epoch: Optional[int] = None, category_balanced: bool = False,
                 val_views: Optional[Sequence[int]] = None, val_objects_per_category: Optional[int] = None,
                 num_workers: int = 0, pin_memory: bool = False, seed: int = 0, black_background: str = "composite",
                 prepared_dir: Optional[PathLike] = None, prepare: bool = True, extra_view_share: float = 0.0):
        super().__init__()
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
        if not 0.0 <= float(extra_view_share) < 1.0:
            raise ValueError(f"extra_view_share must be in [0, 1), got {extra_view_share!r}")
        self.extra_view_share = float(extra_view_share)
        self._sets: dict[str, NMRDataset] = {}
        self._sampler: Optional[ObjectViewSampler] = None


    def _set_data(self, root: Path, categories: Sequence[tuple[str, str]], shading: Optional[ShadingModel]) -> None:
        self.root = root
        self.categories = list(categories)
        self._category_keys = [c for c, _ in self.categories]
        self.shading = shading

    def prepare_split(self, split: str, progress: bool = True) -> None:
        """Puts one split on disk before an evaluation reads it (a command's explicit step, on one
        process while the others wait): its NMR files are converted to memory-mapped ``.npy`` when
        ``prepare`` is on."""
        check_split(split)
        if self.prepare:
            prepare_nmr(self.root, self.prepared_dir, self._category_keys, (split,), progress=progress)

    def describe(self) -> str:
        """A short description of the data: its kind and folder."""
        nmr = is_nmr_shapenet(self.root, self._category_keys)
        return f"{'NMR ShapeNet' if nmr else 'NMR-format data'} ({self.root})"

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
            self._sampler = ObjectViewSampler(ds.counts, self.views_per_sample, n, self.seed, self.category_balanced,
                                              extra_views=ds.extra_views, extra_share=self.extra_view_share)
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


class NMRDataModule(SVRDataModule):
    """Single-view data from an NMR-format folder (NMR ShapeNet, or one ``svr.data.build`` made).

    Args:
        root: folder with ``{cid}_{split}_{images,voxels}.npz`` (required; must exist).
        categories: ids or names (default: all, see ``svr.nmr.format.resolve_categories``).
        The rest are ``SVRDataModule``'s.
    """

    def __init__(self, root: Optional[PathLike], categories: Optional[Sequence[str]] = None, batch_size: int = 32,
                 eval_batch_size: int = 64, views_per_sample: int = 2, samples_per_epoch: Optional[int] = None,
                 category_balanced: bool = False, val_views: Optional[Sequence[int]] = None,
                 val_objects_per_category: Optional[int] = None, num_workers: int = 0, pin_memory: bool = False,
                 seed: int = 0, black_background: str = "composite", prepared_dir: Optional[PathLike] = None,
                 prepare: bool = True, extra_view_share: float = 0.0):
        if root is None or str(root).strip() in ("", "???"):
            raise ValueError("root must name the folder with the NMR ShapeNet npz files "
                             "(set data.root=/path/to/NMR on the command line)")
        root = Path(root).expanduser()
        if not root.is_dir():
            raise FileNotFoundError(f"NMR data folder does not exist: {root} (check data.root)")
        super().__init__(batch_size, eval_batch_size, views_per_sample, samples_per_epoch, category_balanced,
                         val_views, val_objects_per_category, num_workers, pin_memory, seed, black_background,
                         prepared_dir, prepare, extra_view_share)
        self._set_data(root, resolve_categories(root, categories), load_shading(root))


class ProceduralDataModule(SVRDataModule):
    """The built-in procedural dataset (``svr.data.procedural.generator``), generated on first use into
    ``<cache_dir>/procedural-<hash of the settings>`` and reused afterwards.

    Args:
        cache_dir: where generated datasets live (default: ``default_data_dir()``, ``data/cache`` in
            the checkout, the user's cache folder elsewhere); a relative path is taken from the
            working directory.
        categories: procedural category names or ids (default: the 13 NMR ShapeNet categories).
        train, val, test: objects per category and split.
        data_seed: the dataset's seed (which objects); ``seed`` seeds the training draws.
        supersample: anti-aliasing rays per pixel side.
        voxel_rule: "protocol" (default) or "centre" ground-truth voxels (``ProceduralSettings``).
        generation_workers: processes that generate the dataset when it is missing (0: this one;
            None: one per core). Not part of the dataset's identity.
        extra_views: extra random views of each training object (``ProceduralSettings``), which
            ``extra_view_share`` lets training draw.
        The other arguments are SVRDataModule's.
    """

    def __init__(self, cache_dir: Optional[PathLike] = None, categories: Optional[Sequence[str]] = None,
                 train: int = 32, val: int = 4, test: int = 6, data_seed: int = 0, supersample: int = 3,
                 voxel_rule: str = "protocol", batch_size: int = 32, eval_batch_size: int = 64, views_per_sample: int = 2,
                 samples_per_epoch: Optional[int] = None, category_balanced: bool = False,
                 val_views: Optional[Sequence[int]] = None, val_objects_per_category: Optional[int] = None,
                 num_workers: int = 0, pin_memory: bool = False, seed: int = 0, progress: bool = True,
                 generation_workers: Optional[int] = None, extra_views: int = 0, extra_view_share: float = 0.0):
        if generation_workers is None:
            generation_workers = default_workers()
        generation_workers = check_int(generation_workers, "generation_workers", minimum=0)
        settings = ProceduralSettings(tuple(categories or ()), train, val, test, int(data_seed), supersample,
                                      voxel_rule, extra_views)
        # a relative path: from the working directory, as every path
        cache = Path(default_data_dir() if cache_dir is None else cache_dir).expanduser().resolve()
        super().__init__(batch_size, eval_batch_size, views_per_sample, samples_per_epoch, category_balanced,
                         val_views, val_objects_per_category, num_workers, pin_memory, seed, "composite",
                         None, False, extra_view_share)
        self.generation_workers = generation_workers
        self.settings = settings
        self.cache_dir = cache
        # per-part colours: no single known albedo, as NMR
        self._set_data(procedural_dataset_dir(cache, settings), settings.category_pairs(), None)
        self.progress = progress

    def prepare_data(self) -> None:
        """Generates the dataset if its cache folder does not exist yet, after saying on stderr
        where it goes and how large it will be."""
        if not (self.root / METADATA_FILE).exists():
            print(f"Generating the procedural dataset ({self.settings.num_objects()} objects, about "
                  f"{self.settings.array_bytes() / 1e6:.0f} MB) into {self.root}; paths.data_dir (or data.cache_dir) "
                  f"chooses another folder.", file=sys.stderr, flush=True)
        ensure_procedural_dataset(self.cache_dir, self.settings, progress=self.progress, workers=self.generation_workers)

    def prepare_split(self, split: str, progress: bool = True) -> None:
        """Generates the dataset if it is missing (all splits at once)."""
        check_split(split)
        self.prepare_data()

    def describe(self) -> str:
        return f"procedural ({self.root})"

    def dataset(self, split: str) -> NMRDataset:
        if split not in self._sets and not self.root.exists():
            self.prepare_data()  # used outside a Trainer
        return super().dataset(split)


__all__ = ["SVRDataModule", "NMRDataModule", "ProceduralDataModule"]
