"""views.png: the rows (target, render, |difference|) and the columns (the views) are labelled and the
tiles legible."""
from __future__ import annotations

import numpy as np
from PIL import Image

from mvr import OptimSettings, Schedule, ScoringSettings, TargetSettings, configure_runtime, reconstruct


def test_views_png_is_labelled_and_legible(tmp_path):
    configure_runtime(threads=1)
    views = (0, 6, 12)
    reconstruct("sphere", tmp_path, target_settings=TargetSettings(extent=1.0, mesh_resolution=32),
                schedule=Schedule(resolutions=[8]), optim=OptimSettings(max_passes=1),
                evaluation=ScoringSettings(samples=200, views=views), progress=False)
    picture = np.asarray(Image.open(tmp_path / "views.png"))
    assert picture.shape[0] > 3 * 96 + 10 and picture.shape[1] > len(views) * 96 + 40  # legible tiles and labels
    dark = picture.max(axis=-1) < 128
    assert dark[:12].any() and dark[:, :40].any()  # column labels above, row labels at the left
    assert picture[:4].min() == 255 and picture[:, :4].min() == 255  # white margin around the labels


def test_a_rerun_removes_what_a_killed_write_left(tmp_path):
    """Issue 17 item 5: a run killed mid-write (kill -9) leaves a hidden temporary beside the file it
    was writing; the next run into the folder removes it (and nothing else)."""
    configure_runtime(threads=1)
    left = tmp_path / "checkpoints" / ".level_0.pt.k3j_a9zq.tmp"
    left.parent.mkdir(parents=True)
    left.write_bytes(b"half a level")
    mine = tmp_path / "notes.txt"
    mine.write_text("mine")
    reconstruct("sphere", tmp_path, target_settings=TargetSettings(extent=1.0, mesh_resolution=32),
                schedule=Schedule(resolutions=[8]), optim=OptimSettings(max_passes=1),
                evaluation=ScoringSettings(samples=200, views=(0,)), progress=False)
    assert not left.exists() and mine.read_text() == "mine"
