"""The phone generator: its parameter records cover every style and option and wide ranges of
thicknesses, angles and lengths, its built objects spread in proportion, are one connected solid each
with named parts, handsets bend and flip phones open at any angle, the styles differ in structure, and
a desk phone's handset leaves a hole."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svr.data.procedural.categories import phone

from .helpers import checked_extents, extent, genus, records, span


def test_phone_sweep_covers_styles_options_and_wide_ranges():
    recs = records(phone, 240, seed=41)
    assert {r.style for r in recs} == set(phone.STYLES)
    assert {r.stand for r in recs} == {"none", "dock", "easel"}
    assert {r.camera for r in recs} == {"none", "square", "round", "strip"}
    for flag in ("button", "antenna", "sideways", "display", "cord", "dock_round"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    hand = [r for r in recs if r.style != "desk"]
    lo, hi = span([r.thick for r in hand])
    assert lo < 0.075 and hi > 0.22 and hi / lo > 3  # slab thickness: a thin smartphone to a brick
    lo, hi = span([r.lid_thick for r in recs])
    assert lo < 0.065 and hi > 0.14
    lo, hi = span([r.lean for r in hand])  # upright, tilted, leaning in a dock or on a strut
    assert lo < 0.02 and hi > 0.6
    assert span([r.lean for r in hand if r.stand == "none"])[1] > 0.25
    flips = [r.opening for r in recs if r.style == "flip"]
    assert 0.0 in flips and min(f for f in flips if f > 0) < 1.0 and max(flips) > 3.0
    assert len({round(f, 3) for f in flips}) > 10  # open at any angle
    batteries = [r.battery for r in recs if r.style in ("slab", "candybar")]
    assert 0.0 in batteries and max(batteries) > 0.12
    assert 0 < sum(r.dock_back > 0 for r in recs if r.stand == "dock") < sum(r.stand == "dock" for r in recs)
    handsets = [r for r in recs if r.style == "handset"]
    assert span([r.bend for r in handsets])[0] < 0.05 and span([r.bend for r in handsets])[1] > 0.4
    assert span([r.ear_thick for r in handsets])[1] / span([r.ear_thick for r in handsets])[0] > 2.5
    assert span([r.strut_t for r in recs])[1] > 0.1
    desks = [r for r in recs if r.style == "desk"]
    assert span([r.thick for r in desks])[0] < 0.08 and span([r.thick for r in desks])[1] > 0.3


def test_phone_proportions_spread_and_objects_are_connected_and_labelled():
    ext = checked_extents("phone", phone.STYLES, 43, 36)
    assert ext[:, 2].min() < 0.25 and ext[:, 2].max() > 0.6  # depth: thin upright slabs to leaning and desk phones
    assert ext[:, 0].min() < 0.35 and ext[:, 0].max() > 0.9  # width: a narrow handset to a desk phone


def test_phone_handset_bends_and_flip_opens_at_any_angle():
    rec = phone.sample(np.random.default_rng([5, 1]), "handset")
    straight = phone.build(dataclasses.replace(rec, bend=0.0, stand="none", lean=0.0, antenna=False)).normalized()
    bent = phone.build(dataclasses.replace(rec, bend=0.45, stand="none", lean=0.0, antenna=False)).normalized()
    assert extent(bent)[2] > extent(straight)[2] * 1.3  # the ear end leans out to the front
    rec = phone.sample(np.random.default_rng([5, 2]), "flip")
    depths = [extent(phone.build(dataclasses.replace(rec, opening=a, stand="none", lean=0.0)).normalized())[2]
              for a in (0.0, 1.2, np.pi)]
    assert depths[1] > depths[0] and depths[1] > depths[2]  # half open: a V seen from the side


def test_phone_styles_differ_in_structure():
    """A closed flip phone is short and thick, an open one tall; a desk phone with its handset lying
    in the cradle is wider than tall."""
    for k in range(3):
        rec = phone.sample(np.random.default_rng([7, k]), "flip")
        closed = phone.build(dataclasses.replace(rec, opening=0.0, stand="none", lean=0.0)).normalized()
        opened = phone.build(dataclasses.replace(rec, opening=np.pi, stand="none", lean=0.0)).normalized()
        assert extent(closed)[1] / extent(closed)[2] < extent(opened)[1] / extent(opened)[2] / 1.5
        rec = phone.sample(np.random.default_rng([7, k]), "desk")
        desk = phone.build(dataclasses.replace(rec, layout="across", thick=0.15)).normalized()
        assert extent(desk)[1] < extent(desk)[0]


@pytest.mark.parametrize("layout", ["side", "across"])
def test_phone_hole_under_a_desk_handset(layout):
    rec = dataclasses.replace(phone.sample(np.random.default_rng([9, 0]), "desk"), layout=layout, cord=False)
    assert genus(phone.build(rec).normalized()) >= 1
