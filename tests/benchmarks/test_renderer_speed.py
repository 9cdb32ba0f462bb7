"""benchmarks.renderer_speed: it runs as a module, and its memory probe (a fresh
``python -m benchmarks.renderer_speed`` process) measures a toy forward + backward."""
from __future__ import annotations

import subprocess
import sys

from benchmarks.renderer_speed import ROOT, Config, cpu_table, memory_in_subprocess, table


def test_runs_as_a_module():
    out = subprocess.run([sys.executable, "-m", "benchmarks.renderer_speed", "--help"], cwd=ROOT,
                         capture_output=True, text=True, check=True).stdout
    assert "Renderer speed" in out and "--device" in out


def test_memory_probe_of_a_toy_scene():
    got = memory_in_subprocess(Config(image=16, batch=1, grid=16), "cpu", "auto", "visibility", threads=1)
    assert got["peak_mib"] >= 0.0
    for stage2 in ("auto", "reference"):
        got = memory_in_subprocess(Config(image=16, batch=1, grid=16), "cpu", stage2, "paper", threads=1)
        assert got["method"] in ("VmHWM", "ru_maxrss") and got["peak_mib"] >= 0.0


def test_tables_show_every_pipeline():
    row = {"hit_fraction": 0.3, "march_reference": 100.0, "march_fused": 20.0, "render_reference": 200.0,
           "render_fused_march": 80.0, "render_fused": 40.0, "render_visibility": 100.0, "mem_reference": 90.0,
           "mem_fused_march": 95.0, "mem_fused": 40.0, "mem_visibility": 97.0,
           **{f"{k}_cpu": 1.0 for k in ("march_reference", "march_fused", "render_reference", "render_fused_march",
                                        "render_fused", "render_visibility")}}
    text = table([(Config(64, 32), row)])
    # fused, per image, vs reference, f+b / march, visibility and its cost over fused
    assert "| 40.0 | 1.25 | 5.0x | 2.00 | 100.0 | 2.50 | 90 / 95 / 40 / 97 |" in text
    assert "| 1.0 | 1.0 | 1.0 | 1.0x | 1.0 |" in cpu_table([(Config(64, 32), row)])
