"""svr.data.build, the command that turns a mesh folder into NMR-format data: the loader reads what
it writes, layouts and splits, a kill mid-run then a rerun gives the bytes of an uninterrupted run,
and bad input is a one-line error or a skipped manifest row."""
from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.outputs import write_mesh
from sdfcommon.tooling.settings import build_settings
from svr.data.build import dataset
from svr.data.build.__main__ import main
from svr.data.build.dataset import build_mesh
from data.example_meshes import SOLIDS, shape_mesh, write_example_meshes
from svr.data.build.layouts import assign_splits, find_objects
from svr.data.build.meshes import load_mesh
from svr.data.datasets import NMRDataset
from svr.nmr.format import read_metadata

from ....entry_points import expect_usage_error, run_entry

ROOT = Path(__file__).resolve().parents[4]
DATA_SUFFIXES = (".npz", ".npy", ".csv", ".json")
FAST = ["workers=0", "progress=false", "supersample=2", "ray_directions=7"]


@pytest.fixture(scope="module")
def meshes(tmp_path_factory) -> Path:
    """The example input at 3 meshes per category (3 categories, 9 meshes in 5 formats) plus an
    empty and a corrupt table."""
    folder = tmp_path_factory.mktemp("meshes")
    write_example_meshes(folder, resolution=28, per_category=3)
    (folder / "table" / "empty.obj").write_text("")
    (folder / "table" / "corrupt.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    return folder


def _data_files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file() and p.suffix in DATA_SUFFIXES}


