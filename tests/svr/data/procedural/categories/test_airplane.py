"""The airplane generator: its parameter records cover every style and option and wide ranges, its
built objects span wide proportions, are one connected solid each and carry named parts."""
from __future__ import annotations


from svr.data.procedural.categories import airplane

from .helpers import check_every_style_connected_with_named_parts, check_extents_reach, records, span


def test_airplane_parameter_sweep():
    recs = records(airplane)
    assert {r.style for r in recs} == set(airplane.STYLES)
    assert {r.tail for r in recs} == set(airplane.TAILS)
    assert {r.engines for r in recs} == set(airplane.ENGINES)
    assert {len(r.engine_at) for r in recs if r.engines == "wing"} == {1, 2}
    ratio = [r.span / r.length for r in recs]
    assert span(ratio)[0] < 0.5 and span(ratio)[1] > 2.0
    assert span([r.sweep for r in recs]) < (0.0, 0.9) and max(r.sweep for r in recs) > 0.9
    assert span([r.tip_chord / r.root_chord for r in recs])[0] < 0.25
    assert span([r.dihedral for r in recs])[0] < -0.05 and span([r.dihedral for r in recs])[1] > 0.12
    assert span([r.wing_y for r in recs])[0] < -0.8 and span([r.wing_y for r in recs])[1] > 0.8
    for flag in ("intakes", "struts"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    assert 0 < sum(r.gear > 0 for r in recs) < len(recs) and 0 < sum(r.canopy > 0 for r in recs) < len(recs)
    assert max(max(r.length, r.span) for r in recs) <= 1.0 + 1e-9


def test_proportions_span_a_wide_range():
    check_extents_reach("airplane", (0.6, 0.2, 0.6), (0.95, 0.33, 0.95))


def test_objects_are_one_connected_solid_with_named_parts():
    check_every_style_connected_with_named_parts("airplane", airplane)


