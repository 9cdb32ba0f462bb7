"""Long runs (``pytest -m slow``): the torus benchmark at full scale (the parameter studies:
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

