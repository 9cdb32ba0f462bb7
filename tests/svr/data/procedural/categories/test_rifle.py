"""The rifle generator: its parameter records cover every style and option (stocks, slings, bipods)
and wide ranges of thicknesses, angles and lengths, its built objects span wide proportions, are one
connected solid each with named parts, and its open stocks and slings make holes."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svr.data.procedural.categories import rifle

from .helpers import (check_every_style_connected_with_named_parts, check_extents_reach, checked_extents, genus,
                      records, span)


def test_rifle_parameter_sweep():
    recs = records(rifle)
    assert {r.style for r in recs} == set(rifle.STYLES)
    for field, options in (("stock", rifle.STOCKS), ("magazine", rifle.MAGAZINES), ("fore", rifle.FORE_ENDS),
                           ("sight", rifle.SIGHTS), ("muzzle", rifle.MUZZLES)):
        assert {getattr(r, field) for r in recs} == set(options), field
    for flag in ("double", "grip", "bolt", "foregrip"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    assert span([r.recv_z for r in recs])[0] < -0.2 and span([r.recv_z for r in recs])[1] > 0.1
    assert span([r.stock_h for r in recs])[0] < 0.1 and span([r.stock_h for r in recs])[1] > 0.22
    assert span([r.mag_len for r in recs])[0] < 0.06 and span([r.mag_len for r in recs])[1] > 0.25
    assert span([r.barrel_r for r in recs])[1] > 0.04  # heavy barrels
    assert 0 < sum(r.bipod > 0 for r in recs) < len(recs)


def test_proportions_span_a_wide_range():
    check_extents_reach("rifle", (0.12, 0.25, 1.0), (0.15, 0.45, 1.0))


def test_objects_are_one_connected_solid_with_named_parts():
    check_every_style_connected_with_named_parts("rifle", rifle)


def test_rifle_sweep_covers_stocks_slings_bipods_and_widths():
    recs = records(rifle, 240, seed=41)
    assert {r.style for r in recs} == set(rifle.STYLES)
    assert {r.stock for r in recs} == set(rifle.STOCKS)
    assert 0 < sum(r.sling > 0 for r in recs) < len(recs)
    assert 0 < sum(r.comb > 0 for r in recs) < len(recs)
    bipods = [r for r in recs if r.bipod > 0]
    assert any(r.bipod_angle > 1.3 for r in bipods) and any(r.bipod_angle < 0.0 for r in bipods)  # folded, open
    for field, lo, hi in (("stock_w", 0.032, 0.07), ("fore_w", 0.032, 0.065), ("mag_w", 0.032, 0.055),
                          ("half_w", 0.032, 0.063), ("grip_t", 0.032, 0.045), ("scope_r", 0.04, 0.065),
                          ("muzzle_r", 0.016, 0.035), ("fore_h", 0.03, 0.08)):
        a, b = span([getattr(r, field) for r in recs])
        assert a < lo and b > hi, (field, a, b)
    assert span([r.barrel_r for r in recs])[1] > 0.055  # heavy barrels


def test_rifle_objects_are_connected_labelled_and_spread():
    ext = checked_extents("rifle", rifle.STYLES, 44, 30)
    assert np.allclose(ext[:, 2], 1.0, atol=1e-3)  # long along z
    assert ext[:, 1].min() < 0.25 and ext[:, 1].max() > 0.45
    assert ext[:, 0].min() < 0.11 and ext[:, 0].max() > 0.15


@pytest.mark.parametrize("stock", ["hollow", "skeleton"])
def test_rifle_open_stocks_and_slings_make_holes(stock):
    rec = rifle.sample(np.random.default_rng([3, 0]), "hunting")
    rec = dataclasses.replace(rec, stock=stock, recv_z=-0.2, recv_len=0.15, wrist=0.08, stock_h=0.28, stock_drop=0.0, hole_len=0.7, hole_h=0.6, sling=0.0,
                              sight="none", bipod=0.0, magazine="none", grip=False)
    base = genus(rifle.build(dataclasses.replace(rec, stock="solid")).normalized())
    assert genus(rifle.build(rec).normalized()) > base
    slung = genus(rifle.build(dataclasses.replace(rec, stock="solid", sling=0.1)).normalized())
    assert slung > base
