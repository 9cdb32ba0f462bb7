"""benchmarks.renderer_speed: it runs as a module, and its memory probe (a fresh
``python -m benchmarks.renderer_speed`` process) measures a toy forward + backward."""
from __future__ import annotations

import subprocess
import sys

from benchmarks.renderer_speed import ROOT, Config, memory_in_subprocess


def test_runs_as_a_module():
    out = subprocess.run([sys.executable, "-m", "benchmarks.renderer_speed", "--help"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    assert "Renderer speed" in out and "--device" in out


def test_memory_probe_of_a_toy_scene():
    got = memory_in_subprocess(Config(image=16, batch=1, grid=16), "cpu", threads=1)
    assert got["method"] in ("VmHWM", "ru_maxrss") and got["peak_mib"] >= 0.0
