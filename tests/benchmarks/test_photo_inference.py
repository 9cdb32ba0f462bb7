"""The photo benchmark's photos (benchmarks.photo_inference): JPEGs with no alpha, the object scaled
by 0.8 to 1.2 and moved by up to 10% of the image, that svr.infer's reading and framing put back
where the render had it."""
from __future__ import annotations

import io

import numpy as np
from PIL import Image

from benchmarks.photo_inference import CANVAS, make_photo, sample_test_views
from svr.data.datasets import NMRDataset
from svr.data.procedural.generator import ensure_procedural_dataset, render_dataset_object
from tests.svr.conftest import TINY_SETTINGS
from svr.inference.framing import bounding_box, frame_image, measure_framing
from svr.inference.images import read_rgba


def test_photos_are_moved_scaled_jpegs_that_framing_puts_back(tmp_path):
    yy, xx = np.mgrid[:64, :64]
    alpha = np.where(((yy - 34) / 14.0) ** 2 + ((xx - 30) / 20.0) ** 2 < 1, 255, 0).astype(np.uint8)
    render = np.stack([np.full((64, 64), 90, np.uint8)] * 3 + [alpha])
    rng = np.random.default_rng(3)
    for k in range(4):
        data, scale = make_photo(render, rng)
        photo = Image.open(io.BytesIO(data))
        assert photo.format == "JPEG" and photo.mode == "RGB" and photo.size == (CANVAS, CANVAS)
        assert 0.8 <= scale <= 1.2
        path = tmp_path / f"p{k}.jpg"
        path.write_bytes(data)
        rgba = read_rgba(path)  # the white background removed
        left, top, right, bottom = bounding_box(rgba[..., 3] >= 128)
        assert 2 * scale - 0.1 <= (right - left) / 40 <= 2 * scale + 0.1  # 40 pixels wide in the render, 2x
        assert abs((left + right) / 2 - CANVAS / 2) <= 0.1 * CANVAS + 2 * scale * 2 + 2  # its centre is 2 off
        framed, _ = frame_image(rgba, str(path), 64, measure_framing(alpha[None]))
        back = bounding_box(framed[..., 3] >= 128)
        assert np.allclose(back, bounding_box(alpha >= 128), atol=1.0)  # within a pixel of the render's


def test_random_test_views_are_renders_from_their_cameras(tmp_path):
    """--random-views: the renders come from the drawn cameras (the view coordinate modulo 24 and an
    elevation of 10 to 50 degrees); the NMR mode gives the stored views themselves."""
    root = ensure_procedural_dataset(tmp_path, TINY_SETTINGS, progress=False)
    test = NMRDataset(root, "test")
    renders, rows = sample_test_views(root, test, 1, 3, True, np.random.default_rng(0))
    assert renders.shape == (3, 4, 64, 64) and rows.shape == (3, 2)
    assert ((rows[:, 0] >= 0) & (rows[:, 0] < 24)).all() and ((rows[:, 1] >= 10) & (rows[:, 1] <= 50)).all()
    c, o = test.locate(1)
    cams = np.stack([-15.0 * rows[:, 0], rows[:, 1]], axis=1)  # the same cameras, another azimuth turn
    again = render_dataset_object(root, test.categories[c][0], "test", o, cams)
    assert np.abs(again.astype(int) - renders).max() <= 1
    stored, nmr_rows = sample_test_views(root, test, 1, 2, False, np.random.default_rng(0))
    assert np.array_equal(stored, test.images_uint8(1, nmr_rows[:, 0].astype(int).tolist()))
    assert (nmr_rows[:, 1] == 30).all()
