"""The car and phone generators: their parameter sweeps (every style and option turns up, ranges
are covered), the spread of their proportions, one connected solid per object, named parts, the
structure that tells the styles apart and the holes where the real objects have them."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from svr.data.procedural.categories import car, make_shape, phone
from svr.data.procedural.csg import CSGShape
from svr.data.procedural.generator import voxelize_shape

from .test_categories import _genus

SEEDS = 200


def _records(module, n: int = SEEDS) -> list:
    out = []
    for k in range(n):
        rng = np.random.default_rng([31, k])
        out.append(module.sample(rng, module.STYLES[k % len(module.STYLES)]))
    return out


def _inside(shape: CSGShape, x: float, y: float, z: float) -> bool:
    return bool(shape.sdf_numpy(np.array([[x, y, z]]))[0] < 0)


def _top_at(shape: CSGShape, x: float, z: float) -> float:
    ys = np.linspace(-0.6, 0.6, 481)
    inside = shape.sdf_numpy(np.stack([np.full_like(ys, x), ys, np.full_like(ys, z)], -1)) < 0
    return float(ys[inside].max()) if inside.any() else -np.inf


def _components(shape: CSGShape) -> int:
    return int(ndimage.label(voxelize_shape(shape, rule="protocol"), structure=np.ones((3, 3, 3)))[1])


def _extent(shape: CSGShape) -> np.ndarray:
    lo, hi = shape.bounds
    return np.asarray(hi) - np.asarray(lo)


# ------------------------------------------------------------------------------------------ car


def test_car_sample_sweep_covers_styles_options_and_ranges():
    recs = _records(car)
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
        ext.append(_extent(shape))
        assert len(shape.parts) >= 3 and {"body", "wheels"} <= set(shape.parts)
        if k < 12:
            assert _components(shape) == 1, k
    ext = np.array(ext)
    assert np.allclose(ext[:, 2], 1.0, atol=0.03)  # the length is the longest side
    assert ext[:, 0].min() < 0.4 and ext[:, 0].max() > 0.55  # width over length
    assert ext[:, 1].min() < 0.4 and ext[:, 1].max() > 0.6  # height over length


def _world(shape: CSGShape, q) -> np.ndarray:
    """A point of the raw (program) frame in the normalised shape's world frame."""
    return (np.asarray(q, float) - np.asarray(shape.offset)) * shape.scale


def _top_over(shape: CSGShape, x: float, z: float) -> float:
    """The highest world y of material over the raw point (x, z)."""
    p = _world(shape, (x, 0.0, z))
    return _top_at(shape, p[0], p[2])


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
            assert not _inside(shape, 0.0, lo[1] + 0.01, 0.0), style  # clearance under the body
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
    assert _genus(car.build(rec).normalized()) >= 1


# ---------------------------------------------------------------------------------------- phone


@pytest.mark.parametrize("layout", ["side", "across"])
def test_phone_hole_under_a_desk_handset(layout):
    rec = dataclasses.replace(phone.sample(np.random.default_rng([9, 0]), "desk"), layout=layout, cord=False)
    assert _genus(phone.build(rec).normalized()) >= 1
