"""End to end: small reconstructions converge; outputs, resume and the command line work."""
from __future__ import annotations

import csv
import dataclasses
import importlib
import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from mvr import (GridSettings, NoiseSettings, OptimSettings, Schedule, ScoringSettings, TargetSettings,
                 configure_runtime, default_scene, reconstruct)
from renderer import SDFGrid

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
                 "metrics.json", "settings.json", "checkpoints/level_01.pt", "checkpoints/level_02.pt"):
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
                  schedule=Schedule(resolutions=[8, 12]), optim=OptimSettings(max_passes=1, residual_carve=0.0),
                  evaluation=ScoringSettings(samples=500), progress=False)
    first = reconstruct("sphere", tmp_path, **kwargs)
    again = reconstruct("sphere", tmp_path, **kwargs)
    assert again.metrics["resumed_from_level"] == 2  # both levels were already done
    np.testing.assert_array_equal(again.grid.values.numpy(), first.grid.values.numpy())
    (tmp_path / "checkpoints" / "level_02.pt").unlink()  # as if killed during the last level
    third = reconstruct("sphere", tmp_path, **kwargs)
    assert third.metrics["resumed_from_level"] == 1 and len(third.levels) == 2
    with pytest.raises(ValueError, match="other settings"):
        reconstruct("sphere", tmp_path, noise=NoiseSettings(image_std=0.1), **kwargs)
    # Evaluation settings do not shape the fit: a rerun with more samples resumes.
    more = reconstruct("sphere", tmp_path, **{**kwargs, "evaluation": ScoringSettings(samples=800)})
    assert more.metrics["resumed_from_level"] == 2 and more.metrics["samples"] == 800
    fresh = reconstruct("sphere", tmp_path, noise=NoiseSettings(image_std=0.1), resume=False, **kwargs)
    assert fresh.metrics["resumed_from_level"] is None
    (tmp_path / "checkpoints" / "level_02.pt").write_bytes(b"truncated")
    with pytest.raises(ValueError, match="level_02.pt"):
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


def test_bad_settings_are_refused_before_the_folder_is_made(tmp_path):
    """Issue 40 items 5 and 13: the seed, the pass limits, the light and the target settings are
    checked when reconstruct starts (or when the settings are made), before anything is written."""
    out = tmp_path / "never"
    with pytest.raises(ValueError, match=r"seed must be an integer in \[0, 4294967295\], got -1"):
        reconstruct("sphere", out, seed=-1)
    with pytest.raises(ValueError, match="scene.camera_light must be a finite number >= 0, got -2"):
        reconstruct("sphere", out, scene=dataclasses.replace(default_scene(), camera_light=-2.0))
    with pytest.raises(ValueError, match="backend must be one of"):
        reconstruct("sphere", out, backend="bogus")
    assert not out.exists()
    for bad in (0, -5, [3, 0], [], 2.5):
        with pytest.raises(ValueError, match="max_passes must be"):
            OptimSettings(max_passes=bad)
    for bad in (0, -1.0, [10, -1]):
        with pytest.raises(ValueError, match="max_seconds must be"):
            OptimSettings(max_seconds=bad)
    assert OptimSettings(max_passes=[3, 2], max_seconds=[None, 5]).for_level("max_seconds", 1) == 5
    with pytest.raises(ValueError, match="normals must be one of"):
        TargetSettings(normals="bumpy")
    with pytest.raises(ValueError, match="mesh_resolution must be an integer >= 16"):
        TargetSettings(mesh_resolution=8)
    with pytest.raises(ValueError, match="extent must be a positive"):
        TargetSettings(extent=-1.0)


# The residual carve (on by default) off where a test's subject is not it: its stage would change the counts.
SMALL = dict(target_settings=TargetSettings(extent=1.0, mesh_resolution=48),
             optim=OptimSettings(max_passes=1, residual_carve=0.0),
             evaluation=ScoringSettings(samples=500), progress=False)


