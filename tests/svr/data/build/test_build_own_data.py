"""svr.data.build on one's own meshes (issue 40): 3 categories of 5 meshes give every split objects
(a mesh that cannot be built takes no split's place), split_ratios that leave a split empty are
refused, so are an ``out`` inside ``input`` or holding other files and a layout that matches
nothing, a degenerate mesh is a skipped row, and a stopped build says so in one line, writes its
log and continues when rerun."""
from __future__ import annotations

import csv
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from data.example_meshes import SOLIDS, shape_mesh, write_example_meshes
from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.outputs import write_mesh
from sdfcommon.tooling.settings import build_settings
from svr.data.build import dataset
from svr.data.build.__main__ import main
from svr.data.build.dataset import build_object
from svr.data.build.layouts import MeshObject, split_counts
from svr.data.datasets import NMRDataset
from svr.nmr.format import SPLITS, read_metadata

from ....entry_points import expect_usage_error, files_under, run_entry

ROOT = Path(__file__).resolve().parents[4]
FAST = ["workers=0", "progress=false", "supersample=2", "ray_directions=7"]
PROG = "sdfdiff-build"


def _write_solids(folder: Path, names=("sphere", "torus", "box"), resolution: int = 16) -> None:
    for name, ext in zip(names, ("glb", "stl", "off")):
        v, f = shape_mesh(SOLIDS[name](), resolution)
        write_mesh(folder / f"{name}.{ext}", trimesh.Trimesh(v, f, process=False))


