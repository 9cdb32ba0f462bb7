"""The airplane, rifle and vessel generators: their parameter records cover every style and option
and wide ranges, their built objects span wide proportions, are one connected solid each and carry
named parts."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi

from svr.data.procedural.categories import airplane, make_shape, rifle, vessel

MODULES = {"airplane": airplane, "rifle": rifle, "vessel": vessel}


def _records(module, n: int = 200) -> list:
    return [module.sample(np.random.default_rng(k), module.STYLES[k % len(module.STYLES)]) for k in range(n)]


def _span(values) -> tuple[float, float]:
    return float(np.min(values)), float(np.max(values))


def test_airplane_parameter_sweep():
    recs = _records(airplane)
    assert {r.style for r in recs} == set(airplane.STYLES)
    assert {r.tail for r in recs} == set(airplane.TAILS)
    assert {r.engines for r in recs} == set(airplane.ENGINES)
    assert {len(r.engine_at) for r in recs if r.engines == "wing"} == {1, 2}
    ratio = [r.span / r.length for r in recs]
    assert _span(ratio)[0] < 0.5 and _span(ratio)[1] > 2.0
    assert _span([r.sweep for r in recs]) < (0.0, 0.9) and max(r.sweep for r in recs) > 0.9
    assert _span([r.tip_chord / r.root_chord for r in recs])[0] < 0.25
    assert _span([r.dihedral for r in recs])[0] < -0.05 and _span([r.dihedral for r in recs])[1] > 0.12
    assert _span([r.wing_y for r in recs])[0] < -0.8 and _span([r.wing_y for r in recs])[1] > 0.8
    for flag in ("intakes", "struts"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    assert 0 < sum(r.gear > 0 for r in recs) < len(recs) and 0 < sum(r.canopy > 0 for r in recs) < len(recs)
    assert max(max(r.length, r.span) for r in recs) <= 1.0 + 1e-9


def test_rifle_parameter_sweep():
    recs = _records(rifle)
    assert {r.style for r in recs} == set(rifle.STYLES)
    for field, options in (("stock", rifle.STOCKS), ("magazine", rifle.MAGAZINES), ("fore", rifle.FORE_ENDS),
                           ("sight", rifle.SIGHTS), ("muzzle", rifle.MUZZLES)):
        assert {getattr(r, field) for r in recs} == set(options), field
    for flag in ("double", "grip", "bolt", "foregrip"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    assert _span([r.recv_z for r in recs])[0] < -0.2 and _span([r.recv_z for r in recs])[1] > 0.1
    assert _span([r.stock_h for r in recs])[0] < 0.1 and _span([r.stock_h for r in recs])[1] > 0.22
    assert _span([r.mag_len for r in recs])[0] < 0.06 and _span([r.mag_len for r in recs])[1] > 0.25
    assert _span([r.barrel_r for r in recs])[1] > 0.04  # heavy barrels
    assert 0 < sum(r.bipod > 0 for r in recs) < len(recs)


def test_vessel_parameter_sweep():
    recs = _records(vessel)
    assert {r.style for r in recs} == set(vessel.STYLES)
    assert {r.cargo for r in recs} == set(vessel.CARGO)
    assert {len(r.tiers) for r in recs if r.style == "ship"} == {1, 2, 3, 4}
    assert {len(r.funnels) for r in recs} == {0, 1, 2}
    assert {len(r.masts) for r in recs} == {0, 1, 2}
    assert {r.thwarts for r in recs if r.style == "rowboat"} >= {1, 2, 3, 4}
    for flag in ("jib", "motor"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    assert 0 < sum(r.oars > 0 for r in recs) and 0 < sum(r.sheer > 0 for r in recs) < len(recs)
    assert _span([r.beam for r in recs])[0] < 0.1 and _span([r.beam for r in recs])[1] > 0.4
    assert _span([r.bow for r in recs])[0] < 0.1 and _span([r.bow for r in recs])[1] > 0.4


# normalised bounding-box extents (x, y, z) that 30 objects reach at least, low and high
EXTENTS = {"airplane": ((0.6, 0.2, 0.6), (0.95, 0.33, 0.95)),
           "rifle": ((0.12, 0.25, 1.0), (0.15, 0.45, 1.0)),
           "vessel": ((0.25, 0.25, 1.0), (0.35, 0.5, 1.0))}


@pytest.mark.parametrize("name", MODULES)
def test_proportions_span_a_wide_range(name):
    ext = np.array([np.subtract(*make_shape(name, [21, k]).bounds[::-1]) for k in range(30)])
    low, high = EXTENTS[name]
    assert (ext.min(0) <= np.array(low) + 1e-6).all() and (ext.max(0) >= np.array(high) - 1e-6).all(), \
        (ext.min(0), ext.max(0))


@pytest.mark.parametrize("name", MODULES)
def test_objects_are_one_connected_solid_with_named_parts(name):
    ax = np.linspace(-0.55, 0.55, 64)
    grid = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)
    for style in MODULES[name].STYLES:
        for k in range(2):
            shape = make_shape(name, [22, k], style=style)
            assert ndi.label(shape.sdf_numpy(grid) < 0, np.ones((3, 3, 3)))[1] == 1, (style, k)
            assert 2 <= len(shape.parts) <= 8, (style, shape.parts)


def test_vessel_styles_with_and_without_superstructure():
    for k in range(3):
        row = make_shape("vessel", [13, k], style="rowboat")
        ship = make_shape("vessel", [13, k], style="ship")
        assert (row.bounds[1] - row.bounds[0])[1] < 0.32  # the bare hull (oars reach below it)
        assert (ship.bounds[1] - ship.bounds[0])[1] > 0.25  # deckhouse, funnels, masts


def test_build_is_deterministic_and_draws_nothing():
    for name, module in MODULES.items():
        rec = module.sample(np.random.default_rng(5), module.STYLES[0])
        a, b = module.build(rec), module.build(rec)
        np.testing.assert_array_equal(a.program, b.program)
