"""Running on several processes (``torch.distributed``, any backend): the few pieces that Lightning
does not give for our data, since training runs on Lightning's own strategies (``trainer=ddp``,
``trainer=ddp_cpu``), where Lightning, SLURM or torchrun starts the processes and Lightning
initialises the process group. ``shard_indices`` says which items of an evaluation set a rank
takes, padded (every rank the same count, so that collective calls inside the loop stay matched)
or not; ``gather_uneven`` and ``gather_unique`` all-gather tensors whose first dimension differs
across ranks (``torch.distributed.all_gather`` needs equal shapes) and drop the duplicates that
padding made; ``process_group_from_environment`` joins the process group that a launcher
describes (torchrun's or SLURM's environment variables) for Lightning-free tools such as
``svr.evaluate``; ``launch_rank_is_zero`` says whether this process is global rank 0, also before
any process group exists (for files written before Lightning sets the ranks up). Everything
degrades to the single-process case when no process group is initialised.
"""
from __future__ import annotations

import contextlib
import datetime
import os
from dataclasses import dataclass
from typing import Iterator, Optional

import numpy as np
import torch
import torch.distributed as dist
from lightning_fabric.plugins.environments import SLURMEnvironment

from sdfcommon.tooling.checks import check_int, check_shape, check_tensor


@dataclass(frozen=True)
class RankInfo:
    """This process's place in the process group.

    Attributes:
        rank: global rank, 0..world_size-1.
        world_size: number of processes (1 without a process group).
    """

    rank: int = 0
    world_size: int = 1

    def __post_init__(self) -> None:
        check_int(self.world_size, "world_size", minimum=1)
        check_int(self.rank, "rank", 0, self.world_size - 1)

    @property
    def is_zero(self) -> bool:
        return self.rank == 0

    @classmethod
    def current(cls) -> "RankInfo":
        """The initialised default process group's rank and size; (0, 1) when there is none."""
        if is_initialized():
            return cls(dist.get_rank(), dist.get_world_size())
        return cls()

    @classmethod
    def resolve(cls, rank: Optional[int] = None, world_size: Optional[int] = None) -> "RankInfo":
        """Explicit values where given, the current process group's otherwise.

        Raises:
            ValueError naming ``rank`` / ``world_size`` when only one is given or they do not fit.
        """
        if rank is None and world_size is None:
            return cls.current()
        if rank is None or world_size is None:
            raise ValueError(f"give both rank and world_size or neither, got rank={rank!r}, "
                             f"world_size={world_size!r}")
        return cls(rank, world_size)


def is_initialized() -> bool:
    """Whether a default process group exists (torch.distributed available and initialised)."""
    return dist.is_available() and dist.is_initialized()


def launch_rank_is_zero() -> bool:
    """Whether this process is (or will be) global rank 0.

    With a process group: its rank. Before one exists, the launchers' environment variables:
    torchrun's ``RANK``; Lightning's own launcher's ``LOCAL_RANK`` and ``NODE_RANK`` (set in the
    processes it starts; checked before ``SLURM_PROCID``, which an interactive SLURM shell sets for
    every process); then SLURM's ``SLURM_PROCID`` (srun). No variable: a single process, rank 0.
    """
    if is_initialized():
        return dist.get_rank() == 0
    env = os.environ
    if "RANK" in env:
        return int(env["RANK"]) == 0
    if "LOCAL_RANK" in env:
        return int(env["LOCAL_RANK"]) == 0 and int(env.get("NODE_RANK", env.get("GROUP_RANK", 0))) == 0
    if "SLURM_PROCID" in env:
        return int(env["SLURM_PROCID"]) == 0
    return int(env.get("NODE_RANK", 0)) == 0


def local_rank() -> int:
    """This process's rank on its node from the launcher's environment (torchrun and Lightning:
    ``LOCAL_RANK``; SLURM: ``SLURM_LOCALID``); 0 without one. Picks the GPU of a process."""
    env = os.environ
    return int(env.get("LOCAL_RANK", env.get("SLURM_LOCALID", 0)))


