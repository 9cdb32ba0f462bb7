"""The chair generator: its parameter records cover every style and option and wide numeric ranges,
built objects are one connected solid with named parts and widely varied proportions, and the styles
differ in structure."""
from __future__ import annotations

import numpy as np
import pytest

from svr.data.procedural.categories import chair, make_shape

from .helpers import check_normalised_ratio_spread, check_seats_connected_with_named_parts, genus, records, values


def test_chair_sample_sweep_covers_options_and_ranges():
    recs = records(chair, seed=77)
    assert set(values(recs, "style")) == set(chair.STYLES)
    for name, options in (("seat", chair.SEATS), ("base", chair.BASES), ("leg", chair.LEGS),
                          ("back", chair.BACKS), ("arms", chair.ARMS), ("stretcher", chair.STRETCHERS)):
        assert set(values(recs, name)) == set(options), name
    assert len(set(values([r for r in recs if r.back in ("slats", "spindles", "ladder")], "n_back"))) >= 4
    assert set(values([r for r in recs if r.base == "star"], "spokes")) == {4, 5}
    for name, lo, hi in (("seat_h", 0.3, 0.6), ("back_h", 0.25, 0.5), ("back_tilt", 0.05, 0.3),
                         ("leg_t", 0.065, 0.09), ("seat_t", 0.07, 0.13), ("back_w", 0.65, 0.9)):
        v = np.array(values(recs, name))
        assert v.min() < lo and v.max() > hi, (name, v.min(), v.max())


def test_built_objects_are_one_connected_solid_with_named_parts():
    """Each object is one 26-connected solid on a 64^3 sample, with 2-8 named parts."""
    check_seats_connected_with_named_parts("chair")


@pytest.mark.parametrize("ratio,lo,hi", [
    ("height/width", 1.0, 1.8),  # a lounge chair is squat, a bar stool tall
    ("depth/width", 0.85, 1.2),
])
def test_normalised_proportions_span_a_wide_range(ratio, lo, hi):
    check_normalised_ratio_spread("chair", ratio, lo, hi)


def test_chair_styles_differ_in_structure():
    """Swivel chairs and pedestal stools stand on a central column where legged chairs have none;
    a bar stool's seat sits higher than a dining chair's; a cantilever frame leaves the floor
    under the back of the seat empty; a slatted back has holes."""
    def raw(style: str, k: int):
        rec = chair.sample(np.random.default_rng([80, k]), style)
        return rec, chair.build(rec)

    def column(style: str, k: int) -> bool:  # material all the way up the axis under the seat
        rec, shape = raw(style, k)
        ys = np.linspace(0.15, 0.85, 15) * rec.seat_h
        return bool((shape.sdf_numpy(np.stack([np.zeros_like(ys), ys, np.zeros_like(ys)], -1)) < 0).all())

    for k in range(4):
        assert column("swivel", k) and not column("four_legs", k) and not column("slatted", k)
        rec, cant = raw("cantilever", k)
        # nothing under the rear half of the seat between floor runners and seat rails
        pts = np.array([[x, y, z] for x in np.linspace(-rec.seat_w / 2, rec.seat_w / 2, 9)
                        for y in np.linspace(0.3, 0.7, 5) * rec.seat_h for z in np.linspace(0.1, 0.5, 5) * rec.seat_d])
        assert (cant.sdf_numpy(pts) > 0).all(), k
    # seat height over total height: bar stools sit high
    def seat_level(style: str, k: int) -> float:
        rec = chair.sample(np.random.default_rng([81, k]), style)
        return rec.seat_h / (rec.seat_h + rec.seat_t + rec.cushion_t + (rec.back_h if rec.back != "none" else 0))
    high = np.mean([seat_level("barstool", k) for k in range(20)])
    assert high > np.mean([seat_level("four_legs", k) for k in range(20)]) + 0.15
    assert genus(make_shape("chair", [80, 0], style="slatted")) >= 2
