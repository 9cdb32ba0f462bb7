"""svr.inference.framing: a rendered object moved and scaled in a photo is put back where the
framing puts the render itself (within a pixel), with alpha or on a plain background as a JPEG;
the transform maps pixels both ways; refusals are one line naming the file."""
from __future__ import annotations

import io

import numpy as np
import pytest

from svr.inference.framing import (TRAINING_FRAMING, Framing, background_mask, bounding_box, frame_image,
                                   measure_framing, object_rgba)


def render(scale: float = 1.0, offset: tuple[float, float] = (0.0, 0.0), size: tuple[int, int] = (64, 64),
           background=None) -> np.ndarray:
    """An object-like image: a filled ellipse with a stem, drawn as in a 64^2 render, then scaled by
    ``scale`` and moved by ``offset`` (x, y) in a ``size`` (w, h) image, anti-aliased (8x8 samples a
    pixel). RGBA on transparency, or RGB composited on a plain ``background`` colour."""
    k = 8
    w, h = size
    x, y = np.meshgrid((np.arange(w * k) + 0.5) / k, (np.arange(h * k) + 0.5) / k)
    x, y = (x - offset[0]) / scale, (y - offset[1]) / scale  # back to the 64^2 render's coordinates
    body = ((x - 30) / 16) ** 2 + ((y - 26) / 10) ** 2 <= 1
    stem = (np.abs(x - 30) <= 2.5) & (y >= 26) & (y <= 50)
    alpha = (body | stem).reshape(h, k, w, k).mean(axis=(1, 3))
    colour = np.array([200, 60, 40], dtype=np.float64)
    if background is None:
        rgba = np.zeros((h, w, 4), np.uint8)
        rgba[..., :3] = colour
        rgba[..., 3] = np.rint(alpha * 255)
        return rgba
    rgb = colour * alpha[..., None] + np.array(background, dtype=np.float64) * (1 - alpha[..., None])
    return np.rint(rgb).astype(np.uint8)


def jpeg(rgb: np.ndarray) -> np.ndarray:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="JPEG", quality=90)
    return np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"))


def box(rgba: np.ndarray) -> np.ndarray:
    return np.array(bounding_box(rgba[..., 3] >= 128))


def test_a_moved_and_scaled_object_is_put_back_within_a_pixel():
    original = render()
    reference, _ = frame_image(original, "render.png")
    left, top, right, bottom = box(reference)
    assert max(right - left, bottom - top) == pytest.approx(TRAINING_FRAMING.extent * 64, abs=1)
    assert ((left + right) / 2, (top + bottom) / 2) == pytest.approx((32, 33), abs=1)
    for scale, offset, size in ((3.3, (20, 41), (260, 250)), (5.6, (150, 12), (560, 380))):
        photo = render(scale, offset, size)
        framed, t = frame_image(photo, "photo.png")
        assert np.abs(box(framed) - box(reference)).max() <= 1
        assert np.abs(framed[..., 3].astype(int) - reference[..., 3]).mean() < 4  # alpha, 0..255
        # The transform maps the photo's object box onto the framed one and back.
        corners = np.array(bounding_box(photo[..., 3] >= 128)).reshape(2, 2)
        assert np.abs(t.to_framed(corners).reshape(-1) - box(framed)).max() <= 1
        assert t.to_photo(t.to_framed(corners)) == pytest.approx(corners)
        assert t.photo_size == size and t.framed_size == 64


def test_a_jpeg_on_a_plain_background_frames_like_its_alpha():
    original = render()
    reference, _ = frame_image(original, "render.png")
    for background in ((255, 255, 255), (20, 20, 25)):
        photo = jpeg(render(4.2, (37, 60), (330, 340), background=background))
        framed, _ = frame_image(object_rgba(photo, "photo.jpg"), "photo.jpg")
        assert np.abs(box(framed) - box(reference)).max() <= 1
        inter = ((framed[..., 3] >= 128) & (reference[..., 3] >= 128)).sum()
        union = ((framed[..., 3] >= 128) | (reference[..., 3] >= 128)).sum()
        assert inter / union > 0.95


def test_holes_that_look_like_the_background_are_filled():
    rgb = np.full((40, 40, 3), 250, np.uint8)
    rgb[10:30, 10:30] = (30, 90, 200)
    rgb[17:23, 17:23] = 250  # a white label on the object
    mask = background_mask(rgb, "x.png")
    assert mask[10:30, 10:30].all() and mask.sum() == 400


def test_measure_framing_of_known_boxes():
    alphas = np.zeros((3, 64, 64), np.uint8)
    alphas[0, 10:30, 20:40] = 255  # 20 x 20, centre (30, 20)
    alphas[1, 0:40, 12:42] = 255   # 30 wide, 40 high, centre (27, 20)
    alphas[2, 20:41, 20:41] = 255  # 21 x 21, centre (30.5, 30.5)
    assert measure_framing(alphas) == Framing(extent=21 / 64, centre_x=30 / 64, centre_y=20 / 64)


@pytest.mark.parametrize("case, message", [
    ("touches", "photo.png: the object touches the image border"),
    ("empty", "photo.png: the silhouette is empty"),
])
def test_silhouettes_that_cannot_be_framed_are_one_line_naming_the_file(case, message):
    # "touches": the photo's left edge cuts the object.
    rgba = render(2, (-40, 30), (160, 200)) if case == "touches" else np.zeros((50, 50, 4), np.uint8)
    with pytest.raises(ValueError) as err:
        frame_image(rgba, "photo.png")
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


@pytest.mark.parametrize("case, message", [
    ("busy", "photo.jpg: cannot tell the background from the object: only"),
    ("same", "photo.jpg: cannot tell the object from the background: no pixel differs"),
])
def test_backgrounds_that_cannot_be_told_apart_are_one_line_naming_the_file(case, message):
    rng = np.random.default_rng(0)
    if case == "busy":
        rgb = rng.integers(0, 256, (80, 80, 3), dtype=np.uint8)  # no plain colour anywhere
    else:
        rgb = render(2, (40, 40), (220, 220), background=(200, 60, 40))  # object = background colour
    with pytest.raises(ValueError) as err:
        object_rgba(rgb, "photo.jpg")
    assert str(err.value).startswith(message) and "\n" not in str(err.value)
