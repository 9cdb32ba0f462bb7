"""The car generator: its parameter records cover every style and option and wide ranges, its built
objects spread in proportion, are one connected solid each with named parts, the structure tells the
styles apart, the wing and roll bar make holes, and the open cabin and the hollow under the floor
are empty."""
from __future__ import annotations

import dataclasses

import numpy as np

from svr.data.procedural.categories import car, make_shape
from svr.data.procedural.csg import CSGShape

from .helpers import components, extent, genus, inside, records, span, values


def _top_at(shape: CSGShape, x: float, z: float) -> float:
    ys = np.linspace(-0.6, 0.6, 481)
    inside = shape.sdf_numpy(np.stack([np.full_like(ys, x), ys, np.full_like(ys, z)], -1)) < 0
    return float(ys[inside].max()) if inside.any() else -np.inf


def _world(shape: CSGShape, q) -> np.ndarray:
    """A point of the raw (program) frame in the normalised shape's world frame."""
    return (np.asarray(q, float) - np.asarray(shape.offset)) * shape.scale


def _top_over(shape: CSGShape, x: float, z: float) -> float:
    """The highest world y of material over the raw point (x, z)."""
    p = _world(shape, (x, 0.0, z))
    return _top_at(shape, p[0], p[2])


def test_car_sample_sweep_covers_styles_options_and_ranges():
    recs = records(car, seed=31)
    assert {r.style for r in recs} == set(car.STYLES)
    assert {r.cargo for r in recs} == {"none", "bed", "cockpit", "box", "open", "tank", "flat"}
    assert {r.roof for r in recs} == {"none", "rack", "pod"}
    assert {r.spoiler for r in recs} == {"none", "lip", "wing"}
    assert {r.rear_axles for r in recs} == {1, 2}
    for flag in ("spare", "bullbar", "rollbar", "canopy"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    span = lambda name: (min(getattr(r, name) for r in recs), max(getattr(r, name) for r in recs))  # noqa: E731
    assert span("width")[0] < 0.33 and span("width")[1] > 0.6
    assert span("wheel_r")[0] < 0.055 and span("wheel_r")[1] > 0.14
    assert span("cab_h")[0] < 0.08 and span("cab_h")[1] > 0.4
    assert span("wheel_out")[1] > 0.05 and span("clearance")[1] > 0.15
    rows = [len(car.build(r).program) for r in recs[:60]]
    assert 8 <= min(rows) and max(rows) <= 30 and len(set(rows)) >= 5


def test_car_proportions_spread_and_objects_are_connected_and_labelled():
    ext = []
    for k in range(30):
        shape = make_shape("car", [32, k])
        ext.append(extent(shape))
        assert len(shape.parts) >= 3 and {"body", "wheels"} <= set(shape.parts)
        if k < 12:
            assert components(shape) == 1, k
    ext = np.array(ext)
    assert np.allclose(ext[:, 2], 1.0, atol=0.03)  # the length is the longest side
    assert ext[:, 0].min() < 0.4 and ext[:, 0].max() > 0.55  # width over length
    assert ext[:, 1].min() < 0.4 and ext[:, 1].max() > 0.6  # height over length


def test_car_styles_differ_in_structure():
    """All stand on wheels, not on the body; a sedan's boot is lower than its roof, a van's roof runs
    to the tail, a pickup's bed is open (lower between its walls), a truck's load is taller than
    its chassis, and an open car has no roof over its seats."""
    for k in range(3):
        rec = {s: car.sample(np.random.default_rng([12, k]), s) for s in car.STYLES}
        shapes = {s: car.build(dataclasses.replace(r, spoiler="none", canopy=False, rollbar=False, roof="none"))
                  .normalized() for s, r in rec.items()}
        for style, shape in shapes.items():
            lo, hi = shape.bounds
            assert not inside(shape, 0.0, lo[1] + 0.01, 0.0), style  # clearance under the body
        s, r = shapes["sedan"], rec["sedan"]
        if r.cargo == "none":
            assert _top_over(s, 0.0, 0.47) < s.bounds[1][1] - 0.05
        v = shapes["van"]
        assert _top_over(v, 0.0, 0.3) > v.bounds[1][1] - 0.08
        b, r = shapes["pickup"], rec["pickup"]
        z = (r.cargo_z0 + 0.44) / 2
        assert _top_over(b, 0.0, z) < _top_over(b, r.width / 2 - 0.03, z) - 0.03  # a well between walls
        t, r = shapes["truck"], rec["truck"]
        assert _top_over(t, 0.0, (r.cargo_z0 + 0.5) / 2) > t.bounds[0][1] + 0.3
        o, r = shapes["open"], rec["open"]
        assert _top_over(o, 0.0, r.cab_z1 - 0.04) < o.bounds[1][1] - 0.05


def test_car_wing_and_roll_bar_make_holes():
    rec = dataclasses.replace(car.sample(np.random.default_rng([6, 0]), "sedan"), spoiler="wing", spoiler_h=0.09,
                              cargo="none")
    assert genus(car.build(rec).normalized()) >= 1


def test_car_sample_sweep_covers_new_options_and_ranges():
    recs = records(car, 240, seed=47)
    for flag in ("open_cab", "shell"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    assert not any(r.open_cab for r in recs if r.cargo == "cockpit")
    assert {r.under > 0 for r in recs} == {False, True}
    for name, lo, hi in (("wall", 0.065, 0.11), ("pillar", 0.065, 0.09), ("skirt", 0.07, 0.14),
                         ("sink", 0.05, 0.2), ("width", 0.3, 0.62), ("cab_h", 0.08, 0.45)):
        a, b = span(values(recs, name))
        assert a < lo and b > hi, (name, a, b)
    assert min(r.well for r in recs if r.cargo == "bed") < 0.08 and max(r.well for r in recs if r.cargo == "bed") > 0.17


def test_car_open_cabin_and_hollow_under_the_floor():
    """An open cabin is empty inside between its pillars; the hollow under the floor is empty above
    the body's bottom, inside the skirts, and the skirts are solid."""
    for k in range(4):
        rec = car.sample(np.random.default_rng([6, k]), "van")
        rec = dataclasses.replace(rec, open_cab=True, under=0.0, roof="none", cab_z0=-0.3, cab_z1=0.45, cab_h=0.3,
                                  pillar=0.06, screen_run=0.1, rear_run=0.05, sink=0.0)
        s = car.build(rec)
        lo, hi = s.measure_bounds()
        top = hi[1]
        assert not inside(s, 0.0, top - 0.12, 0.1), k
        rec = dataclasses.replace(rec, open_cab=False, under=1.0, skirt=0.07, nose_drop=0.0, tail_drop=0.0,
                                  body_round=0.01)
        s = car.build(rec)
        assert not inside(s, 0.0, rec.clearance + 0.02, 0.0), k
        assert inside(s, rec.width / 2 - 0.035, rec.clearance + 0.02, 0.0), k


def test_car_objects_are_connected_and_labelled():
    for k in range(12):
        shape = make_shape("car", [49, k])
        assert {"body", "wheels"} <= set(shape.parts), k
        assert components(shape) == 1, k
