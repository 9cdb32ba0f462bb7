"""sdfcommon.tooling.outputs: every writer leaves either the old file or the whole new one, with the mode a
plainly created file gets; a killed writer's temporaries are recognised and removed."""
from __future__ import annotations

import json
import stat

import numpy as np
import pytest
import torch

from sdfcommon.tooling.outputs import (atomic_path, atomic_write, remove_stale_temporaries, write_csv, write_json,
                               write_mesh, write_npz, write_png, write_text, write_torch)


def test_writers_round_trip(tmp_path):
    import trimesh
    from PIL import Image

    write_text(tmp_path / "a" / "t.txt", "héllo")
    assert (tmp_path / "a" / "t.txt").read_text(encoding="utf-8") == "héllo"
    write_json(tmp_path / "j.json", {"x": 1.5, "bad": float("nan"), "rows": [float("inf"), 2]})
    assert json.loads((tmp_path / "j.json").read_text()) == {"x": 1.5, "bad": None, "rows": [None, 2]}
    write_csv(tmp_path / "c.csv", [{"a": 1, "b": 2, "extra": 3}], ["a", "b"])
    assert (tmp_path / "c.csv").read_text().splitlines() == ["a,b", "1,2"]
    write_torch(tmp_path / "w.pt", {"w": torch.arange(3)})
    assert torch.equal(torch.load(tmp_path / "w.pt")["w"], torch.arange(3))
    write_npz(tmp_path / "g.npz", values=np.eye(2))
    assert np.array_equal(np.load(tmp_path / "g.npz")["values"], np.eye(2))
    write_mesh(tmp_path / "m.ply", trimesh.creation.box())
    assert len(trimesh.load(tmp_path / "m.ply").faces) == 12
    write_png(tmp_path / "p.png", np.full((2, 3), 2.0))  # clipped to white
    assert np.asarray(Image.open(tmp_path / "p.png")).tolist() == [[255] * 3] * 2
    assert not list(tmp_path.rglob("*.tmp"))


def test_files_follow_the_umask(tmp_path, umask_022):
    path = atomic_write(tmp_path / "sub" / "f.bin", lambda f: f.write(b"x"))
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o755
    with atomic_path(tmp_path / "g.npy") as tmp:
        np.lib.format.open_memmap(tmp, mode="w+", dtype=np.float32, shape=(2,)).flush()
    assert stat.S_IMODE((tmp_path / "g.npy").stat().st_mode) == 0o644


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = write_text(tmp_path / "f.txt", "old")

    def fail(f):
        f.write(b"half")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError, match="killed"):
        atomic_write(path, fail)
    with pytest.raises(RuntimeError, match="killed"):
        with atomic_path(path) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("killed")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["f.txt"]


def test_stale_temporaries_of_both_namings_are_removed(tmp_path):
    with atomic_path(tmp_path / "deep" / "x.json") as tmp:  # what a killed writer leaves
        left = tmp.with_name(tmp.name + ".copy")
        left.write_bytes(tmp.read_bytes())
    left = left.rename(tmp.parent / tmp.name)
    old = tmp_path / ".last.ckpt.0123456789abcdef.tmp"  # svr's former checkpoint writer
    old.write_bytes(b"x")
    keep = [tmp_path / "notes.tmp", tmp_path / ".x.tmp", tmp_path / ".x.ab.tmp"]  # not a writer's names
    for p in keep:
        p.write_text("mine")
    removed = remove_stale_temporaries(tmp_path)
    assert sorted(removed) == sorted([left, old])
    assert all(p.exists() for p in keep) and (tmp_path / "deep" / "x.json").exists()
    assert remove_stale_temporaries(tmp_path / "missing") == []
