"""The cabinet generator: frozen parameter records built deterministically, sweeps that draw every
style, base, handle and cell kind (open doors, pulled-out drawers, open cells of drawn depth) over wide
ranges, proportions, one labelled solid per object, and the through-holes of open-backed shelves
(and of a monitor neck's cable cut-out)."""
from __future__ import annotations

import dataclasses

import numpy as np

from svr.data.procedural.categories import cabinet, display

from .helpers import (check_every_style_builds_one_labelled_solid, check_one_solid_with_parts, check_ratio_spreads,
                      check_records_frozen_and_build_deterministic, genus, records)


def test_records_are_frozen_and_build_is_deterministic():
    check_records_frozen_and_build_deterministic(cabinet)


def test_cabinet_sweep():
    recs = records(cabinet)
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


def test_proportions_span_a_wide_range():
    check_ratio_spreads("cabinet", 1.5, 0.5)


def test_objects_are_one_solid_with_parts():
    check_one_solid_with_parts("cabinet")


def test_holes_where_cabinets_and_displays_have_them():
    """Open-backed shelves are through-holes, and so is a monitor neck's cable cut-out."""
    open_back = [k for k in range(40) if cabinet.sample(np.random.default_rng(k), "open_shelves").back == 0]
    p = cabinet.sample(np.random.default_rng(open_back[0]), "open_shelves")
    assert genus(cabinet.build(p).normalized()) >= 1
    p = dataclasses.replace(display.sample(np.random.default_rng(1), "monitor"), arm=1.0, neck_width=0.18)
    assert genus(display.build(p).normalized()) >= 1


def test_cabinet_open_doors_pulled_drawers_and_cell_depths_are_drawn():
    recs = records(cabinet, seed=31)
    kinds = [kind for r in recs for s in r.sections for t in s.tiers for kind, _ in t.cells]
    assert set(kinds) == set(cabinet.CELL_KINDS)
    assert kinds.count("ajar") >= 10 and kinds.count("pulled") >= 10
    depths = [t.depth for r in recs for s in r.sections for t in s.tiers]
    assert min(depths) < 0.4 and any(d == 1.0 for d in depths)
    angles = [r.door_angle for r in recs]
    assert min(angles) < 0.5 and max(angles) > 1.7
    assert np.ptp([r.pull for r in recs]) > 0.4
    fr = [r.front_recess / r.depth for r in recs if r.front_recess > 0]
    assert len(fr) > 40 and max(fr) > 0.3
    assert np.ptp([r.panel for r in recs]) > 0.06


def test_every_style_builds_one_labelled_solid():
    check_every_style_builds_one_labelled_solid(cabinet)


