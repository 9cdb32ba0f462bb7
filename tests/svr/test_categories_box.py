"""The boxy procedural categories (cabinet, speaker, display): parameter records, their sweeps,
proportions, connectedness, parts and holes."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from svr.data.procedural.categories import cabinet, display, make_shape, speaker, style_of
from svr.data.procedural.generator import voxelize_shape

from .test_categories import _genus

MODULES = {"cabinet": cabinet, "speaker": speaker, "display": display}


def _records(module, n: int = 200):
    out = []
    for k in range(n):
        rng = np.random.default_rng(k)
        style = module.STYLES[k % len(module.STYLES)]
        out.append(module.sample(rng, style))
    return out


@pytest.mark.parametrize("name", MODULES)
def test_records_are_frozen_and_build_is_deterministic(name):
    module = MODULES[name]
    p = module.sample(np.random.default_rng(3), module.STYLES[0])
    assert dataclasses.is_dataclass(p) and dataclasses.fields(p)[0].name == "style"
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.style = "x"
    np.testing.assert_array_equal(module.build(p).program, module.build(p).program)
    with pytest.raises(ValueError, match="style must be one of"):
        module.sample(np.random.default_rng(0), "teapot")


def test_cabinet_sweep():
    recs = _records(cabinet)
    assert {r.style for r in recs} == set(cabinet.STYLES)
    assert {r.base for r in recs} == set(cabinet.BASES)
    assert {r.handle for r in recs} == set(cabinet.HANDLES)
    assert {r.leg_shape for r in recs} == set(cabinet.LEG_SHAPES)
    kinds = {kind for r in recs for s in r.sections for t in s.tiers for kind, _ in t.cells}
    assert kinds == set(cabinet.CELL_KINDS)
    assert len({len(r.sections) for r in recs}) >= 3
    assert len({sum(len(t.cells) for s in r.sections for t in s.tiers) for r in recs}) >= 8  # cell counts
    assert any(r.back == 0 for r in recs) and max(r.back for r in recs) > 0.15
    assert any(r.upper_height > 0 for r in recs) and any(r.front_recess > 0 for r in recs)
    assert np.ptp([r.panel for r in recs]) > 0.04 and np.ptp([r.base_height for r in recs]) > 0.15


def test_speaker_sweep():
    recs = _records(speaker)
    assert {r.style for r in recs} == set(speaker.STYLES)
    assert {r.profile for r in recs} == set(speaker.PROFILES)
    assert {r.base for r in recs} == set(speaker.BASES)
    assert {r.form for r in recs if r.style == "round"} == set(speaker.ROUND_FORMS)
    assert {r.port for r in recs} == {"none", "round", "slot"}
    assert any(r.grille for r in recs)
    assert {r.firing for r in recs if r.style == "subwoofer"} == {"front", "side", "bottom"}
    assert len({len(r.drivers) for r in recs}) >= 4
    assert np.ptp([r.cone_depth for r in recs]) > 0.3


def test_display_sweep():
    recs = _records(display)
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


# (category, smallest spread of each normalised bounding-box ratio height/width, depth/width)
RATIOS = {"cabinet": (1.5, 0.5), "speaker": (1.5, 0.8), "display": (0.3, 0.5)}


@pytest.mark.parametrize("name", MODULES)
def test_proportions_span_a_wide_range(name):
    hw, dw = [], []
    for k in range(30):
        lo, hi = make_shape(name, [21, k]).bounds
        ext = hi - lo
        hw.append(ext[1] / ext[0])
        dw.append(ext[2] / ext[0])
    assert np.ptp(hw) >= RATIOS[name][0] and np.ptp(dw) >= RATIOS[name][1], (np.ptp(hw), np.ptp(dw))


@pytest.mark.parametrize("name", MODULES)
def test_objects_are_one_solid_with_parts(name):
    styles = set()
    for k in range(16):
        shape = make_shape(name, [22, k])
        styles.add(style_of(name, [22, k]))
        vox = voxelize_shape(shape, rule="protocol")
        _, count = ndimage.label(vox, structure=np.ones((3, 3, 3)))
        assert count == 1, (k, count)
        assert 2 <= len(shape.parts) <= 8, shape.parts
        assert len(shape.program) <= 40
    assert len(styles) >= 3


def test_display_screens_are_their_own_part():
    for k in range(6):
        assert "screen" in make_shape("display", [23, k]).parts


def test_holes_where_cabinets_and_displays_have_them():
    """Open-backed shelves are through-holes, and so is a monitor neck's cable cut-out."""
    open_back = [k for k in range(40) if cabinet.sample(np.random.default_rng(k), "open_shelves").back == 0]
    p = cabinet.sample(np.random.default_rng(open_back[0]), "open_shelves")
    assert _genus(cabinet.build(p).normalized()) >= 1
    p = dataclasses.replace(display.sample(np.random.default_rng(1), "monitor"), arm=1.0, neck_width=0.18)
    assert _genus(display.build(p).normalized()) >= 1
