"""Host memory allocation for long CPU runs (single-view training, multi-view reconstruction): a
training step at the demo's size allocates and frees dozens of 4-16 MiB tensors (a batch's 64^3
grids and their gradients), and glibc serves blocks above its mmap threshold with fresh ``mmap``
pages that it returns on free, so every such tensor pays a page fault per 4 KiB page on first
touch, again on every step, a large part of a step's time on a CPU (docs/measurements.md).
Raising the threshold to its maximum (32 MiB on 64-bit Linux) and never trimming the heap keeps
those pages in the process for reuse; the process keeps its peak heap size, and blocks above
32 MiB are unaffected.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import logging
import sys

log = logging.getLogger(__name__)

_M_TRIM_THRESHOLD = -1
_M_TOP_PAD = -2
_M_MMAP_THRESHOLD = -3
_MMAP_THRESHOLD_MAX = 32 * 2**20  # glibc's limit on 64-bit: 4 MiB * sizeof(long)

_tuned = False


def tune_allocator(mmap_threshold: int = _MMAP_THRESHOLD_MAX, trim_threshold: int = 1 << 30,
                   top_pad: int = 64 << 20) -> bool:
    """Sets glibc malloc's mmap threshold, trim threshold and top pad (``mallopt``). Returns True
    where all three took effect (Linux with glibc); False elsewhere (nothing changed)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
    ok = (mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1) and ok
    return (mallopt(_M_TOP_PAD, int(top_pad)) == 1) and ok


def keep_freed_memory() -> bool:
    """Tells glibc malloc to keep freed blocks up to 32 MiB in the process (see the module
    docstring; ``tune_allocator`` with its defaults). Idempotent; returns True where it took effect
    (Linux with glibc), False elsewhere (other C libraries and systems keep their own behaviour)."""
    global _tuned
    if not _tuned and tune_allocator():
        _tuned = True
        log.debug("malloc keeps freed blocks up to %d MiB", _MMAP_THRESHOLD_MAX // 2**20)
    return _tuned


__all__ = ["keep_freed_memory", "tune_allocator"]
