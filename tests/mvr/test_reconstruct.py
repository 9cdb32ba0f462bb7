"""End to end: small reconstructions converge; outputs, resume and the command line work."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from mvr import (GridSettings, NoiseSettings, OptimSettings, Schedule, ScoringSettings, TargetSettings,
                 configure_runtime, reconstruct)

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module", autouse=True)
def _runtime():
    configure_runtime(threads=1)


def test_sphere_of_another_radius_converges(tmp_path):
    """A sphere of radius 0.5 from the initial sphere of radius 0.75, at 8^3 then 16^3; and the
    output folder's files."""
    result = reconstruct(
        "sphere", tmp_path,
        grid=GridSettings(init_radius=0.75),
        target_settings=TargetSettings(extent=1.0, mesh_resolution=64),
        schedule=Schedule(resolutions=[8, 16]),
        optim=OptimSettings(max_passes=3),
        evaluation=ScoringSettings(samples=5000), progress=False)
    m = result.metrics
    print({k: m[k] for k in ("hausdorff_rel", "chamfer_rel", "seconds")})
    radii = np.linalg.norm(result.mesh.vertices, axis=1)
    assert abs(radii.mean() - 0.5) < 0.02  # the voxel is 0.133, 0.077 of the diagonal
    assert m["hausdorff_rel"] < 0.035 and m["chamfer_rel"] < 0.012  # measured: 0.018, 0.007
    assert m["mesh_genus"] == 0 and m["mesh_watertight"]
    losses = [r.loss_end for r in result.levels]
    assert losses[-1] < result.levels[0].loss_start / 5
    for name in ("grid.npz", "mesh.ply", "mesh.obj", "target.ply", "views.png", "levels.json", "levels.csv",
                 "metrics.json", "settings.json", "checkpoints/level_00.pt", "checkpoints/level_01.pt"):
        assert (tmp_path / name).is_file(), name
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["hausdorff_rel"] == pytest.approx(m["hausdorff_rel"])
    assert "bounding-box diagonal" in saved["normalisation"] and saved["seconds"] > 0
    grid = np.load(tmp_path / "grid.npz")
    assert grid["values"].shape == (16, 16, 16)
    assert trimesh.load(tmp_path / "mesh.ply").is_watertight
    assert not list(tmp_path.glob(".*.tmp")), "temporary files left behind"


def test_torus_converges_with_its_hole(tmp_path):
    result = reconstruct(
        "torus", tmp_path,
        target_settings=TargetSettings(mesh_resolution=96),
        schedule=Schedule(resolutions=[8, 16, 24]),
        optim=OptimSettings(max_passes=4),
        evaluation=ScoringSettings(samples=5000), progress=False)
    m = result.metrics
    print({k: m[k] for k in ("hausdorff_rel", "chamfer_rel", "seconds")})
    assert m["mesh_genus"] == 1 and m["mesh_components"] == 1
    # One voxel at 24^3 is 0.038 of the torus's diagonal (measured: 0.013 and 0.003).
    assert m["hausdorff_rel"] < 0.03 and m["chamfer_rel"] < 0.006


def test_resume_and_settings_guard(tmp_path):
    kwargs = dict(target_settings=TargetSettings(extent=1.0, mesh_resolution=48),
                  schedule=Schedule(resolutions=[8, 12]), optim=OptimSettings(max_passes=1),
                  evaluation=ScoringSettings(samples=500), progress=False)
    first = reconstruct("sphere", tmp_path, **kwargs)
    again = reconstruct("sphere", tmp_path, **kwargs)
    assert again.metrics["resumed_from_level"] == 2  # both levels were already done
    np.testing.assert_array_equal(again.grid.values.numpy(), first.grid.values.numpy())
    (tmp_path / "checkpoints" / "level_01.pt").unlink()  # as if killed during the last level
    third = reconstruct("sphere", tmp_path, **kwargs)
    assert third.metrics["resumed_from_level"] == 1 and len(third.levels) == 2
    with pytest.raises(ValueError, match="other settings"):
        reconstruct("sphere", tmp_path, noise=NoiseSettings(image_std=0.1), **kwargs)
    # Evaluation settings do not shape the fit: a rerun with more samples resumes.
    more = reconstruct("sphere", tmp_path, **{**kwargs, "evaluation": ScoringSettings(samples=800)})
    assert more.metrics["resumed_from_level"] == 2 and more.metrics["samples"] == 800
    fresh = reconstruct("sphere", tmp_path, noise=NoiseSettings(image_std=0.1), resume=False, **kwargs)
    assert fresh.metrics["resumed_from_level"] is None
    (tmp_path / "checkpoints" / "level_01.pt").write_bytes(b"truncated")
    with pytest.raises(ValueError, match="level_01.pt"):
        reconstruct("sphere", tmp_path, noise=NoiseSettings(image_std=0.1), **kwargs)


def test_noise_options_run(tmp_path):
    result = reconstruct("sphere", tmp_path, noise=NoiseSettings(image_std=0.17, camera_std=0.05),
                         target_settings=TargetSettings(extent=1.0, mesh_resolution=48),
                         schedule=Schedule(resolutions=[8]), optim=OptimSettings(max_passes=1),
                         evaluation=ScoringSettings(samples=500), progress=False)
    assert result.metrics["hausdorff_rel"] is not None


def test_bad_settings(tmp_path):
    with pytest.raises(ValueError, match="extent"):
        reconstruct("sphere", tmp_path, target_settings=TargetSettings(extent=2.5))
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        reconstruct(str(tmp_path / "missing.ply"), tmp_path / "out")
    with pytest.raises(ValueError, match="init_radius"):
        GridSettings(init_radius=2.0)
    with pytest.raises(ValueError, match="image_std"):
        NoiseSettings(image_std=-1.0)


def test_command_line(tmp_path):
    """``python -m mvr`` with hydra overrides writes metrics.json (the console script is the same main)."""
    out = tmp_path / "cli"
    cmd = [sys.executable, "-m", "mvr", "target=sphere", f"out_dir={out}", "schedule.resolutions=[8]",
           "optim.max_passes=1", "target_settings.extent=1.0", "target_settings.mesh_resolution=48",
           "evaluation.samples=500", "progress=false", "mvr/noise=image"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert {"hausdorff_rel", "chamfer_rel", "seconds"} <= metrics.keys()
    settings = json.loads((out / "settings.json").read_text())
    assert settings["noise"]["image_std"] == pytest.approx(0.1732)
    # The console script sdfdiff-mvr calls mvr.__main__:main with the same argv.
    script = ("import sys; from mvr.__main__ import main; "
              f"sys.argv = ['sdfdiff-mvr', 'target=nosuchshape', 'out_dir={tmp_path / 'bad'}']; main()")
    bad = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert bad.returncode != 0 and "nosuchshape" in bad.stderr and "built-in shape" in bad.stderr
