"""The speaker generator: frozen parameter records built deterministically, sweeps that draw every
style, profile, base, form and port and the hidden depths (recessed baffles, open backs, hollows
underneath), proportions, and one labelled solid of a few tens of rows per object."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from svr.data.procedural.categories import make_shape, speaker, style_of
from svr.data.procedural.generator import voxelize_shape

from .helpers import records


def test_records_are_frozen_and_build_is_deterministic():
    p = speaker.sample(np.random.default_rng(3), speaker.STYLES[0])
    assert dataclasses.is_dataclass(p) and dataclasses.fields(p)[0].name == "style"
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.style = "x"
    np.testing.assert_array_equal(speaker.build(p).program, speaker.build(p).program)
    with pytest.raises(ValueError, match="style must be one of"):
        speaker.sample(np.random.default_rng(0), "teapot")


def test_speaker_sweep():
    recs = records(speaker)
    assert {r.style for r in recs} == set(speaker.STYLES)
    assert {r.profile for r in recs} == set(speaker.PROFILES)
    assert {r.base for r in recs} == set(speaker.BASES)
    assert {r.form for r in recs if r.style == "round"} == set(speaker.ROUND_FORMS)
    assert {r.port for r in recs} == {"none", "round", "slot"}
    assert any(r.grille for r in recs)
    assert {r.firing for r in recs if r.style == "subwoofer"} == {"front", "side", "bottom"}
    assert len({len(r.drivers) for r in recs}) >= 4
    assert np.ptp([r.cone_depth for r in recs]) > 0.3


def test_proportions_span_a_wide_range():
    # the smallest spread of each normalised bounding-box ratio: height/width 1.5, depth/width 0.8
    hw, dw = [], []
    for k in range(30):
        lo, hi = make_shape("speaker", [21, k]).bounds
        ext = hi - lo
        hw.append(ext[1] / ext[0])
        dw.append(ext[2] / ext[0])
    assert np.ptp(hw) >= 1.5 and np.ptp(dw) >= 0.8, (np.ptp(hw), np.ptp(dw))


def test_objects_are_one_solid_with_parts():
    styles = set()
    for k in range(16):
        shape = make_shape("speaker", [22, k])
        styles.add(style_of("speaker", [22, k]))
        vox = voxelize_shape(shape, rule="protocol")
        _, count = ndimage.label(vox, structure=np.ones((3, 3, 3)))
        assert count == 1, (k, count)
        assert 2 <= len(shape.parts) <= 8, shape.parts
        assert len(shape.program) <= 40
    assert len(styles) >= 3


def test_speaker_hidden_depths_and_forms_are_drawn():
    recs = records(speaker, seed=31)
    assert {r.form for r in recs if r.style == "soundbar"} == set(speaker.BAR_FORMS)
    assert any(r.handle for r in recs if r.form == "boombox")
    box = [r for r in recs if r.style != "round"]
    rec = [r.recess / r.depth for r in box if r.recess > 0]
    assert 0.2 < len(rec) / len(box) < 0.9 and min(rec) < 0.2 and max(rec) > 0.5
    assert sum(r.back_open > 0 for r in box) >= 15
    assert sum(r.gap[1] > 0 for r in recs) >= 5
    assert sum(r.bottom_well > 0 for r in recs) >= 3
    walls = [r.wall for r in box]
    assert min(walls) < 0.07 and max(walls) > 0.13
    assert np.ptp([r.top_well for r in recs]) > 0.6


def test_every_style_builds_one_labelled_solid():
    for k in range(24):
        style = speaker.STYLES[k % len(speaker.STYLES)]
        shape = speaker.build(speaker.sample(np.random.default_rng([33, k]), style)).normalized()
        vox = voxelize_shape(shape, rule="protocol")
        _, count = ndimage.label(vox, structure=np.ones((3, 3, 3)))
        assert count == 1, (style, k, count)
        assert 2 <= len(shape.parts) <= 8, shape.parts
        assert len(shape.program) <= 45, (style, k, len(shape.program))
