"""Framing a photo like the training renders: find the object (alpha, a mask, or a plain background
told apart from it), then crop and scale the image so that the object's silhouette has the size
and place it has in the renders the network learnt from, recording the transform so that pixels
map back to the photo. NMR-style renders show an object normalised to a longest side of 1 from
2.732 units with a 30 degree field of view, so its silhouette's bounding box in a 64^2 render is
about 45 pixels on its longest side and centred a little below the middle (``measure_framing``
measures both on a dataset's training views; ``TRAINING_FRAMING`` is what it gave on the procedural
data). Framing normalises a photo's scale and offset to those medians; the object's true scale in
the renders varies with its shape and view (the 5th to 95th percentile of the longest side is 31
to 56 pixels), which a camera estimate has to settle. Every refusal is one line naming the file.
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from typing import Union

import numpy as np

PathLike = Union[str, os.PathLike]
# A background pixel differs from the border's median colour by at most this (0..255, per channel):
# room for JPEG noise and soft shading of a studio backdrop.
BACKGROUND_TOLERANCE = 24
# The share of border pixels that must be the background colour for the background to count as plain.
PLAIN_BORDER_SHARE = 0.95


@dataclass(frozen=True)
class Framing:
    """Where the object's silhouette sits in a training render.

    Attributes:
        extent: the longest side of its bounding box, as a fraction of the image side.
        centre_x, centre_y: the box's centre, as fractions of the image side from the left and top.
    """

    extent: float
    centre_x: float
    centre_y: float


# measure_framing on the procedural training split (generator version 4, every 4th object, all 24
# views): longest side median 45 of 64 pixels, centre (32, 33) pixels.
TRAINING_FRAMING = Framing(extent=45 / 64, centre_x=32 / 64, centre_y=33 / 64)


@dataclass(frozen=True)
class FrameTransform:
    """The similarity that framed an image: framed = scale * photo + offset, in pixel coordinates
    (x right, y down, pixel centres at half-integers), with the photo's and framed image's sizes."""

    scale: float
    offset_x: float
    offset_y: float
    photo_size: tuple[int, int]  # (width, height)
    framed_size: int

    def to_framed(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) photo pixel coordinates -> framed image coordinates."""
        return np.asarray(xy, dtype=np.float64) * self.scale + np.array([self.offset_x, self.offset_y])

    def to_photo(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) framed image coordinates -> photo pixel coordinates."""
        return (np.asarray(xy, dtype=np.float64) - np.array([self.offset_x, self.offset_y])) / self.scale

    def to_dict(self) -> dict:
        return asdict(self)


def border_pixels(image: np.ndarray) -> np.ndarray:
    """(2 (H + W) - 4, ...) the pixels of the image's outer ring, each once."""
    image = np.asarray(image)
    return np.concatenate([image[0], image[-1], image[1:-1, 0], image[1:-1, -1]])


def bounding_box(mask: np.ndarray) -> tuple[float, float, float, float]:
    """(left, top, right, bottom) of the True pixels, in pixel-edge coordinates (a single pixel at
    column 3 spans 3 to 4)."""
    rows, cols = np.any(mask, axis=1), np.any(mask, axis=0)
    top, bottom = np.flatnonzero(rows)[[0, -1]]
    left, right = np.flatnonzero(cols)[[0, -1]]
    return float(left), float(top), float(right + 1), float(bottom + 1)


def measure_framing(alphas: np.ndarray) -> Framing:
    """The median framing of (N, S, S) uint8 silhouettes (a dataset's training views; empty ones skipped)."""
    alphas = np.asarray(alphas)
    size = alphas.shape[-1]
    boxes = [bounding_box(a >= 128) for a in alphas if (a >= 128).any()]
    if not boxes:
        raise ValueError("measure_framing: every silhouette is empty")
    b = np.array(boxes)
    extent = np.maximum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])
    return Framing(extent=float(np.median(extent)) / size, centre_x=float(np.median((b[:, 0] + b[:, 2]) / 2)) / size,
                   centre_y=float(np.median((b[:, 1] + b[:, 3]) / 2)) / size)


def background_mask(rgb: np.ndarray, name: str, tolerance: float = BACKGROUND_TOLERANCE) -> np.ndarray:
    """The object of a photo on a plain background: pixels that differ from the border's colour.

    The background is the median colour of the image's border pixels, and must be plain: at least
    ``PLAIN_BORDER_SHARE`` of the border within ``tolerance`` of it. Holes inside the object that
    look like the background (a white label on a white backdrop) are filled.

    Args:
        rgb: (H, W, 3) uint8.
        name: the file, for errors.
    Returns:
        (H, W) bool, True on the object.
    Raises:
        ValueError naming ``name`` when the border is not one plain colour or nothing differs from it.
    """
    from scipy import ndimage

    rgb = np.asarray(rgb, dtype=np.int16)
    border = border_pixels(rgb)
    colour = np.median(border, axis=0)
    plain = float((np.abs(border - colour).max(axis=1) <= tolerance).mean())
    if plain < PLAIN_BORDER_SHARE:
        raise ValueError(f"{name}: cannot tell the background from the object: only {plain:.0%} of the image border "
                         f"is one plain colour (at least {PLAIN_BORDER_SHARE:.0%} needed); give an RGBA image or a mask file")
    diff = np.abs(rgb - colour).max(axis=2).astype(np.float32)
    square = np.ones((3, 3), bool)
    mask = ndimage.binary_opening(diff > tolerance, structure=square)  # specks of JPEG noise are not the object
    if not mask.any():
        raise ValueError(f"{name}: cannot tell the object from the background: no pixel differs from the border's "
                         f"colour {tuple(int(c) for c in colour)} by more than {tolerance:g}; give an RGBA image or a mask file")
    # The edge where an alpha channel would be 0.5: a pixel of the mask's rim stays only if it differs
    # from the background by at least half as much as the object just inside it does.
    inner = ndimage.binary_erosion(mask, structure=square, iterations=2)
    contrast = ndimage.maximum_filter(np.where(inner, diff, 0.0), size=7)
    mask &= inner | (diff >= 0.5 * contrast)
    return ndimage.binary_fill_holes(mask)


