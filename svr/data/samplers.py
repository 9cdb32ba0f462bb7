"""Which items a training or evaluation loader reads, on every process (SPEC section 5). Training: each batch element is a random object, then ``views_per_sample`` (V = 2) distinct random
views of it (``ObjectViewSampler``). The draws happen in the main process, seeded by ``seed`` and
the epoch, so they do not depend on the number of workers; ``ResumableLoader`` records where in the
epoch training was, so a resumed run reads exactly the batches an uninterrupted one would.
With several processes (DDP, ``trainer=ddp``) every rank draws the same stream of an epoch and takes
every world-size-th key of it: the ranks see disjoint parts of one stream, together the keys a
single process with a world-size-times larger batch would see (``samples_per_epoch`` counts all
ranks together; the last ``samples_per_epoch mod world size`` keys are dropped so that every rank
runs the same number of steps). Evaluation (``EvalShardSampler``): each rank takes one contiguous
block of the (object, view) items, padded by wrapping around so that all ranks run the same number
of batches (DDP's forward pass is a collective); ``SVRLightningModule`` gathers the per-image IoU
and counts each image once.
"""
from __future__ import annotations

from typing import Callable, Iterator, Optional, Sequence

import numpy as np
from torch.utils.data import DataLoader
from torch.utils.data.distributed import DistributedSampler

from sdfcommon.tooling.checks import check_int
from svr.distributed import RankInfo, shard_indices
from svr.nmr.format import NUM_VIEWS


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
        extra_views, extra_share: K extra views per object (ids ``num_views .. num_views + K - 1``,
            ``svr.data.datasets.NMRDataset``), and the probability that a drawn view (the input
            and the supervising ones alike) is one of them; 0 (the default): only the NMR views,
            in the same stream as without extra views.
        rank, world_size: see ``RankShardedSampler`` (default: the process group's).
    """

    def __init__(self, counts: Sequence[int], views_per_sample: int = 2, samples_per_epoch: int = 1000,
                 seed: int = 0, category_balanced: bool = False, num_views: int = NUM_VIEWS,
                 rank: Optional[int] = None, world_size: Optional[int] = None, extra_views: int = 0,
                 extra_share: float = 0.0):
        super().__init__(rank, world_size)
        check_int(extra_views, "extra_views", minimum=0)
        if not 0.0 <= float(extra_share) < 1.0:
            raise ValueError(f"extra_share must be in [0, 1), got {extra_share!r}")
        if extra_share > 0 and extra_views == 0:
            raise ValueError(f"extra_share (data.extra_view_share) is {extra_share} but the training split holds "
                             f"no extra views; generate them (data.extra_views, or the builder's extra_views) or "
                             f"set it to 0")
        if extra_share > 0 and views_per_sample > num_views + extra_views:
            raise ValueError(f"views_per_sample ({views_per_sample}) exceeds the {num_views + extra_views} views")
        self.extra_views = int(extra_views)
        self.extra_share = float(extra_share)
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
            if self.extra_share > 0:
                p = np.concatenate([np.full(self.num_views, (1.0 - self.extra_share) / self.num_views),
                                    np.full(self.extra_views, self.extra_share / self.extra_views)])
                views = rng.choice(self.num_views + self.extra_views, size=self.views_per_sample, replace=False,
                                   p=p / p.sum())
            else:
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


__all__ = ["RankShardedSampler", "ObjectViewSampler", "ResumableLoader", "EvalShardSampler"]
