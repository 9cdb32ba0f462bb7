"""Long runs (``pytest -m slow -n 0``): the torus benchmark at full scale (the parameter studies:
tests/benchmarks/test_mvr_parameter_study.py)."""
from __future__ import annotations

import pytest

from mvr import configure_runtime, reconstruct
from mvr.settings import compose_config, reconstruct_kwargs

pytestmark = pytest.mark.slow


def test_torus_benchmark(tmp_path):
    """The issue's target: relative symmetric Hausdorff <= 0.0156 (paper: 0.015637) with the
    command's default settings. The 15-minute budget depends on the machine's load, so the time is
    reported, not asserted."""
    configure_runtime(threads=1)
    cfg = compose_config(["target=torus", f"out_dir={tmp_path}", "progress=false"])
    m = reconstruct("torus", tmp_path, **reconstruct_kwargs(cfg)).metrics
    print(f"torus: hausdorff_rel {m['hausdorff_rel']:.5f} chamfer_rel {m['chamfer_rel']:.5f} "
          f"in {m['seconds']:.0f}s")
    assert m["hausdorff_rel"] <= 0.0156
    assert m["mesh_genus"] == 1 and m["mesh_components"] == 1



@pytest.mark.parametrize("signame, status", [("SIGINT", 130), ("SIGTERM", 143)])
def test_a_signal_stops_the_command_in_one_line_and_the_same_command_resumes(signame, status, tmp_path):
    """Issue 40 item 16 with real signals (Ctrl+C sends SIGINT): one line on stderr, exit status
    130 / 143, and rerunning the same command resumes after the last finished level (the fast
    in-process version: tests/mvr/test_cli.py)."""
    import json
    import re
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "mvr", "target=sphere", f"out_dir={out}", "progress=false",
           "runtime.threads=1", "schedule.resolutions=[8,16]", "optim.max_passes=[1,4]", "optim.min_passes=4",
           "target_settings.mesh_resolution=48", "evaluation.samples=500"]
    proc = subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while not (out / "checkpoints" / "level_01.pt").exists() and proc.poll() is None:
            assert time.monotonic() < deadline, "level 1 did not finish"
            time.sleep(0.05)
        proc.send_signal(getattr(signal, signame))
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == status, err[-3000:]
    lines = [line for line in err.splitlines() if line.strip() and "Warning" not in line]
    assert len(lines) == 1 and "Traceback" not in err, err[-3000:]
    done = int(re.search(r"after level (\d) of 2", lines[0]).group(1))
    assert f"out_dir={out}" in lines[0] and "rerun the same command" in lines[0], lines[0]
    assert (out / "checkpoints" / f"level_{done:02d}.pt").is_file()
    again = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    assert json.loads((out / "metrics.json").read_text())["resumed_from_level"] == done