def check_inside(mask: np.ndarray, name: str) -> None:
    """Refuses a silhouette that touches the image border: the object is cut off, so its size and
    centre are unknown."""
    if border_pixels(mask).any():
        raise ValueError(f"{name}: the object touches the image border, so it may be cut off and cannot be framed; "
                         f"use a photo with background all round it")


def frame_image(rgba: np.ndarray, name: str, size: int = 64, framing: Framing = TRAINING_FRAMING,
                supersample: int = 4) -> tuple[np.ndarray, FrameTransform]:
    """Crops and scales an RGBA photo so that its silhouette (alpha >= 128) has ``framing``'s extent
    and centre in a ``size``^2 image.

    Each output pixel averages ``supersample``^2 bilinear samples of the photo (premultiplied by
    alpha, so the background colour does not bleed into the edge); what lies outside the photo is
    transparent.

    Args:
        rgba: (H, W, 4) uint8.
        name: the file, for errors.
    Returns:
        (size, size, 4) uint8 framed image and its FrameTransform.
    Raises:
        ValueError naming ``name`` for an empty silhouette or one touching the border.
    """
    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] != 4:
        raise ValueError(f"{name}: expected an (H, W, 4) RGBA image, got shape {rgba.shape}")
    mask = rgba[..., 3] >= 128
    if not mask.any():
        raise ValueError(f"{name}: the silhouette is empty (no opaque pixel); the object must be opaque on a "
                         f"transparent or plain background")
    check_inside(mask, name)
    left, top, right, bottom = bounding_box(mask)
    scale = framing.extent * size / max(right - left, bottom - top)
    offset_x = framing.centre_x * size - scale * (left + right) / 2
    offset_y = framing.centre_y * size - scale * (top + bottom) / 2
    h, w = mask.shape
    transform = FrameTransform(scale=scale, offset_x=offset_x, offset_y=offset_y, photo_size=(w, h), framed_size=size)
    k = int(supersample)
    sub = (np.arange(size * k) + 0.5) / k  # framed coordinates of the sub-samples
    xs = (sub - offset_x) / scale - 0.5  # photo coordinates, pixel centres at integers
    ys = (sub - offset_y) / scale - 0.5
    # Only the part of the photo the frame covers, shrunk by whole factors (box means) until the
    # sub-samples are no sparser than its pixels.
    x0, x1 = max(int(np.floor(xs[0])) - 1, 0), min(int(np.ceil(xs[-1])) + 2, w)
    y0, y1 = max(int(np.floor(ys[0])) - 1, 0), min(int(np.ceil(ys[-1])) + 2, h)
    premult = rgba[y0:y1, x0:x1].astype(np.float32)
    premult[..., :3] *= premult[..., 3:] / 255.0
    xs, ys = xs - x0, ys - y0
    f = max(int(1.0 / (scale * k)), 1)
    if f > 1:
        ch, cw = -(-premult.shape[0] // f) * f, -(-premult.shape[1] // f) * f  # padded with transparency
        premult = np.pad(premult, ((0, ch - premult.shape[0]), (0, cw - premult.shape[1]), (0, 0)))
        premult = premult.reshape(ch // f, f, cw // f, f, 4).mean(axis=(1, 3))
        xs, ys = (xs + 0.5) / f - 0.5, (ys + 0.5) / f - 0.5
    samples = _bilinear(premult, xs, ys)  # (S k, S k, 4)
    out = samples.reshape(size, k, size, k, 4).mean(axis=(1, 3))
    alpha = out[..., 3:]
    rgb = np.where(alpha > 0, out[..., :3] * 255.0 / np.maximum(alpha, 1e-9), 255.0)
    framed = np.concatenate([rgb, alpha], axis=-1)
    return np.clip(np.rint(framed), 0, 255).astype(np.uint8), transform


def _bilinear(image: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Samples (H, W, C) at the grid of columns ``xs`` and rows ``ys`` (pixel centres at integers);
    zero outside."""
    h, w, _ = image.shape
    padded = np.zeros((h + 2, w + 2, image.shape[2]), dtype=image.dtype)
    padded[1:-1, 1:-1] = image
    x = np.clip(xs + 1, 0, w + 1 - 1e-9)
    y = np.clip(ys + 1, 0, h + 1 - 1e-9)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w + 1), np.minimum(y0 + 1, h + 1)
    fx, fy = (x - x0)[None, :, None], (y - y0)[:, None, None]
    top = padded[y0][:, x0] * (1 - fx) + padded[y0][:, x1] * fx
    bottom = padded[y1][:, x0] * (1 - fx) + padded[y1][:, x1] * fx
    return top * (1 - fy) + bottom * fy


def object_rgba(rgb: np.ndarray, name: str) -> np.ndarray:
    """(H, W, 4) uint8: a photo on a plain background with the background removed (alpha 0 there,
    255 on the object: ``background_mask``)."""
    rgb = np.asarray(rgb, dtype=np.uint8)[..., :3]
    alpha = background_mask(rgb, name).astype(np.uint8) * 255
    return np.concatenate([rgb, alpha[..., None]], axis=-1)


__all__ = ["Framing", "TRAINING_FRAMING", "FrameTransform", "border_pixels", "bounding_box", "measure_framing", "background_mask",
           "check_inside", "frame_image", "object_rgba"]