def test_levels_are_numbered_from_one_in_files_logs_and_resume(tmp_path, caplog):
    """Issue 40 item 17: the log counts levels from 1 ("level 2/2"); so do the checkpoints, levels.json
    and levels.csv, the resume message and metrics.json's resumed_from_level."""
    caplog.set_level(logging.INFO, logger="mvr")
    reconstruct("sphere", tmp_path, schedule=Schedule(resolutions=[8, 12]), **SMALL)
    assert sorted(p.name for p in (tmp_path / "checkpoints").iterdir()) == ["level_01.pt", "level_02.pt"]
    assert [r["level"] for r in json.loads((tmp_path / "levels.json").read_text())] == [1, 2]
    rows = list(csv.DictReader((tmp_path / "levels.csv").open()))
    assert [r["level"] for r in rows] == ["1", "2"]
    assert any(m.startswith("level 1/2 8^3") for m in caplog.messages), caplog.messages
    (tmp_path / "checkpoints" / "level_02.pt").unlink()
    caplog.clear()
    again = reconstruct("sphere", tmp_path, schedule=Schedule(resolutions=[8, 12]), **SMALL)
    resumed = [m for m in caplog.messages if m.startswith("resuming")]
    assert resumed and resumed[0].startswith("resuming after level 1 of 2 (8^3)"), caplog.messages
    assert any(m.startswith("level 2/2 12^3") for m in caplog.messages)
    assert not any(m.startswith("level 1/2") for m in caplog.messages)
    assert again.metrics["resumed_from_level"] == 1 and [r.level for r in again.levels] == [1, 2]


def test_a_resumed_run_writes_the_target_mesh_of_a_fresh_run(tmp_path):
    """Issue 40 item 17: target.ply is the same file (vertex normals included) whether the run was
    fresh, resumed after its last level, or shaded with face normals."""
    fresh = reconstruct("sphere", tmp_path / "a", schedule=Schedule(resolutions=[8]), **SMALL)
    written = (tmp_path / "a" / "target.ply").read_bytes()
    header = written[:written.index(b"end_header")].decode()
    assert "property float nx" in header or "property double nx" in header, header
    again = reconstruct("sphere", tmp_path / "a", schedule=Schedule(resolutions=[8]), **SMALL)
    assert fresh.metrics["resumed_from_level"] is None and again.metrics["resumed_from_level"] == 1
    assert (tmp_path / "a" / "target.ply").read_bytes() == written
    face = {**SMALL, "target_settings": TargetSettings(extent=1.0, mesh_resolution=48, normals="face")}
    reconstruct("sphere", tmp_path / "b", schedule=Schedule(resolutions=[8]), **face)
    assert (tmp_path / "b" / "target.ply").read_bytes() == written


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


def test_refined_cameras_are_checkpointed_and_resumed(tmp_path):
    """optim.cameras: the corrections go into each level's checkpoint, a run resumed after its first
    level ends where the uninterrupted one did, bit for bit, and metrics.json says how far the
    cameras were from the true ones as given and at the end."""
    kwargs = dict(target_settings=TargetSettings(extent=1.0, mesh_resolution=48),
                  schedule=Schedule(resolutions=[8, 12]), noise=NoiseSettings(camera_std=0.05),
                  optim=OptimSettings(max_passes=1, residual_carve=0.0, cameras=True, camera_levels=2),
                  evaluation=ScoringSettings(samples=500), progress=False)
    first = reconstruct("torus", tmp_path, **kwargs)
    ckpt = torch.load(tmp_path / "checkpoints" / "level_01.pt", weights_only=False)
    assert ckpt["poses"]["orbit"].abs().sum() > 0 and ckpt["poses"]["aim"].abs().sum() > 0
    (tmp_path / "checkpoints" / "level_02.pt").unlink()
    again = reconstruct("torus", tmp_path, **kwargs)
    assert again.metrics["resumed_from_level"] == 1
    np.testing.assert_array_equal(again.grid.values.numpy(), first.grid.values.numpy())
    m = first.metrics
    for key in ("eye_error", "angle_error_deg", "reprojection_px"):
        assert m[f"camera_{key}_given"] > 0 and np.isfinite(m[f"camera_{key}_final"])
    assert m["camera_eye_error_final"] != m["camera_eye_error_given"]  # the cameras moved
    plain = reconstruct("torus", tmp_path / "plain",
                        **{**kwargs, "optim": OptimSettings(max_passes=1, residual_carve=0.0)})
    assert plain.metrics["camera_eye_error_final"] == plain.metrics["camera_eye_error_given"]
    # A checkpoint of the earlier parameterisation (a turn and a shift of each eye) is refused
    # before anything is written, naming the file.
    old = {**ckpt, "poses": {"rotation": torch.zeros(26, 3), "translation": torch.zeros(26, 3), "adam": {}}}
    torch.save(old, tmp_path / "checkpoints" / "level_01.pt")
    (tmp_path / "checkpoints" / "level_02.pt").unlink()
    stamp = (tmp_path / "metrics.json").stat().st_mtime_ns
    with pytest.raises(ValueError, match="level_01.pt.*earlier version.*resume=false"):
        reconstruct("torus", tmp_path, **kwargs)
    assert (tmp_path / "metrics.json").stat().st_mtime_ns == stamp


