"""The table generator: parameter records, the ranges its sweep covers, proportions, connectedness,
named parts and the structure of its styles."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svr.data.procedural.categories import make_shape, table

from .helpers import components, extent, genus, records_of_one_stream


def test_table_sweep_covers_every_option_and_wide_ranges():
    recs = records_of_one_stream(table)
    assert {r.style for r in recs} == set(table.STYLES)
    assert {r.top for r in recs} == set(table.TOPS)
    assert {r.leg for r in recs} == set(table.LEGS)
    assert {r.stretcher for r in recs if r.style in ("legs", "trestle")} == set(table.STRETCHERS)
    assert {r.stretcher for r in recs if r.style == "splayed"} == {"none", "ring", "shelf", "cross"}
    assert {r.base for r in recs if r.style == "pedestal"} == set(table.PEDESTAL_BASES)
    assert {r.base for r in recs if r.style == "trestle"} == set(table.ENDS)
    assert {r.column for r in recs} == set(table.COLUMNS)
    assert {r.legs_n for r in recs} == {3, 4, 5} and {r.shelves for r in recs if r.style == "lower_shelf"} == {1, 2}
    assert {r.columns for r in recs if r.style == "pedestal"} == {1, 2}
    assert {r.drawers for r in recs} == {1, 2, 3, 4} and {r.pedestals for r in recs} == {1, 2}
    ratios = np.array([r.height / r.width for r in recs])
    assert ratios.min() < 0.35 and ratios.max() > 1.05
    assert min(r.depth / r.width for r in recs) < 0.45
    thick = np.array([r.top_thick for r in recs])
    assert thick.min() < 0.06 and thick.max() > 0.1
    assert any(r.apron == 0 for r in recs) and max(r.apron for r in recs) > 0.14
    for r in recs:
        assert min(r.top_thick, r.leg_thick, r.bar_thick, r.shelf_thick, r.base_thick) >= 0.055
        assert max(r.width, r.depth, r.height) <= 1.0 + 1e-9


def test_table_proportions_span_a_wide_range():
    """Over 30 objects the normalised height runs from a coffee table's to a bar table's, the depth
    from a narrow trestle's to a square top's."""
    ext = np.array([extent(make_shape("table", [30, k])) for k in range(30)])
    assert ext[:, 1].min() < 0.45 and ext[:, 1].max() > 0.9
    assert ext[:, 2].min() < 0.55 and ext[:, 2].max() > 0.95


@pytest.mark.parametrize("style", table.STYLES)
def test_tables_are_one_solid_with_named_parts(style):
    for k in range(3):
        shape = make_shape("table", [31, k], style=style)
        assert components(shape) == 1, (style, k)
        assert 2 <= len(shape.parts) <= 8 and "top" in shape.parts, shape.parts


def test_table_styles_differ_in_structure():
    """A round top leaves the corners of its box empty; a pedestal puts a column on the axis where
    four legs leave it empty; a lower shelf or stretchers make holes; a desk's drawers are recesses
    in its front."""
    rng = np.random.default_rng(5)

    def shape(style, **kw):
        return table.build(dataclasses.replace(table.sample(rng, style), **kw)).normalized()

    def inside(s, x, y, z):
        return bool(s.sdf_numpy(np.array([[x, y, z]]))[0] < 0)

    for _ in range(3):
        round_top = shape("pedestal", top="round", columns=1)
        lo, hi = round_top.bounds
        assert not inside(round_top, 0.9 * hi[0], hi[1] - 0.02, 0.9 * hi[2])  # the corner
        assert inside(round_top, 0.0, lo[1] + 0.5 * (hi[1] - lo[1]), 0.0)  # the column
        legs = shape("legs", top="rect", stretcher="none", apron=0.0)
        lo, hi = legs.bounds
        assert inside(legs, 0.95 * hi[0], hi[1] - 0.01, 0.95 * hi[2])
        assert not inside(legs, 0.0, lo[1] + 0.5 * (hi[1] - lo[1]), 0.0)
    assert genus(shape("lower_shelf", top="rect", leg="square")) >= 1
    assert genus(shape("legs", top="rect", stretcher="box", leg="square")) >= 1
    desk = shape("desk", drawers=2)
    assert "drawers" in desk.parts
