"""The vessel generator: its parameter records cover every style and option and wide ranges, its
built objects span wide proportions, are one connected solid each with named parts, the styles with
and without superstructure differ, and the open volumes it draws (wells, catamaran tunnels, open
hulls) are empty."""
from __future__ import annotations

import dataclasses

import numpy as np

from svr.data.procedural.categories import make_shape, vessel

from .helpers import (check_every_style_connected_with_named_parts, check_extents_reach, components, inside, records,
                      span, values)


def test_vessel_parameter_sweep():
    recs = records(vessel)
    assert {r.style for r in recs} == set(vessel.STYLES)
    assert {r.cargo for r in recs} == set(vessel.CARGO)
    assert {len(r.tiers) for r in recs if r.style == "ship"} == {1, 2, 3, 4}
    assert {len(r.funnels) for r in recs} == {0, 1, 2}
    assert {len(r.masts) for r in recs} == {0, 1, 2}
    assert {r.thwarts for r in recs if r.style == "rowboat"} >= {1, 2, 3, 4}
    for flag in ("jib", "motor"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    assert 0 < sum(r.oars > 0 for r in recs) and 0 < sum(r.sheer > 0 for r in recs) < len(recs)
    assert span([r.beam for r in recs])[0] < 0.1 and span([r.beam for r in recs])[1] > 0.4
    assert span([r.bow for r in recs])[0] < 0.1 and span([r.bow for r in recs])[1] > 0.4


def test_proportions_span_a_wide_range():
    check_extents_reach("vessel", (0.25, 0.25, 1.0), (0.35, 0.5, 1.0))


def test_objects_are_one_connected_solid_with_named_parts():
    check_every_style_connected_with_named_parts("vessel", vessel)


def test_vessel_styles_with_and_without_superstructure():
    for k in range(3):
        row = make_shape("vessel", [13, k], style="rowboat")
        ship = make_shape("vessel", [13, k], style="ship")
        assert (row.bounds[1] - row.bounds[0])[1] < 0.32  # the bare hull (oars reach below it)
        assert (ship.bounds[1] - ship.bounds[0])[1] > 0.25  # deckhouse, funnels, masts


def test_vessel_sample_sweep_covers_styles_options_and_ranges():
    recs = records(vessel, 240, seed=47)
    assert {r.style for r in recs} == set(vessel.STYLES)
    cats = [r for r in recs if r.tunnel_w > 0]
    assert {r.style for r in cats} == {"ship", "sailboat", "speedboat"}
    assert min(r.tunnel_w for r in cats) < 0.45 and max(r.tunnel_w for r in cats) > 0.6
    wells = [r for r in recs if r.well_z1 > r.well_z0]
    assert {r.style for r in wells} == {"ship", "tanker"}
    sails = [r for r in recs if r.style == "sailboat"]
    assert min(r.sail_th for r in sails) < 0.065 and max(r.sail_th for r in sails) > 0.1
    assert min(r.sail_angle for r in sails) < -0.5 and max(r.sail_angle for r in sails) > 0.5
    assert {r.gaff > 0 for r in sails} == {False, True}
    assert {r.cockpit > 0 for r in sails} == {False, True}
    assert span(values(recs, "wall"))[0] < 0.06 and span(values(recs, "wall"))[1] > 0.095
    assert span(values(recs, "beam"))[0] < 0.1 and span(values(recs, "beam"))[1] > 0.45
    rows = [len(vessel.build(r).program) for r in recs[:60]]
    assert 5 <= min(rows) and max(rows) <= 30 and len(set(rows)) >= 5


def test_vessel_proportions_spread_and_objects_are_connected_and_labelled():
    ext = []
    for k in range(30):
        shape = make_shape("vessel", [48, k])
        lo, hi = shape.bounds
        ext.append(np.asarray(hi) - np.asarray(lo))
        assert len(shape.parts) >= 2 and "hull" in shape.parts, k
        if k < 12:
            assert components(shape) == 1, k
    ext = np.array(ext)
    assert ext[:, 0].min() < 0.15 and ext[:, 0].max() > 0.35  # beam over the longest side
    assert ext[:, 1].min() < 0.15 and ext[:, 1].max() > 0.6  # height: hulls to sails


def test_vessel_tunnel_and_wells_are_open():
    """A catamaran's tunnel is empty under its bridge deck, which stays solid; a well deck is empty
    above its floor, a rowboat's open hull above its floor."""
    rec = dataclasses.replace(vessel.sample(np.random.default_rng([3, 1]), "speedboat"), tunnel_w=0.5, tunnel_h=0.5,
                              v_rise=0.0)
    s = vessel.build(rec)
    assert not inside(s, 0.0, 0.01, 0.0) and inside(s, rec.beam * 0.45, 0.01, 0.0)
    for k in range(6):
        rec = vessel.sample(np.random.default_rng([4, k]), "tanker")
        rec = dataclasses.replace(rec, well_z0=-0.2, well_z1=0.1, floor=0.4, cargo="none", sheer=0.0,
                                  v_rise=0.0, depth=0.15)
        s = vessel.build(rec)
        y = vessel._well(rec)[2]
        assert not inside(s, 0.0, (y + rec.depth) / 2, -0.05), k
        assert inside(s, 0.0, y - 0.02, -0.05), k
    rec = dataclasses.replace(vessel.sample(np.random.default_rng([5, 0]), "rowboat"), thwarts=0, oars=0.0,
                              motor=False)
    s = vessel.build(rec)
    assert not inside(s, 0.0, rec.depth - 0.005, 0.1 - rec.stern_taper / 2)
