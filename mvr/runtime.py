"""Process-wide settings for long CPU runs, called by ``python -m mvr`` and the benchmarks, never on
import (``configure_runtime``), with three effects, each large on machines whose few cores are
shared with other jobs (figures measured on one such machine: docs/measurements.md). Threads: the
command uses every core by default (``runtime.threads: null``), since with the fused renderer and
regularisers a 64^3 pass is much faster on 2 threads than on 1 (docs/mvr_method.md), but where
other jobs share the cores torch's intra-op threads wait for each other (this once made the 64^3
eikonal term many times slower on 2 threads), and ``runtime.threads=1`` is then better. Page
faults: glibc serves an allocation above its mmap threshold (128 KiB to start with) by a fresh
``mmap`` and returns it to the OS when freed, so each backward pass, which allocates many
grid-sized (1 MiB at 64^3) gradient buffers, can page-fault them in again; raising glibc's mmap
and trim thresholds and its top pad (``mallopt``, ``tune_allocator``) keeps freed memory in the
heap for reuse (``sdfcommon.tooling.host_memory``, shared with single-view training). Denormal
floats: Adam's second moments of the tiny gradients that far-away grid values receive underflow
into denormals, which x86 CPUs process far more slowly than normal floats, and flushing them to
zero (FTZ/DAZ, ``torch.set_flush_denormal``, for the calling thread) makes an update at 64^3
faster. (How the command stops on Ctrl+C or SIGTERM is ``sdfcommon.tooling.stopping``'s, shared
with the mesh builder.)
"""
from __future__ import annotations

import os
from typing import Optional

import numba
import torch

import renderer
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.host_memory import tune_allocator

def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask; ``os.cpu_count()`` where the
    platform has none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def configure_runtime(threads: Optional[int] = None, tune_malloc: bool = True, flush_denormal: bool = True) -> dict:
    """Sets torch's and numba's thread counts (None: every core this process may use,
    ``available_cores``) and, optionally, the allocator and the flushing of denormal floats (this
    thread).

    Returns:
        what was set: {"threads": int, "malloc_tuned": bool, "flush_denormal": bool}.
    """
    if threads is None:
        threads = available_cores()
    check_int(threads, "threads (None: all cores)", minimum=1)
    torch.set_num_threads(threads)
    try:
        # Setting numba's thread count starts its thread pool: let the renderer's kernels start
        # it first, with the layer they choose (renderer.start_cpu_thread_pool: torch's own
        # OpenMP runtime). The renderer's kernels run with torch's count; this sets it for numba's
        # other parallel kernels (the fallback ray caster).
        renderer.backend_available("cpu")
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    except (ImportError, ValueError):
        pass
    tuned = tune_allocator() if tune_malloc else False
    flushed = bool(torch.set_flush_denormal(True)) if flush_denormal else False
    return {"threads": threads, "malloc_tuned": tuned, "flush_denormal": flushed}