def _manifest(folder: Path) -> list[dict]:
    with open(folder / "manifest.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def solids(tmp_path_factory) -> Path:
    """One category of three small solids (the cheapest input that fills every split)."""
    folder = tmp_path_factory.mktemp("solids_input")
    _write_solids(folder / "solids")
    return folder


def test_three_categories_of_five_meshes_fill_every_split(tmp_path, monkeypatch, capsys):
    """Issue 40 item 2: before, 5 meshes with the default ratios gave val = 0 in every category,
    and a mesh that could not be read took a split's place."""
    meshes = tmp_path / "meshes"
    write_example_meshes(meshes, resolution=24, per_category=5)
    _write_solids(meshes / "solids")  # 3 that build and 2 that do not: still one object per split
    (meshes / "solids" / "empty.obj").write_text("")
    (meshes / "solids" / "corrupt.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 9\n")
    _write_solids(meshes / "single", names=("sphere",))  # too few for every split: a warning
    out = tmp_path / "nmr"
    run_entry(main, [f"input={meshes}", f"out={out}", *FAST], monkeypatch)
    captured = capsys.readouterr()
    sizes = read_metadata(out)["sizes"]
    for cid in ("03001627", "04256520", "04379243"):  # chair, sofa, table
        assert sizes[cid] == {"train": 3, "val": 1, "test": 1}, (cid, sizes)
    assert sizes["solids"] == {"train": 1, "val": 1, "test": 1} and sizes["single"] == {"train": 1, "val": 0, "test": 0}
    for split in SPLITS:
        assert len(NMRDataset(out, split, categories=["chair", "sofa", "table", "solids"])) == (10 if split == "train" else 4)
    rows = {r["object_id"]: r for r in _manifest(out)}
    assert rows["empty"]["status"] == rows["corrupt"]["status"] == "skipped"
    assert rows["empty"]["split"] == rows["corrupt"]["split"] == ""  # no split's place
    # The summary: objects per category and split, and the category that cannot fill them.
    assert "built 19 objects, skipped 2" in captured.out
    assert re.search(r"03001627 \(chair\)\s+3\s+1\s+1\b", captured.out), captured.out
    assert re.search(r"single \(single\)\s+1\s+0\s+0\b", captured.out), captured.out
    warnings = [line for line in captured.err.splitlines() if line.startswith("warning: ")]
    assert len(warnings) == 1 and "single" in warnings[0] and "no val/test objects" in warnings[0], captured.err
    log = (out / "build.log").read_text()  # issue 40 item 16: the log holds what was printed
    assert "built 19 objects, skipped 2" in log and "no val/test objects" in log
    # A rerun finds the build done and prints the same table.
    run_entry(main, [f"input={meshes}", f"out={out}", *FAST], monkeypatch)
    again = capsys.readouterr()
    assert "nothing to do" in again.out and re.search(r"03001627 \(chair\)\s+3\s+1\s+1\b", again.out)


def test_split_counts_give_each_split_one_from_three_objects():
    assert [split_counts(n) for n in (1, 2, 3, 4, 5, 10)] == [(1, 0, 0), (1, 0, 1), (1, 1, 1), (2, 1, 1), (3, 1, 1),
                                                              (7, 1, 2)]
    for n in range(3, 60):
        for ratios in ((0.7, 0.1, 0.2), (0.05, 0.5, 0.45), (0.9, 0.05, 0.05), (1 / 3, 1 / 3, 1 / 3)):
            counts = split_counts(n, ratios)
            assert sum(counts) == n and min(counts) >= 1, (n, ratios, counts)


@pytest.mark.parametrize("ratios", ["[1,0,0]", "[0.5,0.5,0.5]", "[0.8,0.2]", "[0.9,0.2,-0.1]"])
def test_split_ratios_must_be_positive_and_sum_to_one(ratios, solids, tmp_path, monkeypatch, capsys):
    out = tmp_path / "nmr"
    line = expect_usage_error(main, [f"input={solids}", f"out={out}", f"split_ratios={ratios}"], monkeypatch, capsys,
                              PROG)
    assert "split_ratios must be three numbers > 0 (train, val, test) that sum to 1" in line
    assert not out.exists()


def test_out_inside_input_or_holding_other_files_is_refused(solids, tmp_path, monkeypatch, capsys):
    """Issue 40 item 8: before, ``out`` inside ``input`` was built (a later build read it as a
    category) and a build mixed its files into any folder."""
    before = files_under(solids)
    for out in (solids, solids / "nmr", solids / "solids" / "deeper"):
        line = expect_usage_error(main, [f"input={solids}", f"out={out}"], monkeypatch, capsys, PROG)
        assert line.startswith(f"{PROG}: error: out must be a folder outside input"), line
        assert files_under(solids) == before and not (solids / "nmr").exists()
    other = tmp_path / "project"
    (other / "notes").mkdir(parents=True)
    (other / "train.log").write_text("not the builder's\n")
    (other / "README.md").write_text("mine\n")
    (other / ".hydra").mkdir()
    (other / ".hydra" / "config.yaml").write_text("a: 1\n")
    before = files_under(other)
    for extra in ([], ["overwrite=true"]):
        line = expect_usage_error(main, [f"input={solids}", f"out={other}", *extra, *FAST], monkeypatch, capsys, PROG)
        assert line.startswith(f"{PROG}: error: out: {other} is not empty and is no build of this command"), line
        assert "README.md" in line and "notes" in line
        assert files_under(other) == before and sorted(p.name for p in other.iterdir()) == [
            ".hydra", "README.md", "notes", "train.log"]
    # Another tool's metadata.json (the procedural data's, say) is not this builder's either.
    procedural = tmp_path / "procedural"
    procedural.mkdir()
    (procedural / "metadata.json").write_text('{"format": "nmr-shapenet", "generator_version": 4}')
    line = expect_usage_error(main, [f"input={solids}", f"out={procedural}", "overwrite=true"], monkeypatch, capsys,
                              PROG)
    assert "is no build of this command (it holds metadata.json)" in line


def test_a_layout_that_matches_no_object_is_refused(solids, tmp_path, monkeypatch, capsys):
    """Issue 40 item 12: before, layout=shapenet_v1 on a flat folder 'built 0 objects', exit 0."""
    for layout, expects in (("shapenet_v1", "<synset>/<id>/model.obj"),
                            ("shapenet_v2", "<synset>/<id>/models/model_normalized.obj")):
        out = tmp_path / layout
        line = expect_usage_error(main, [f"input={solids}", f"out={out}", f"layout={layout}"], monkeypatch, capsys,
                                  PROG)
        assert f"no objects found for layout={layout} in {solids} (it expects {expects})" in line, line
        assert not out.exists()


def _triangle_soup(path: Path, vertices, faces) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"v {x} {y} {z}" for x, y, z in vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_degenerate_meshes_are_skipped_rows(tmp_path):
    """Issue 40 item 22: before, a one-triangle mesh was an "ok" object."""
    settings = build_settings(compose("build", ["input=unused", "out=unused", "supersample=1", "ray_directions=3"]))
    grid = np.stack(np.meshgrid(np.arange(4.0), np.arange(4.0), indexing="ij"), -1).reshape(-1, 2)
    tilted = np.c_[grid, 0.3 * grid[:, 0] - 0.2 * grid[:, 1]]  # 16 vertices in one tilted plane
    quads = [(i * 4 + j, i * 4 + j + 1, i * 4 + j + 4) for i in range(3) for j in range(3)]
    quads += [(i * 4 + j + 1, i * 4 + j + 5, i * 4 + j + 4) for i in range(3) for j in range(3)]
    cases = {
        "triangle": ([(0, 0, 0), (1, 0, 0), (0, 1, 0.5)], [(0, 1, 2)], "degenerate mesh: 1 triangle(s) with non-zero area"),
        "sliver": ([(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 1)], [(0, 1, 2), (0, 1, 3), (1, 2, 3), (0, 2, 3)],
                   "degenerate mesh: 3 triangle(s) with non-zero area"),
        "sheet": (tilted, quads, "degenerate mesh: flat (all its vertices lie in one plane)"),
    }
    for name, (vertices, faces, reason) in cases.items():
        path = _triangle_soup(tmp_path / "odd" / f"{name}.obj", vertices, faces)
        row = build_object(MeshObject("odd", name, path), settings, f"odd/{name}.obj").row
        assert row["status"] == "skipped" and row["reason"].startswith(reason), (name, row)
    tetrahedron = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]
    path = _triangle_soup(tmp_path / "odd" / "tetra.obj", tetrahedron, [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)])
    result = build_object(MeshObject("odd", "tetra", path), settings, "odd/tetra.obj")
    assert result.row["status"] == "ok" and result.voxels.any()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stopped_build_says_so_in_one_line_and_continues(signum, solids, tmp_path, monkeypatch, capsys,
                                                          ctrl_c_raises):
    """Issue 40 item 16: before, Ctrl+C printed a KeyboardInterrupt traceback, SIGTERM no word of how
    to continue, and build.log stayed empty. Here the signal arrives while the second mesh builds."""
    out = tmp_path / "nmr"
    calls = []

    def build_then_stop(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            os.kill(os.getpid(), signum)  # SIGINT: Python's KeyboardInterrupt
            time.sleep(5)  # the handler raises during this
        return real_build(*args, **kwargs)

    real_build = dataset.build_object
    handler = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(dataset, "build_object", build_then_stop)
    capsys.readouterr()
    with pytest.raises(SystemExit) as stopped:
        run_entry(main, [f"input={solids}", f"out={out}", *FAST], monkeypatch)
    assert stopped.value.code == 128 + signum
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    name = "Ctrl+C (SIGINT)" if signum == signal.SIGINT else "SIGTERM"
    assert lines == [f"build stopped by {name} after 1 of 3 objects (kept in {out}/.build); rerunning the same "
                     f"command continues it"], err
    assert lines[0] in (out / "build.log").read_text()
    assert len(list((out / ".build" / "objects").rglob("*.npz"))) == 1
    monkeypatch.setattr(dataset, "build_object", real_build)
    run_entry(main, [f"input={solids}", f"out={out}", *FAST], monkeypatch)
    assert "built 3 objects, skipped 0" in capsys.readouterr().out and not (out / ".build").exists()
    assert signal.getsignal(signal.SIGTERM) == handler  # the builder's own handler is gone


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "killpg"), reason="sends Ctrl+C to a process group")
def test_ctrl_c_and_sigterm_stop_a_parallel_build_in_one_line(tmp_path):
    """Issue 40 item 16 as a user meets it: Ctrl+C in a terminal (SIGINT to the process group: the
    builder and its worker processes) and SIGTERM to the builder alone, with two workers; each stop
    is one line with its exit status, no traceback and no "leaked semaphore" warning."""
    meshes = tmp_path / "meshes"
    write_example_meshes(meshes, resolution=24, per_category=4)
    out = tmp_path / "nmr"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}
    command = [sys.executable, "-m", "svr.data.build", f"input={meshes}", f"out={out}", "workers=2",
               "progress=false", "supersample=2", "ray_directions=7"]
    def done() -> int:
        folder = out / ".build" / "objects"
        return len(list(folder.rglob("*.json"))) if folder.is_dir() else 0

    for signum, to_group in ((signal.SIGINT, True), (signal.SIGTERM, False)):
        before = done()
        proc = subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, start_new_session=True)
        try:
            end = time.time() + 120
            while time.time() < end and done() < before + 1:
                time.sleep(0.05)
            (os.killpg if to_group else os.kill)(proc.pid, signum)
            stdout, stderr = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        assert proc.returncode == 128 + signum, stderr
        assert "Traceback" not in stderr and "leaked" not in stderr, stderr
        stops = [line for line in stderr.splitlines() if "build stopped by" in line]
        assert len(stops) == 1 and "rerunning the same command continues it" in stops[0], stderr
        assert stops[0] in (out / "build.log").read_text()
    finished = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert finished.returncode == 0 and "built 12 objects, skipped 0" in finished.stdout, finished.stderr
