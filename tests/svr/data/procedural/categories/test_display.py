"""The display generator: frozen parameter records built deterministically, a sweep that draws every
style and stand over wide ranges, proportions, one labelled solid per object, and screens that are
their own part."""
from __future__ import annotations


import numpy as np

from svr.data.procedural.categories import display, make_shape

from .helpers import (check_one_solid_with_parts, check_ratio_spreads, check_records_frozen_and_build_deterministic,
                      records)


def test_records_are_frozen_and_build_is_deterministic():
    check_records_frozen_and_build_deterministic(display)


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
    check_ratio_spreads("display", 0.3, 0.5)


def test_objects_are_one_solid_with_parts():
    check_one_solid_with_parts("display")


def test_display_screens_are_their_own_part():
    for k in range(6):
        assert "screen" in make_shape("display", [23, k]).parts