def test_camera_rounds_run_the_schedule_again_with_the_refined_cameras(tmp_path):
    """optim.camera_rounds=2: the schedule runs twice (its stages checkpointed on, level_01 to
    level_04), the second round starting from the sphere with the cameras the first refined; a run
    resumed at the second round's start ends where the uninterrupted one did, bit for bit; rounds
    without camera refinement are refused."""
    kwargs = dict(target_settings=TargetSettings(extent=1.0, mesh_resolution=48),
                  schedule=Schedule(resolutions=[8, 12]), noise=NoiseSettings(camera_std=0.05),
                  optim=OptimSettings(max_passes=1, residual_carve=0.0, cameras=True, camera_rounds=2),
                  evaluation=ScoringSettings(samples=500), progress=False)
    first = reconstruct("torus", tmp_path, **kwargs)
    assert [r.resolution for r in first.levels] == [8, 12, 8, 12]
    assert first.metrics["levels"] == 4
    names = sorted(p.name for p in (tmp_path / "checkpoints").glob("level_*.pt"))
    assert names == ["level_01.pt", "level_02.pt", "level_03.pt", "level_04.pt"]
    one = torch.load(tmp_path / "checkpoints" / "level_02.pt", weights_only=False)["poses"]
    three = torch.load(tmp_path / "checkpoints" / "level_03.pt", weights_only=False)["poses"]
    # the second round's first level sees the corrected cameras but does not move them
    assert one["orbit"].abs().sum() > 0 and torch.equal(one["orbit"], three["orbit"])
    assert torch.equal(one["aim"], three["aim"])
    single = reconstruct("torus", tmp_path / "single",
                         **{**kwargs, "optim": OptimSettings(max_passes=1, residual_carve=0.0, cameras=True)})
    assert single.metrics["levels"] == 2
    assert not np.array_equal(single.grid.values.numpy(), first.grid.values.numpy())
    for k in (3, 4):
        (tmp_path / "checkpoints" / f"level_{k:02d}.pt").unlink()
    again = reconstruct("torus", tmp_path, **kwargs)
    assert again.metrics["resumed_from_level"] == 2
    np.testing.assert_array_equal(again.grid.values.numpy(), first.grid.values.numpy())
    with pytest.raises(ValueError, match="camera_rounds=2 needs cameras=true"):
        OptimSettings(camera_rounds=2)


def test_residual_carve_with_refined_cameras_comes_after_the_last_round_and_refines_them_on(tmp_path):
    """With ``optim.cameras`` the residual carve is one stage after the last camera round (the fifth
    checkpoint of two rounds of a 2-level schedule, reported as level 3), at the last level's
    resolution; its rays are the refined cameras' and its refit goes on refining them (the poses
    move between level_04 and level_05)."""
    kwargs = dict(target_settings=TargetSettings(extent=1.0, mesh_resolution=48),
                  schedule=Schedule(resolutions=[8, 12]), noise=NoiseSettings(camera_std=0.05),
                  optim=OptimSettings(max_passes=1, cameras=True, camera_rounds=2, residual_carve=2.0,
                                      refit_passes=1),
                  evaluation=ScoringSettings(samples=500), progress=False)
    result = reconstruct("torus", tmp_path, **kwargs)
    assert [r.resolution for r in result.levels] == [8, 12, 8, 12, 12]
    assert [r.level for r in result.levels] == [1, 2, 1, 2, 3]
    four = torch.load(tmp_path / "checkpoints" / "level_04.pt", weights_only=False)["poses"]
    five = torch.load(tmp_path / "checkpoints" / "level_05.pt", weights_only=False)["poses"]
    assert not torch.equal(four["orbit"], five["orbit"])