def barrier() -> None:
    """``torch.distributed.barrier`` when a process group exists; nothing otherwise."""
    if is_initialized() and dist.get_world_size() > 1:
        dist.barrier()


# ------------------------------------------------------------------------------------------------
# Sharding


def shard_indices(num_items: int, rank: int, world_size: int, pad: bool = False) -> np.ndarray:
    """The items of ``range(num_items)`` that ``rank`` of ``world_size`` processes takes: one
    contiguous block per rank, in rank order, so that concatenating the ranks' blocks gives
    ``0..num_items-1`` in order.

    Args:
        num_items: size of the set (>= 0).
        rank, world_size: this process and the number of processes.
        pad: False: blocks of floor or ceil(num_items / world_size) items that cover each item exactly
            once (uneven sizes). True: every rank takes ceil(num_items / world_size) items, the last
            ranks' blocks wrapping around to the start (as ``DistributedSampler`` pads), so that all
            ranks run the same number of batches; the duplicates must be dropped after gathering
            (``gather_unique``).
    Returns:
        (K,) int64 item indices.
    """
    check_int(int(num_items) if isinstance(num_items, np.integer) else num_items, "num_items", minimum=0)
    info = RankInfo(int(rank), int(world_size))
    n, w, r = int(num_items), info.world_size, info.rank
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    if pad:
        per = -(-n // w)
        return np.arange(r * per, (r + 1) * per, dtype=np.int64) % n
    return np.arange(r * n // w, (r + 1) * n // w, dtype=np.int64)


# ------------------------------------------------------------------------------------------------
# Collectives


def _collective_device() -> torch.device:
    """Where tensors must be for the default group's backend (NCCL: this process's GPU)."""
    if dist.get_backend() == "nccl":
        return torch.device("cuda", torch.cuda.current_device())
    return torch.device("cpu")


def gather_uneven(tensor: torch.Tensor) -> torch.Tensor:
    """All-gathers a tensor whose first dimension may differ across ranks.

    Every rank must call it (a collective). Sizes are exchanged first, each rank's tensor is padded
    to the largest, gathered, and the padding cut off again.

    Args:
        tensor: (M_r, ...) on any device, any dtype (bool travels as uint8); the trailing
            dimensions and the dtype must be the same on every rank.
    Returns:
        (sum_r M_r, ...) the ranks' tensors concatenated in rank order, on ``tensor``'s device. Without
        a process group (or with one process): ``tensor`` itself.
    """
    check_tensor(tensor, "tensor", "N, ...")
    if not is_initialized() or dist.get_world_size() == 1:
        return tensor
    world = dist.get_world_size()
    device = _collective_device()
    is_bool = tensor.dtype == torch.bool
    local = (tensor.to(torch.uint8) if is_bool else tensor).to(device).contiguous()
    size = torch.tensor([local.shape[0]], dtype=torch.int64, device=device)
    sizes = [torch.zeros_like(size) for _ in range(world)]
    dist.all_gather(sizes, size)
    counts = [int(s.item()) for s in sizes]
    longest = max(counts)
    padded = local.new_zeros((longest, *local.shape[1:]))
    padded[: local.shape[0]] = local
    parts = [torch.empty_like(padded) for _ in range(world)]
    dist.all_gather(parts, padded)
    out = torch.cat([p[:c] for p, c in zip(parts, counts)])
    return (out.bool() if is_bool else out).to(tensor.device)


def gather_unique(keys: torch.Tensor, *values: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Gathers per-item results from every rank and keeps each key once (its first occurrence, in
    rank order): the evaluation items that ``shard_indices(pad=True)`` gave to two ranks count once.

    Args:
        keys: (M_r, K) int64, one row per item, unique per item (e.g. category, object, view).
        values: (M_r, ...) tensors, one row per item.
    Returns:
        (keys (U, K), *values (U, ...)): the distinct items in gathered order, on the inputs' devices.
    """
    check_shape(keys, "keys", "M, K")
    for i, v in enumerate(values):
        if v.shape[:1] != keys.shape[:1]:
            raise ValueError(f"values[{i}] has {v.shape[0] if v.dim() else 0} rows, keys have {keys.shape[0]}")
    keys = gather_uneven(keys)
    values = tuple(gather_uneven(v) for v in values)
    if keys.shape[0] == 0:
        return (keys, *values)
    _, inverse = torch.unique(keys.cpu(), dim=0, return_inverse=True)
    positions = torch.arange(len(inverse))
    first = torch.full((int(inverse.max()) + 1,), len(inverse), dtype=torch.int64)
    first = first.scatter_reduce(0, inverse, positions, reduce="amin").sort().values
    return (keys[first.to(keys.device)], *(v[first.to(v.device)] for v in values))


# ------------------------------------------------------------------------------------------------
# Joining a launcher's process group (tools that do not run under Lightning)


def environment_ranks() -> Optional[tuple[int, int, str, int]]:
    """(rank, world size, main address, main port) described by the launcher's environment, or None
    when it describes a single process.

    torchrun (and Lightning's own launcher): ``RANK``, ``WORLD_SIZE``, ``MASTER_ADDR``,
    ``MASTER_PORT``. SLURM, inside an ``srun`` step: ``SLURM_PROCID``, ``SLURM_STEP_NUM_TASKS`` (set
    by srun only, so a plain command in a batch script stays a single process), the first node of
    ``SLURM_STEP_NODELIST`` as the address and, unless ``MASTER_PORT`` is set, Lightning's port rule
    (15000 + the job id's last 4 digits).
    """
    env = os.environ
    if "WORLD_SIZE" in env and "RANK" in env:
        world = int(env["WORLD_SIZE"])
        if world <= 1:
            return None
        return int(env["RANK"]), world, env.get("MASTER_ADDR", "127.0.0.1"), int(env.get("MASTER_PORT", 29500))
    if "SLURM_STEP_NUM_TASKS" in env and "SLURM_PROCID" in env:
        world = int(env["SLURM_STEP_NUM_TASKS"])
        if world <= 1:
            return None

        nodes = env.get("SLURM_STEP_NODELIST", env.get("SLURM_NODELIST", "127.0.0.1"))
        addr = env.get("MASTER_ADDR") or SLURMEnvironment.resolve_root_node_address(nodes)
        port = int(env["MASTER_PORT"]) if "MASTER_PORT" in env else 15000 + int(env.get("SLURM_JOB_ID", "0")[-4:])
        return int(env["SLURM_PROCID"]), world, addr, port
    return None


@contextlib.contextmanager
def process_group_from_environment(backend: str = "gloo", timeout_s: float = 1800.0) -> Iterator[RankInfo]:
    """Joins the launcher's process group for the duration of the block; yields this RankInfo.

    An already initialised process group is used as it is (and left alone); an environment that
    describes one process (or none) yields ``RankInfo(0, 1)`` without a group. A group created here
    is destroyed on exit.

    Args:
        backend: "gloo" (CPU tensors; what gathering per-image results needs) or "nccl".
        timeout_s: how long a collective may wait for the slowest rank (evaluation shards differ in
            speed).
    """
    if is_initialized():
        yield RankInfo.current()
        return
    found = environment_ranks()
    if found is None:
        yield RankInfo()
        return
    rank, world, addr, port = found
    dist.init_process_group(backend, init_method=f"tcp://{addr}:{port}", rank=rank, world_size=world,
                            timeout=datetime.timedelta(seconds=timeout_s))
    try:
        yield RankInfo.current()
        # Every rank waits here for the slowest before tearing down. Gloo's worker threads drop
        # their last references to a finished collective's tensors after the caller has woken up,
        # and that needs the GIL: a rank that went on straight to interpreter shutdown could be
        # aborted ("terminate called without an active exception") while a worker still waited
        # for it. The barrier's wait releases the GIL and lets the workers finish first.
        dist.barrier()
    finally:
        dist.destroy_process_group()


__all__ = ["RankInfo", "is_initialized", "launch_rank_is_zero", "local_rank", "barrier", "shard_indices",
           "gather_uneven", "gather_unique", "environment_ranks", "process_group_from_environment"]
