"""Object colours and the NMR light of the procedural renders (svr/data/procedural/appearance.py)."""
from __future__ import annotations

import colorsys

import numpy as np

from svr.data.procedural.appearance import NMR_LIGHTING, colour_rng, draw_colours
from svr.data.procedural.generator import make_shape, object_seed

PARTS = ("body", "legs", "seat", "back")


def _objects(n: int) -> list[np.ndarray]:
    return [draw_colours(colour_rng(object_seed(0, "03001627", "train", k)), PARTS) for k in range(n)]


def test_object_colours_cover_the_palette():
    """Over 400 objects: dark, near-white and saturated objects, every hue sextant among the
    saturated ones, and objects with one colour as well as with several."""
    objects = _objects(400)
    means = np.array([c.mean(0) for c in objects])
    value, sat = means.max(1), means.max(1) - means.min(1)
    assert (value < 0.2).mean() > 0.08                      # near-black
    assert (means.min(1) > 0.8).mean() > 0.05               # near-white
    hues = [colorsys.rgb_to_hsv(*m)[0] for m, s in zip(means, sat) if s > 0.35]
    assert len(hues) > 40 and len(set(int(h * 6) % 6 for h in hues)) == 6
    distinct = np.array([len(np.unique(c, axis=0)) for c in objects])
    assert (distinct == 1).mean() > 0.25 and (distinct > 1).mean() > 0.4 and (distinct == 4).any()
    assert all(((c >= 0) & (c <= 1)).all() for c in objects)


def test_a_seed_gives_the_same_colours_and_does_not_touch_the_shape():
    a, b = _objects(20), _objects(20)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not all(np.array_equal(a[0], x) for x in a[1:])
    seed = object_seed(0, "03001627", "train", 3)
    shape = make_shape("chair", seed)
    draw_colours(colour_rng(seed), shape.parts)
    assert np.array_equal(make_shape("chair", seed).program, shape.program)


def test_nmr_light_is_environment_plus_a_lambert_lamp():
    lamp = np.asarray(NMR_LIGHTING.direction) / np.linalg.norm(NMR_LIGHTING.direction)
    normals = np.stack([lamp, -lamp, np.cross(lamp, [0.0, 0.0, 1.0]) / np.linalg.norm(np.cross(lamp, [0, 0, 1]))])
    albedo = np.array([[0.5, 0.2, 1.0]] * 3)
    rgb = NMR_LIGHTING.shade(normals, albedo)
    full = NMR_LIGHTING.environment + NMR_LIGHTING.lamp
    assert np.allclose(rgb[0], np.minimum(albedo[0] * full, 1.0))   # facing the lamp (blue clipped at 1)
    assert np.allclose(rgb[1], albedo[1] * NMR_LIGHTING.environment)  # facing away: environment only
    assert np.allclose(rgb[2], albedo[2] * NMR_LIGHTING.environment)  # grazing
