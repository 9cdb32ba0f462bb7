"""Pictures people read: a grid of image tiles with its rows and columns labelled. Small renders
(32-64 px, or a crop of a few dozen pixels) are scaled up by a whole factor with nearest-neighbour
sampling, so each pixel stays a sharp square and the labels have room.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from sdfcommon.tooling.checks import check_int, check_shape

TEXT_SIZE = 14
PADDING = 6


def labelled_grid(tiles, row_labels: Sequence[str], column_labels: Sequence[str], *, min_tile: int = 128,
                  gap: int = 2) -> np.ndarray:
    """Lays out R x C tiles on a white sheet, each row's label at its left and each column's above it.

    Args:
        tiles: (R, C, h, w) grey or (R, C, h, w, 3) RGB array (or CPU tensor), values in [0, 1]
            (clipped).
        row_labels: R strings. column_labels: C strings, wrapped at spaces to the column's width
            (the tile's, or the longest word's where that is wider).
        min_tile: every tile is scaled by the smallest whole factor that makes its longer side at
            least this many pixels (nearest neighbour); a larger tile keeps its size.
        gap: white pixels between neighbouring tiles.
    Returns:
        (H, W, 3) float32 array in [0, 1], H = top label strip + R * (s h + gap) and
        W = left label strip + C * (max(s w, longest label word) + gap) for the scale s.
    """
    from PIL import Image, ImageDraw  # heavy: only drawing needs it

    arr = np.asarray(tiles, dtype=np.float32)
    check_shape(arr, "tiles", "R, C, h, w", "R, C, h, w, 3", at_least={"R": 1, "C": 1, "h": 1, "w": 1})
    if arr.ndim == 4:
        arr = np.repeat(arr[..., None], 3, axis=-1)
    n_rows, n_cols, h, w, _ = arr.shape
    if len(row_labels) != n_rows or len(column_labels) != n_cols:
        raise ValueError(f"need {n_rows} row labels and {n_cols} column labels for the tiles, got "
                         f"{len(row_labels)} and {len(column_labels)}")
    check_int(min_tile, "min_tile", minimum=1)
    scale = max(1, math.ceil(min_tile / max(h, w)))
    th, tw = h * scale, w * scale
    pixels = (np.clip(arr, 0.0, 1.0) * 255).round().astype(np.uint8)
    pixels = pixels.repeat(scale, axis=2).repeat(scale, axis=3)

    font = _font()
    measure = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    # A column is as wide as its tile, or as its labels' longest word (the tile centred in it).
    words = [word for label in column_labels for word in str(label).split(" ")]
    cw = max(tw, math.ceil(max(measure.textlength(word, font=font) for word in words)) + PADDING)
    columns = [_wrap(str(label), cw, measure, font) for label in column_labels]
    rows = [str(label) for label in row_labels]
    left = max(measure.textbbox((0, 0), label, font=font)[2] for label in rows) + 2 * PADDING
    top = max(measure.multiline_textbbox((0, 0), label, font=font)[3] for label in columns) + 2 * PADDING

    sheet = Image.new("RGB", (left + n_cols * (cw + gap), top + n_rows * (th + gap)), "white")
    draw = ImageDraw.Draw(sheet)
    for c, label in enumerate(columns):
        x = left + c * (cw + gap) + cw / 2
        draw.multiline_text((x, top - PADDING), label, fill="black", font=font, anchor="md", align="center")
    for r, label in enumerate(rows):
        y = top + r * (th + gap)
        draw.text((PADDING, y + th / 2), label, fill="black", font=font, anchor="lm")
        for c in range(n_cols):
            sheet.paste(Image.fromarray(pixels[r, c]), (left + c * (cw + gap) + (cw - tw) // 2, y))
    return np.asarray(sheet, dtype=np.float32) / 255.0


def _font():
    """PIL's built-in font (no file to find or download); a scalable one where PIL has FreeType."""
    from PIL import ImageFont  # heavy: only drawing needs it

    try:
        return ImageFont.load_default(size=TEXT_SIZE)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font only
        return ImageFont.load_default()


def _wrap(label: str, width: int, measure, font) -> str:
    """``label`` broken at spaces into lines no wider than ``width`` pixels where a word allows."""
    lines: list[str] = []
    for word in label.split(" "):
        if lines and measure.textlength(f"{lines[-1]} {word}", font=font) <= width:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    return "\n".join(lines)
