"""The display generator: frozen parameter records built deterministically, a sweep that draws every
style and stand over wide ranges, proportions, one labelled solid per object, and screens that are
their own part."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from svr.data.procedural.categories import display, make_shape, style_of
from svr.data.procedural.generator import voxelize_shape

from .helpers import records


def test_records_are_frozen_and_build_is_deterministic():
    p = display.sample(np.random.default_rng(3), display.STYLES[0])
    assert dataclasses.is_dataclass(p) and dataclasses.fields(p)[0].name == "style"
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.style = "x"
    np.testing.assert_array_equal(display.build(p).program, display.build(p).program)
    with pytest.raises(ValueError, match="style must be one of"):
        display.sample(np.random.default_rng(0), "teapot")


def test_display_sweep():
    recs = records(display)
    assert {r.style for r in recs} == set(display.STYLES)
    assert {r.stand for r in recs if r.style == "monitor"} == set(display.FEET)
    assert {r.stand for r in recs if r.style == "arm"} == {"clamp", "disc"}
    assert np.ptp([r.arm for r in recs if r.style == "wall"]) > 0.3
    assert {r.stand for r in recs if r.style == "tv"} == set(display.TV_STANDS)
    assert {r.tube_round for r in recs if r.style == "crt"} == {True, False}
    assert any(r.housing[2] > 0 for r in recs) and any(r.housing[2] == 0 for r in recs)
    assert any(r.soundbar for r in recs)
    thick = [r.thick for r in recs if r.style != "crt"]
    assert min(thick) < 0.075 and max(thick) > 0.12
    tilt = [r.tilt for r in recs]
    assert min(tilt) < -0.1 and max(tilt) > 0.3


def test_proportions_span_a_wide_range():
    # the smallest spread of each normalised bounding-box ratio: height/width 0.3, depth/width 0.5
    hw, dw = [], []
    for k in range(30):
        lo, hi = make_shape("display", [21, k]).bounds
        ext = hi - lo
        hw.append(ext[1] / ext[0])
        dw.append(ext[2] / ext[0])
    assert np.ptp(hw) >= 0.3 and np.ptp(dw) >= 0.5, (np.ptp(hw), np.ptp(dw))


def test_objects_are_one_solid_with_parts():
    styles = set()
    for k in range(16):
        shape = make_shape("display", [22, k])
        styles.add(style_of("display", [22, k]))
        vox = voxelize_shape(shape, rule="protocol")
        _, count = ndimage.label(vox, structure=np.ones((3, 3, 3)))
        assert count == 1, (k, count)
        assert 2 <= len(shape.parts) <= 8, shape.parts
        assert len(shape.program) <= 40
    assert len(styles) >= 3


def test_display_screens_are_their_own_part():
    for k in range(6):
        assert "screen" in make_shape("display", [23, k]).parts
