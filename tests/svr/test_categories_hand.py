"""The phone and rifle generators, second round: their parameter sweeps (every style and option turns
up, thicknesses, angles and lengths cover wide ranges), the spread of the built objects' proportions,
one connected solid per object with named parts, and the holes of the new part shapes."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from svr.data.procedural.categories import make_shape, phone, rifle
from svr.data.procedural.generator import voxelize_shape

from .test_categories import _genus

SEEDS = 240


def _records(module, n: int = SEEDS) -> list:
    return [module.sample(np.random.default_rng([41, k]), module.STYLES[k % len(module.STYLES)]) for k in range(n)]


def _span(values) -> tuple[float, float]:
    return float(np.min(values)), float(np.max(values))


def _extent(shape) -> np.ndarray:
    lo, hi = shape.bounds
    return np.asarray(hi) - np.asarray(lo)


def _components(shape) -> int:
    return int(ndimage.label(voxelize_shape(shape, rule="protocol"), structure=np.ones((3, 3, 3)))[1])


# ---------------------------------------------------------------------------------------- phone


def test_phone_sweep_covers_styles_options_and_wide_ranges():
    recs = _records(phone)
    assert {r.style for r in recs} == set(phone.STYLES)
    assert {r.stand for r in recs} == {"none", "dock", "easel"}
    assert {r.camera for r in recs} == {"none", "square", "round", "strip"}
    for flag in ("button", "antenna", "sideways", "display", "cord", "dock_round"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    hand = [r for r in recs if r.style != "desk"]
    lo, hi = _span([r.thick for r in hand])
    assert lo < 0.075 and hi > 0.22 and hi / lo > 3  # slab thickness: a thin smartphone to a brick
    lo, hi = _span([r.lid_thick for r in recs])
    assert lo < 0.065 and hi > 0.14
    lo, hi = _span([r.lean for r in hand])  # upright, tilted, leaning in a dock or on a strut
    assert lo < 0.02 and hi > 0.6
    assert _span([r.lean for r in hand if r.stand == "none"])[1] > 0.25
    flips = [r.opening for r in recs if r.style == "flip"]
    assert 0.0 in flips and min(f for f in flips if f > 0) < 1.0 and max(flips) > 3.0
    assert len({round(f, 3) for f in flips}) > 10  # open at any angle
    batteries = [r.battery for r in recs if r.style in ("slab", "candybar")]
    assert 0.0 in batteries and max(batteries) > 0.12
    assert 0 < sum(r.dock_back > 0 for r in recs if r.stand == "dock") < sum(r.stand == "dock" for r in recs)
    handsets = [r for r in recs if r.style == "handset"]
    assert _span([r.bend for r in handsets])[0] < 0.05 and _span([r.bend for r in handsets])[1] > 0.4
    assert _span([r.ear_thick for r in handsets])[1] / _span([r.ear_thick for r in handsets])[0] > 2.5
    assert _span([r.strut_t for r in recs])[1] > 0.1
    desks = [r for r in recs if r.style == "desk"]
    assert _span([r.thick for r in desks])[0] < 0.08 and _span([r.thick for r in desks])[1] > 0.3


def _checked_extents(name: str, styles, seed: int, count: int) -> np.ndarray:
    """Builds ``count`` objects cycling through the styles, checks that each has 2-8 parts and the
    first half one connected solid each; returns their (count, 3) extents."""
    ext = []
    for k in range(count):
        shape = make_shape(name, [seed, k], style=styles[k % len(styles)])
        ext.append(_extent(shape))
        assert 2 <= len(shape.parts) <= 8, shape.parts
        if k < count // 2:
            assert _components(shape) == 1, k
    return np.array(ext)


def test_phone_proportions_spread_and_objects_are_connected_and_labelled():
    ext = _checked_extents("phone", phone.STYLES, 43, 36)
    assert ext[:, 2].min() < 0.25 and ext[:, 2].max() > 0.6  # depth: thin upright slabs to leaning and desk phones
    assert ext[:, 0].min() < 0.35 and ext[:, 0].max() > 0.9  # width: a narrow handset to a desk phone


def test_phone_handset_bends_and_flip_opens_at_any_angle():
    rec = phone.sample(np.random.default_rng([5, 1]), "handset")
    straight = phone.build(dataclasses.replace(rec, bend=0.0, stand="none", lean=0.0, antenna=False)).normalized()
    bent = phone.build(dataclasses.replace(rec, bend=0.45, stand="none", lean=0.0, antenna=False)).normalized()
    assert _extent(bent)[2] > _extent(straight)[2] * 1.3  # the ear end leans out to the front
    rec = phone.sample(np.random.default_rng([5, 2]), "flip")
    depths = [_extent(phone.build(dataclasses.replace(rec, opening=a, stand="none", lean=0.0)).normalized())[2]
              for a in (0.0, 1.2, np.pi)]
    assert depths[1] > depths[0] and depths[1] > depths[2]  # half open: a V seen from the side


# ---------------------------------------------------------------------------------------- rifle


def test_rifle_sweep_covers_stocks_slings_bipods_and_widths():
    recs = _records(rifle)
    assert {r.style for r in recs} == set(rifle.STYLES)
    assert {r.stock for r in recs} == set(rifle.STOCKS)
    assert 0 < sum(r.sling > 0 for r in recs) < len(recs)
    assert 0 < sum(r.comb > 0 for r in recs) < len(recs)
    bipods = [r for r in recs if r.bipod > 0]
    assert any(r.bipod_angle > 1.3 for r in bipods) and any(r.bipod_angle < 0.0 for r in bipods)  # folded, open
    for field, lo, hi in (("stock_w", 0.032, 0.07), ("fore_w", 0.032, 0.065), ("mag_w", 0.032, 0.055),
                          ("half_w", 0.032, 0.063), ("grip_t", 0.032, 0.045), ("scope_r", 0.04, 0.065),
                          ("muzzle_r", 0.016, 0.035), ("fore_h", 0.03, 0.08)):
        a, b = _span([getattr(r, field) for r in recs])
        assert a < lo and b > hi, (field, a, b)
    assert _span([r.barrel_r for r in recs])[1] > 0.055  # heavy barrels


def test_rifle_objects_are_connected_labelled_and_spread():
    ext = _checked_extents("rifle", rifle.STYLES, 44, 30)
    assert np.allclose(ext[:, 2], 1.0, atol=1e-3)  # long along z
    assert ext[:, 1].min() < 0.25 and ext[:, 1].max() > 0.45
    assert ext[:, 0].min() < 0.11 and ext[:, 0].max() > 0.15


@pytest.mark.parametrize("stock", ["hollow", "skeleton"])
def test_rifle_open_stocks_and_slings_make_holes(stock):
    rec = rifle.sample(np.random.default_rng([3, 0]), "hunting")
    rec = dataclasses.replace(rec, stock=stock, recv_z=-0.2, recv_len=0.15, wrist=0.08, stock_h=0.28, stock_drop=0.0, hole_len=0.7, hole_h=0.6, sling=0.0,
                              sight="none", bipod=0.0, magazine="none", grip=False)
    base = _genus(rifle.build(dataclasses.replace(rec, stock="solid")).normalized())
    assert _genus(rifle.build(rec).normalized()) > base
    slung = _genus(rifle.build(dataclasses.replace(rec, stock="solid", sling=0.1)).normalized())
    assert slung > base


def test_phone_styles_differ_in_structure():
    """(Moved from test_categories_car.py.) A closed flip phone is short and thick, an open one tall;
    a desk phone with its handset lying in the cradle is wider than tall."""
    for k in range(3):
        rec = phone.sample(np.random.default_rng([7, k]), "flip")
        closed = phone.build(dataclasses.replace(rec, opening=0.0, stand="none", lean=0.0)).normalized()
        opened = phone.build(dataclasses.replace(rec, opening=np.pi, stand="none", lean=0.0)).normalized()
        assert _extent(closed)[1] / _extent(closed)[2] < _extent(opened)[1] / _extent(opened)[2] / 1.5
        rec = phone.sample(np.random.default_rng([7, k]), "desk")
        desk = phone.build(dataclasses.replace(rec, layout="across", thick=0.15)).normalized()
        assert _extent(desk)[1] < _extent(desk)[0]
