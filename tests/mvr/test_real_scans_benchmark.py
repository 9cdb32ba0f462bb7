"""benchmarks.mvr_real_scans and mvr.error_map at toy size: the mesh folder's checks and repairs,
the error colours and picture, the table, and a whole toy run of the command."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh

import benchmarks.mvr_real_scans as module
from benchmarks.accuracy_vs_time_mvr import QUICK
from mvr import RigSettings
from mvr.error_map import error_colours, error_picture, error_views
from mvr.reconstruct import default_scene


def _open_box() -> trimesh.Trimesh:
    box = trimesh.creation.box((1.0, 0.8, 0.6))
    return trimesh.Trimesh(box.vertices, box.faces[1:], process=False)  # one triangle missing


def _mesh_folder(tmp_path):
    folder = tmp_path / "meshes"
    folder.mkdir()
    trimesh.creation.icosphere(subdivisions=2, radius=0.5).export(folder / "ball.ply")
    _open_box().export(folder / "holey.off")
    sheet = trimesh.creation.box((1.0, 1.0, 1.0)).subdivide().subdivide()
    trimesh.Trimesh(sheet.vertices, sheet.faces[sheet.triangles_center[:, 2] < 0.49]).export(folder / "lid_off.obj")
    (folder / "broken.ply").write_bytes(b"ply\nformat nonsense\n")
    (folder / "notes.txt").write_text("not a mesh")
    return folder


def test_prepare_meshes_repairs_small_holes_and_leaves_out_the_rest(tmp_path):
    folder = _mesh_folder(tmp_path)
    prepared = {m.name: m for m in module.prepare_meshes(folder, [], tmp_path / "work", max_hole_edges=8)}
    assert set(prepared) == {"ball", "holey", "lid_off", "broken"}
    assert prepared["ball"].target == str(folder / "ball.ply") and prepared["ball"].note == ""
    repaired = trimesh.load(prepared["holey"].target, force="mesh")
    assert repaired.is_watertight and "3 boundary edges closed" in prepared["holey"].note
    assert prepared["lid_off"].target is None and "boundary edges" in prepared["lid_off"].note
    assert prepared["broken"].target is None and "unreadable" in prepared["broken"].note
    only = module.prepare_meshes(folder, ["ball"], tmp_path / "work", 8)
    assert [m.name for m in only] == ["ball"]
    with pytest.raises(ValueError, match="no mesh named cow"):
        module.prepare_meshes(folder, ["cow"], tmp_path / "work", 8)
    with pytest.raises(ValueError, match="not a folder"):
        module.prepare_meshes(folder / "ball.ply", [], tmp_path / "work", 8)


def test_error_colours_ramp():
    c = error_colours(np.array([0.0, 0.5, 1.0, 3.0]), vmax=1.0)
    assert c.shape == (4, 3)
    np.testing.assert_allclose(c[2], c[3])  # saturated at vmax
    assert c[0].std() < 1e-9 and c[3, 0] > 0.5 > c[3, 1]  # grey at 0, red at vmax
    with pytest.raises(ValueError, match="vmax"):
        error_colours(np.zeros(2), 0.0)


def test_error_views_measure_the_distance_to_the_other_surface():
    inner = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    outer = trimesh.creation.icosphere(subdivisions=4, radius=0.6)
    cams = RigSettings().cameras(24)[[0, 18]]
    views = error_views(outer, inner, cams, default_scene(), vmax=0.2)
    hit = np.isfinite(views.distances)
    assert hit.any() and not hit.all()
    np.testing.assert_allclose(views.distances[hit], 0.1, atol=0.01)  # the radii differ by 0.1
    assert (views.colours[~hit] == 1.0).all()  # white background
    assert views.colours.shape == (2, 24, 24, 3)


def test_error_picture_marks_a_bump_red():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    bumped = sphere.copy()
    top = bumped.vertices[:, 1] > 0.45
    bumped.vertices[top] *= 1.3  # a bump on top, 0.15 high
    cams = RigSettings().cameras(48)[[2]]  # looking along -x: the bump is seen at the top
    picture = error_picture(sphere, bumped, cams, default_scene(), vmax=0.05, view_names=["side"])
    assert picture.ndim == 3 and picture.shape[2] == 3
    red = (picture[..., 0] > 0.6) & (picture[..., 1] < 0.25) & (picture[..., 2] < 0.25)
    assert red.sum() > 20  # the bump, red (distances above vmax)
    with pytest.raises(ValueError, match="view names"):
        error_picture(sphere, bumped, cams, default_scene(), 0.05, ["a", "b"])


def test_table_and_summary():
    meshes = [module.PreparedMesh("ChineseDragon", "d.ply", "6 boundary edges closed (fill_holes)"),
              module.PreparedMesh("lid", None, "left out: 40 boundary edges")]
    metrics = {"hausdorff_rel": 0.031, "chamfer_rel": 0.0021, "seconds": 95.2, "mesh_watertight": True,
               "mesh_genus": 1.0, "target_genus": 1.0, "mesh_faces": 1000}
    rows = [module.result_row(meshes[0], "default", metrics, 0.012, 2.46, {"hausdorff_rel": 0.0123, "genus": 1.0}),
            module.result_row(meshes[0], "paper", dict(metrics, hausdorff_rel=0.05, seconds=80.0), 0.02),
            module.result_row(meshes[1], "default", None, None)]
    table = module.markdown_table(rows, ["default", "paper"])
    lines = table.splitlines()
    assert lines[0].count("|") == 1 + 1 + 7 * 2 + 2  # mesh, 7 columns per configuration, paper, note
    dragon = next(line for line in lines if line.startswith("| ChineseDragon |"))
    assert "0.0310" in dragon and "0.0500" in dragon and "0.074723" in dragon and "yes, 1 / 1" in dragon
    assert "| 95 | 2.5 |" in dragon and "| yes, 1 / 1 | 0.0123 |" in dragon
    assert "left out: 40 boundary edges" in table
    text = module.summary(rows, ["default", "paper"], goal=0.04)
    assert "`default`: worst relative Hausdorff 0.0310 (ChineseDragon); 1 of 1 at most 0.04" in text
    assert "the truth on the same grids: 1 of 1 at most 0.04, worst 0.0123" in text
    assert "`paper`: worst relative Hausdorff 0.0500 (ChineseDragon); 0 of 1" in text
    assert module.paper_value("bunny00") == 0.026654 and module.paper_value("cow") is None
    levels = [{"history": [{"seconds": 1.0}]}, {"history": [{"seconds": 2.0}, {"seconds": 4.0}]}]
    assert module.finest_pass_seconds(levels) == 3.0 and module.finest_pass_seconds([]) is None


def test_grid_truth_bridges_a_gap_narrower_than_the_grid(tmp_path):
    """Two slabs 0.1 apart: on a grid whose samples straddle the gap the truth itself bridges it
    (one part, its inner faces far from the mesh); on a grid fine enough the gap and both parts stay."""
    slabs = trimesh.util.concatenate([trimesh.creation.box((0.6, 0.6, 0.3)).apply_translation((0, 0, z))
                                      for z in (-0.2, 0.2)])
    sampled = {}
    for n in (10, 32):
        run = tmp_path / f"run{n}"
        run.mkdir()
        slabs.export(run / "target.ply")
        np.savez(run / "grid.npz", values=np.zeros((n, n, n), np.float32),
                 bbox_min=np.full(3, -1.0, np.float32), bbox_max=np.full(3, 1.0, np.float32))
        sampled[n] = module.grid_truth(run)
        assert (run / "grid_truth.json").is_file() and sampled[n]["resolution"] == n
    diagonal = float(np.linalg.norm(slabs.extents))
    assert sampled[32]["hausdorff_rel"] < 0.06 / diagonal and sampled[32]["genus"] == -1  # two parts
    assert sampled[10]["hausdorff_rel"] > 0.15 / diagonal and sampled[10]["genus"] == 0  # bridged


def test_toy_run_writes_table_pictures_and_reuses_runs(tmp_path, monkeypatch):
    import mvr

    monkeypatch.setattr(mvr, "configure_runtime", lambda **kwargs: None)  # process-wide
    folder = tmp_path / "meshes"
    folder.mkdir()
    trimesh.creation.icosphere(subdivisions=2, radius=0.5).export(folder / "ball.ply")
    out, docs = tmp_path / "out", tmp_path / "docs"
    argv = [str(folder), "--shapes", "--configs", "default", "paper", "--out", str(out), "--docs", str(docs),
            "--extra", *QUICK, "seed=3"]
    torch.manual_seed(0)
    module.main(argv)
    for name in ("table.md", "table.csv", "results.json"):
        assert (out / name).is_file(), name
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert {(r["mesh"], r["config"]) for r in rows} == {("ball", "default"), ("ball", "paper")}
    assert all(r["hausdorff_rel"] > 0 and r["seconds"] > 0 for r in rows)
    assert all(0 < r["truth_hausdorff_rel"] < 0.05 for r in rows)  # a reference: a fit may beat it
    assert (out / "paper" / "ball" / "errors.png").stat().st_size > 1000
    text = (docs / "mvr_real_scans.md").read_text()
    assert "| ball |" in text and "mvr_errors_ball.png" in text and (docs / "mvr_errors_ball.png").is_file()
    assert "once per configuration (seed 3)" in text  # --extra's seed (was always printed as 0)

    def no_rerun(*args, **kwargs):
        raise AssertionError("a finished run must be reused")

    monkeypatch.setattr(module, "reconstruct_with_overrides", no_rerun)
    module.main(argv)
    again = json.loads((out / "results.json").read_text())["rows"]
    assert [r["hausdorff_rel"] for r in again] == [r["hausdorff_rel"] for r in rows]


def test_bad_arguments_are_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit, match="mesh folder .* is not a folder"):
        module.main([str(tmp_path / "nowhere"), "--out", str(tmp_path / "o"), "--docs", ""])
    with pytest.raises(SystemExit, match="--shapes: unknown shape"):
        module.main([str(tmp_path), "--shapes", "teapot", "--out", str(tmp_path / "o"), "--docs", ""])
