"""The bench generator: its parameter records cover every style and option and wide numeric ranges,
and built objects are one connected solid with named parts and widely varied proportions (the holes
between a park bench's slats: test_sofa.py, test_categories.py)."""
from __future__ import annotations

import numpy as np
import pytest

from svr.data.procedural.categories import bench

from .helpers import check_normalised_ratio_spread, check_seats_connected_with_named_parts, records, values


def test_bench_sample_sweep_covers_options_and_ranges():
    recs = records(bench, seed=77)
    assert set(values(recs, "style")) == set(bench.STYLES)
    for name, options in (("support", bench.SUPPORTS), ("leg", bench.LEGS), ("back", bench.BACKS),
                          ("arms", bench.ARMS), ("cut", bench.CUTS)):
        assert set(values(recs, name)) == set(options), name
    assert set(values(recs, "slats")) == {0, 2, 3, 4, 5}
    assert set(values(recs, "n_supports")) == {2, 3}
    assert set(values(recs, "back_n")) == {1, 2, 3, 4}
    for name, lo, hi in (("depth", 0.25, 0.4), ("seat_h", 0.3, 0.45), ("back_h", 0.18, 0.36),
                         ("inset", 0.03, 0.15), ("leg_t", 0.065, 0.1)):
        v = np.array(values(recs, name))
        assert v.min() < lo and v.max() > hi, (name, v.min(), v.max())


def test_built_objects_are_one_connected_solid_with_named_parts():
    """Each object is one 26-connected solid on a 64^3 sample, with 2-8 named parts."""
    check_seats_connected_with_named_parts("bench")


@pytest.mark.parametrize("ratio,lo,hi", [
    ("height/width", 0.45, 0.75),  # low backless benches, tall backed ones
    ("depth/width", 0.3, 0.45),
])
def test_normalised_proportions_span_a_wide_range(ratio, lo, hi):
    check_normalised_ratio_spread("bench", ratio, lo, hi)