def _manifest(folder: Path) -> list[dict]:
    with open(folder / "manifest.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_the_loader_reads_what_the_command_writes(meshes, tmp_path, monkeypatch, capsys):
    out = tmp_path / "nmr"
    run_entry(main, [f"input={meshes}", f"out={out}", *FAST], monkeypatch)
    printed = capsys.readouterr().out
    assert "built 9 objects, skipped 2" in printed and "manifest.csv" in printed
    meta = read_metadata(out)
    assert meta["categories"] == [["03001627", "chair"], ["04256520", "sofa"], ["04379243", "table"]]  # by folder name
    assert all(meta["sizes"][cid] == {"train": 1, "val": 1, "test": 1} for cid, _ in meta["categories"])
    data = NMRDataset(out, "train")
    assert len(data) == 3
    item = data[0]
    assert item["images"].shape == (24, 4, 64, 64) and item["voxels"].shape == (32, 32, 32)
    assert item["category_name"] == "chair" and item["voxels"].any()
    raw = data.images_uint8(0)
    corner = raw[:, :, :4, :4]
    assert (corner[:, 3] == 0).all() and (corner[:, :3] == 255).all()  # transparent on white: no inversion
    assert (raw[:, 3] == 255).any() and 0 < raw[:, 3].mean() < 255
    rgb = raw[:, :3].transpose(1, 0, 2, 3)[:, raw[:, 3] == 255]  # (3, opaque pixels)
    assert rgb[0].mean() > rgb[2].mean() + 10  # the chair's brown (MTL Kd 0.6 0.3 0.1) is red-heavy
    rows = {r["object_id"]: r for r in _manifest(out)}
    assert rows["chair_0"]["status"] == "ok" and rows["chair_0"]["watertight"] == "True"
    assert rows["chair_0"]["source"] == "chair/chair_0.obj" and rows["chair_0"]["index"] == "0"
    assert rows["empty"]["status"] == "skipped" and rows["empty"]["reason"] == "no triangles in the file"
    assert rows["corrupt"]["status"] == "skipped" and "\n" not in rows["corrupt"]["reason"]
    assert float(rows["table_0"]["leak_score"]) < 0.05 and int(rows["table_0"]["triangles"]) > 100
    assert rows["table_0"]["source"] == "table/table_0.stl" and rows["table_2"]["source"] == "table/table_2.glb"
    # A second run finds the build done and changes nothing; another build is refused there ...
    before = _data_files(out)
    run_entry(main, [f"input={meshes}", f"out={out}", *FAST], monkeypatch)
    assert "nothing to do" in capsys.readouterr().out and _data_files(out) == before
    line = expect_usage_error(main, [f"input={meshes}", f"out={out}", "seed=1", *FAST], monkeypatch, capsys)
    assert "holds another build" in line and _data_files(out) == before
    # ... unless it may replace it.
    run_entry(main, [f"input={meshes}", f"out={out}", "seed=1", "overwrite=true", *FAST], monkeypatch)
    assert json.loads((out / "metadata.json").read_text())["settings"]["seed"] == 1


def test_textures_colours_and_sdf_grids(tmp_path):
    from PIL import Image

    folder = tmp_path / "cube"
    folder.mkdir()
    Image.new("RGB", (4, 4), (230, 20, 20)).save(folder / "red.png")
    (folder / "cube.mtl").write_text("newmtl tex\nKd 1 1 1\nmap_Kd red.png\n")
    box = trimesh.creation.box((1.0, 0.8, 0.6))
    lines = ["mtllib cube.mtl", "usemtl tex"] + [f"v {x} {y} {z}" for x, y, z in box.vertices]
    lines += ["vt 0 0", "vt 1 0", "vt 1 1"] + [f"f {a + 1}/1 {b + 1}/2 {c + 1}/3" for a, b, c in box.faces]
    (folder / "cube.obj").write_text("\n".join(lines) + "\n")
    mesh = load_mesh(folder / "cube.obj")
    assert len(mesh.textures) == 1 and (mesh.face_texture == 0).all()
    assert np.allclose(mesh.vertices.max(0) - mesh.vertices.min(0), [1.0, 0.8, 0.6])  # longest side 1
    settings = build_settings(compose("build", ["input=unused", "out=unused", "sdf_resolution=24", "supersample=2"]))
    stats, images, vox, sdf = build_mesh(mesh, settings)
    opaque = images[:, 3] == 255
    rgb = images[:, :3].transpose(1, 0, 2, 3)[:, opaque].astype(float)
    assert rgb[0].mean() > 3 * rgb[1].mean() and rgb[0].mean() > 3 * rgb[2].mean()  # the texture's red
    assert stats.watertight and vox.voxels.sum() > 0.4 * 32 ** 3
    assert sdf.shape == (24, 24, 24) and sdf[12, 12, 12] < 0 < sdf[0, 0, 0]


def test_layouts_categories_and_split_lists(tmp_path):
    root = tmp_path / "shapenet"
    v, f = shape_mesh(SOLIDS["sphere"](), 12)
    files = [root / "02691156" / f"id{k}" / "model.obj" for k in range(5)]
    files += [root / "04530566" / f"v{k}" / "models" / "model_normalized.obj" for k in range(3)]
    for path in files:
        write_mesh(path, trimesh.Trimesh(v, f, process=False))
    pairs, objects = find_objects(root, categories=["vessel", "02691156"])
    assert pairs == [("04530566", "vessel"), ("02691156", "airplane")]
    assert [o.object_id for o in objects] == ["v0", "v1", "v2", "id0", "id1", "id2", "id3", "id4"]
    assert objects[0].path.name == "model_normalized.obj" and objects[3].path.name == "model.obj"
    lists = tmp_path / "lists"
    lists.mkdir()
    (lists / "02691156_trainids.txt").write_text("02691156/id0\nid1\n")
    (lists / "02691156_testids.txt").write_text("id3\n")
    kept, left_out = assign_splits(objects, seed=0, id_lists=lists)
    where = {o.object_id: o.split for o in kept}
    assert where["id0"] == where["id1"] == "train" and where["id3"] == "test"
    assert sorted(o.object_id for o in left_out) == ["id2", "id4"]
    assert {where[f"v{k}"] for k in range(3)} <= {"train", "val", "test"}  # no lists: seeded ratios
    again, _ = assign_splits(objects, seed=0, id_lists=lists)
    assert again == kept
    with pytest.raises(ValueError, match="unknown category 'mug'"):
        find_objects(root, categories=["mug"])


def _wait_for(folder: Path, pattern: str, count: int, timeout: float) -> None:
    end = time.time() + timeout
    while time.time() < end:
        if len(list(folder.rglob(pattern))) >= count:
            return
        time.sleep(0.05)
    raise AssertionError(f"no {count} files {pattern} under {folder} after {timeout} s")


def test_a_killed_build_continues_to_the_bytes_of_an_uninterrupted_one(meshes, tmp_path, monkeypatch, capsys):
    args = [f"input={meshes}", "seed=3", *FAST]
    whole = tmp_path / "whole"
    run_entry(main, [*args, f"out={whole}"], monkeypatch)
    cut = tmp_path / "cut"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    proc = subprocess.Popen([sys.executable, "-m", "svr.data.build", *args, f"out={cut}"], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for(cut / ".build" / "objects", "*.json", 2, timeout=120)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    done = len(list((cut / ".build" / "objects").rglob("*.json")))
    assert 2 <= done < 11 and not (cut / "metadata.json").exists()
    run_entry(main, [*args, f"out={cut}"], monkeypatch)
    assert _data_files(cut) == _data_files(whole)
    assert not (cut / ".build").exists()
    splits = {r["split"] for r in _manifest(cut) if r["status"] == "ok"}
    assert splits <= {"train", "val", "test"} and json.loads((cut / "metadata.json").read_text())["objects"] == {
        "built": 9, "skipped": 2, "left_out": 0}


def test_bad_input_is_one_line(meshes, tmp_path, monkeypatch, capsys):
    prog = "sdfdiff-build"
    line = expect_usage_error(main, [f"input={tmp_path / 'nowhere'}", f"out={tmp_path / 'o1'}"], monkeypatch, capsys, prog)
    assert "input folder does not exist" in line and str(tmp_path / "nowhere") in line
    assert not (tmp_path / "o1").exists()
    line = expect_usage_error(main, [f"input={meshes}", f"out={tmp_path / 'o2'}", "categories=[mug]"], monkeypatch,
                              capsys, prog)
    assert "unknown category 'mug'" in line and not (tmp_path / "o2").exists()
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    line = expect_usage_error(main, [f"input={meshes}", f"out={blocker / 'sub'}"], monkeypatch, capsys, prog)
    assert "cannot write" in line
    line = expect_usage_error(main, [f"input={meshes}", f"out={tmp_path / 'o3'}", "views=0"], monkeypatch, capsys, prog)
    assert "views must be an integer >= 1" in line
    line = expect_usage_error(main, [f"input={meshes}", f"out={tmp_path / 'o4'}", "+colour=red"], monkeypatch, capsys, prog)
    assert "colour: unknown setting" in line
    empty = tmp_path / "empty_input"
    (empty / "chair").mkdir(parents=True)
    line = expect_usage_error(main, [f"input={empty}", f"out={tmp_path / 'o5'}"], monkeypatch, capsys, prog)
    assert "no category folder with meshes" in line


def _spawned_children() -> list[int]:
    """Process ids of this process's spawned worker processes (multiprocessing's spawn_main)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            cmdline = (stat.parent / "cmdline").read_bytes()
        except (OSError, ValueError, IndexError):
            continue
        if ppid == os.getpid() and b"spawn_main" in cmdline:
            found.append(int(stat.parent.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds the worker through /proc")
def test_a_worker_killed_mid_build_costs_no_object(meshes, tmp_path, monkeypatch, capsys):
    """A worker process that dies (SIGKILL here; a crash in a mesh library or the OOM killer in
    life) breaks the pool: the objects it may have held are rebuilt one by one, the build goes on.
    The packing runs in a worker process as well (as it does for large builds)."""
    out = tmp_path / "nmr"
    killed = []

    def kill_a_worker() -> None:
        end = time.time() + 120
        while time.time() < end and not killed:
            if len(list((out / ".build" / "objects").rglob("*.json"))) >= 1:
                for pid in _spawned_children():
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                    break
            time.sleep(0.02)

    import threading

    thread = threading.Thread(target=kill_a_worker, daemon=True)
    thread.start()
    monkeypatch.setattr(dataset, "PARALLEL_PACK_OBJECTS", 0)  # the packing in a worker process too
    run_entry(main, [f"input={meshes}", f"out={out}", "workers=1", "progress=false", "supersample=2",
                     "ray_directions=7"], monkeypatch)
    thread.join(5)
    assert killed, "no worker was found to kill"
    rows = _manifest(out)
    assert sum(r["status"] == "ok" for r in rows) == 9 and sum(r["status"] == "skipped" for r in rows) == 2
    assert not any("worker process died" in r["reason"] for r in rows)
    # The same bytes as a build in this process alone, without a death.
    alone = tmp_path / "alone"
    run_entry(main, [f"input={meshes}", f"out={alone}", "workers=0", "progress=false", "supersample=2",
                     "ray_directions=7"], monkeypatch)
    assert _data_files(alone) == _data_files(out)