def test_erosion_shrinks_the_last_levels_start_and_gives_them_their_passes(tmp_path, monkeypatch):
    """``optim.erosion``: the last ``erosion_levels`` levels (never the first) start from the level
    before with every value raised by ``erosion`` of their voxels, and run up to
    ``erosion_pass_factor`` times their passes."""
    rec = importlib.import_module("mvr.reconstruct")  # the package's ``reconstruct`` is the function
    starts = []
    real = rec.optimise_level

    def spy(grid, losses, level, seed, progress, description, max_passes=None):
        starts.append((level, grid.values.clone(), float(grid.voxel_size.min()), max_passes))
        return real(grid, losses, level, seed, progress, description, max_passes=max_passes)

    monkeypatch.setattr(rec, "optimise_level", spy)
    settings = dict(SMALL, optim=OptimSettings(max_passes=1, min_passes=2, erosion=2.0, erosion_keep=None, erosion_levels=2,
                                               erosion_pass_factor=2.0, hard_view_updates=1,
                                               easy_view_updates=1, residual_carve=0.0))
    result = reconstruct("sphere", tmp_path / "eroded", schedule=Schedule(resolutions=[8, 12, 16]), **settings)
    assert [s[0] for s in starts] == [0, 1, 2]
    assert [s[3] for s in starts] == [1, 2, 2]
    assert [r.passes for r in result.levels][1:] == [2, 2]
    for level, res in ((1, 12), (2, 16)):
        before = torch.load(tmp_path / "eroded" / "checkpoints" / f"level_0{level}.pt", weights_only=False)
        resampled = SDFGrid(before["values"], before["bbox_min"], before["bbox_max"]).resample(res).values
        assert torch.allclose(starts[level][1], resampled + 2.0 * starts[level][2], atol=1e-6)
    assert not OptimSettings(erosion=2.0).erodes(0, 4) and OptimSettings(erosion=2.0).erodes(3, 4)
    assert not OptimSettings(erosion=2.0).erodes(2, 4) and not OptimSettings(erosion=0.0).erodes(3, 4)
    # refined cameras would take the shrunk start's silhouettes for camera error: no erosion, no extra passes
    assert not OptimSettings(erosion=2.0, cameras=True).erodes(3, 4)
    assert OptimSettings(erosion=2.0, cameras=True).passes(3, 4) == 10
    assert OptimSettings(max_passes=[10, 10, 10, 15]).passes(3, 4) == 30
    assert OptimSettings(max_passes=3, erosion_pass_factor=1.5).passes(3, 4) == 5
    assert OptimSettings(max_passes=3).passes(2, 4) == 3 and OptimSettings(erosion=0.0).passes(3, 4) == 10
    for bad, match in ((dict(erosion=-1.0), "erosion must be"), (dict(erosion_levels=0), "erosion_levels"),
                       (dict(erosion_pass_factor=0.5), "erosion_pass_factor")):
        with pytest.raises(ValueError, match=match):
            OptimSettings(**bad)


def test_residual_carve_adds_a_refit_after_the_schedule_that_a_rerun_resumes_after(tmp_path):
    """``optim.residual_carve``: one more stage after the last level, at its resolution and images,
    numbered on (level 3 of a 2-level schedule), with at most ``refit_passes`` passes; its
    checkpoint is where a rerun resumes; two rounds, two stages."""
    optim = OptimSettings(max_passes=1, residual_carve=2.0, refit_passes=2, refit_lr_scale=0.2)
    settings = dict(SMALL, optim=optim)
    result = reconstruct("sphere", tmp_path, schedule=Schedule(resolutions=[8, 12]), **settings)
    assert [r.level for r in result.levels] == [1, 2, 3]
    assert [r.resolution for r in result.levels] == [8, 12, 12]
    assert result.levels[2].image_size == result.levels[1].image_size and result.levels[2].passes <= 2
    assert (tmp_path / "checkpoints" / "level_03.pt").is_file()
    again = reconstruct("sphere", tmp_path, schedule=Schedule(resolutions=[8, 12]), **settings)
    assert again.metrics["resumed_from_level"] == 3
    two = dict(SMALL, optim=OptimSettings(max_passes=1, residual_carve=2.0, residual_carve_rounds=2, refit_passes=2,
                                          refit_batch_steps=3))
    twice = reconstruct("sphere", tmp_path / "two", schedule=Schedule(resolutions=[8, 12]), **two)
    assert [r.level for r in twice.levels] == [1, 2, 3, 4]  # each round a stage of its own
    assert twice.levels[1].updates >= 26  # the levels update view by view, the refits on all views at once
    assert [r.updates for r in twice.levels[2:]] == [3 * r.passes for r in twice.levels[2:]]
    assert (tmp_path / "two" / "checkpoints" / "level_04.pt").is_file()
    with pytest.raises(ValueError, match="residual_carve_rounds"):
        OptimSettings(residual_carve=2.0, residual_carve_rounds=0)
