"""The sofa generator: its parameter records cover every style and option and wide numeric ranges,
built objects are one connected solid with named parts and widely varied proportions, and the styles
differ in structure (one test with the park bench, whose slats make holes)."""
from __future__ import annotations

import numpy as np
import pytest

from svr.data.procedural.categories import make_shape, sofa

from .helpers import (check_normalised_ratio_spread, check_seats_connected_with_named_parts, genus, inside, records,
                      values)


def test_sofa_sample_sweep_covers_options_and_ranges():
    recs = records(sofa, seed=77)
    assert set(values(recs, "style")) == set(sofa.STYLES)
    for name, options in (("leg", sofa.LEGS), ("back", sofa.BACKS), ("arm", sofa.ARMS)):
        assert set(values(recs, name)) == set(options), name
    assert set(values(recs, "n_seats")) == {1, 2, 3, 4}
    assert set(values(recs, "n_backs")) == {0, 1, 2, 3}
    assert set(values(recs, "legs_per_side")) == {2, 3}
    assert {len(r.arm_sides) for r in recs} == {0, 1, 2}
    sectional = [r for r in recs if r.style == "sectional"]
    assert {r.u_shape for r in sectional} == {True, False} and {r.corner for r in sectional} == {True, False}
    curve = np.array([r.curve for r in recs if r.style == "curved"])
    assert curve.min() < -0.2 and curve.max() > 0.3
    for name, lo, hi in (("width", 0.65, 0.95), ("depth", 0.35, 0.55), ("back_h", 0.18, 0.36),
                         ("arm_w", 0.08, 0.18), ("base_h", 0.1, 0.2), ("back_tilt", 0.05, 0.25)):
        v = np.array(values(recs, name))
        assert v.min() < lo and v.max() > hi, (name, v.min(), v.max())


def test_built_objects_are_one_connected_solid_with_named_parts():
    """Each object is one 26-connected solid on a 64^3 sample, with 2-8 named parts."""
    check_seats_connected_with_named_parts("sofa")


@pytest.mark.parametrize("ratio,lo,hi", [
    ("height/width", 0.45, 0.85),  # a long low daybed, a tall short loveseat
    ("depth/width", 0.5, 0.85),
])
def test_normalised_proportions_span_a_wide_range(ratio, lo, hi):
    check_normalised_ratio_spread("sofa", ratio, lo, hi)


def test_sofa_and_bench_structure():
    """A sectional's chaise reaches forward on one side (an L) or both (a U); a curved sofa's
    corners are empty where a straight one's are full; a park bench has holes between its slats."""
    for k in range(6):
        rec = sofa.sample(np.random.default_rng([82, k]), "sectional")
        shape = sofa.build(rec)
        y = rec.leg_h + rec.base_h / 2
        z = -rec.depth / 2 - rec.chaise_len + 0.03
        ahead = [inside(shape, sx * 0.45 * rec.width, y, z) for sx in (-1, 1)]
        assert ahead == ([True, True] if rec.u_shape else [rec.chaise_side < 0, rec.chaise_side > 0]), k
    for k in range(3):
        rec = sofa.sample(np.random.default_rng([83, k]), "curved")
        shape = sofa.build(rec)
        r, y = rec.width / 2, rec.leg_h + rec.base_h / 2
        assert inside(shape, 0.0, y, 0.5 * r) and not inside(shape, 0.95 * r, y, 0.95 * r)
    assert genus(make_shape("bench", [82, 0], style="park")) >= 1
