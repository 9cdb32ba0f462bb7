"""The speaker generator: frozen parameter records built deterministically, sweeps that draw every
style, profile, base, form and port and the hidden depths (recessed baffles, open backs, hollows
underneath), proportions, and one labelled solid of a few tens of rows per object."""
from __future__ import annotations


import numpy as np

from svr.data.procedural.categories import speaker

from .helpers import (check_every_style_builds_one_labelled_solid, check_one_solid_with_parts, check_ratio_spreads,
                      check_records_frozen_and_build_deterministic, records)


def test_records_are_frozen_and_build_is_deterministic():
    check_records_frozen_and_build_deterministic(speaker)


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
    check_ratio_spreads("speaker", 1.5, 0.8)


def test_objects_are_one_solid_with_parts():
    check_one_solid_with_parts("speaker")


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
    check_every_style_builds_one_labelled_solid(speaker)


