"""The labelled picture grid: labels above the columns and left of the rows, legible tile sizes."""
from __future__ import annotations

import numpy as np
import pytest

from sdfcommon.tooling.pictures import labelled_grid

RED = (1.0, 0.0, 0.0)


def _red_tiles(rows: int, cols: int, h: int, w: int) -> np.ndarray:
    return np.broadcast_to(np.asarray(RED, dtype=np.float32), (rows, cols, h, w, 3))


def _tile_box(picture: np.ndarray) -> tuple[int, int, int, int]:
    """(top, left, bottom, right) of the red pixels: where the tiles are."""
    red = (picture[..., 0] > 0.9) & (picture[..., 1] < 0.1) & (picture[..., 2] < 0.1)
    ys, xs = np.nonzero(red)
    return ys.min(), xs.min(), ys.max() + 1, xs.max() + 1


def _has_text(band: np.ndarray) -> bool:
    return bool((band.max(axis=-1) < 0.5).any())  # dark pixels on the white sheet


def test_rows_and_columns_are_labelled():
    picture = labelled_grid(_red_tiles(3, 4, 20, 24), ["target", "render", "|difference|"],
                            ["view 0", "view 2", "view 4", "view 6"])
    top, left, bottom, right = _tile_box(picture)
    assert top > 0 and left > 0  # a label strip above and one at the left
    assert _has_text(picture[:top, left:])  # the column labels
    assert _has_text(picture[top:, :left])  # the row labels
    assert not _has_text(picture[top:bottom, left:right])  # labels stay off the tiles
    assert bottom == picture.shape[0] - 2 and right == picture.shape[1] - 2  # only the gap after the last tile


def test_small_tiles_are_scaled_up_by_a_whole_factor_and_the_picture_grows_with_the_columns():
    labels = ["a", "b", "c", "d", "e"]
    two = labelled_grid(_red_tiles(1, 2, 20, 24), ["row"], labels[:2], min_tile=100)
    five = labelled_grid(_red_tiles(1, 5, 20, 24), ["row"], labels, min_tile=100)
    top, left, bottom, right = _tile_box(two)
    assert (bottom - top, right - left) == (5 * 20, 2 * 5 * 24 + 2)  # scale 5: 24 * 5 >= 100, 2-pixel gap
    assert five.shape[0] == two.shape[0] and five.shape[1] == two.shape[1] + 3 * (5 * 24 + 2)
    big = labelled_grid(_red_tiles(1, 1, 200, 150), ["row"], ["col"], min_tile=100)
    top, left, bottom, right = _tile_box(big)
    assert (bottom - top, right - left) == (200, 150)  # large tiles keep their size


def test_long_labels_wrap_and_widen_narrow_columns_only_to_their_longest_word():
    tiles = _red_tiles(1, 2, 8, 8)
    short = labelled_grid(tiles, ["row"], ["a", "b"], min_tile=32)
    long = labelled_grid(tiles, ["row"], ["view 0 target colour", "view 0 render colour"], min_tile=32)
    top_short, left, _, right_short = _tile_box(short)
    top_long, _, _, right_long = _tile_box(long)
    assert top_long > top_short + 20  # wrapped onto several lines
    assert 2 * 32 < right_long - left < 2 * 100  # wider than the tiles for "colour", far narrower than a line
    assert right_short - left == 2 * 32 + 2


def test_grey_tiles_and_bad_input():
    grey = np.linspace(0, 1, 2 * 3 * 8 * 8, dtype=np.float32).reshape(2, 3, 8, 8)
    picture = labelled_grid(grey, ["sample 0", "sample 1"], ["input", "target", "render"], min_tile=32)
    assert picture.dtype == np.float32 and picture.ndim == 3 and picture.shape[-1] == 3
    assert picture.min() == 0.0 and picture.max() == 1.0
    with pytest.raises(ValueError, match="row labels"):
        labelled_grid(grey, ["sample 0"], ["a", "b", "c"])
    with pytest.raises(ValueError, match="tiles must have shape"):
        labelled_grid(grey[0], ["a", "b", "c"], ["x"] * 8)
    with pytest.raises(ValueError, match="min_tile"):
        labelled_grid(grey, ["a", "b"], ["x", "y", "z"], min_tile=0)


def test_imports_neither_application():
    import subprocess
    import sys

    code = "import sys, sdfcommon.tooling.pictures; print(sorted({'svr', 'mvr'} & {m.split('.')[0] for m in sys.modules}))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
