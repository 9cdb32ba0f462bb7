"""sdfcommon.tooling.host_memory: on Linux/glibc a freed 64^3-grid-sized block stays in the process (to be reused
without page faults) instead of going back to the system, and the call is idempotent."""
from __future__ import annotations

import subprocess
import sys

import pytest

from sdfcommon.tooling.host_memory import keep_freed_memory

PROBE = r"""
import sys, torch
from sdfcommon.tooling.host_memory import keep_freed_memory
if sys.argv[1] == "on":
    assert keep_freed_memory() and keep_freed_memory()
def rss_kib():
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:"))
x = torch.ones(4 * 2**20)  # 16 MiB, touched
held = rss_kib()
del x
print(held - rss_kib())  # KiB the free gave back to the system
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc malloc settings")
def test_a_freed_16_mib_block_stays_in_the_process():
    def given_back_kib(mode: str) -> int:
        out = subprocess.run([sys.executable, "-c", PROBE, mode], check=True, capture_output=True, text=True)
        return int(out.stdout.strip().splitlines()[-1])

    assert given_back_kib("off") > 12 * 1024  # glibc's default: unmapped on free
    assert given_back_kib("on") < 1024        # kept for the next step's tensors
    assert keep_freed_memory() is True
