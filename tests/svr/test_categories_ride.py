"""The vessel and car generators' newer variety: parameter sweeps (every style and option turns up,
ranges are covered), the spread of their proportions, one connected solid per object, named parts,
and the open volumes they draw (wells, catamaran tunnels, open cabins, hollows under the floor)."""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import ndimage

from svr.data.procedural.categories import car, make_shape, vessel
from svr.data.procedural.csg import CSGShape
from svr.data.procedural.generator import voxelize_shape

SEEDS = 240


def _records(module, n: int = SEEDS) -> list:
    return [module.sample(np.random.default_rng([47, k]), module.STYLES[k % len(module.STYLES)]) for k in range(n)]


def _span(recs, name: str) -> tuple[float, float]:
    vals = [getattr(r, name) for r in recs]
    return min(vals), max(vals)


def _components(shape: CSGShape) -> int:
    return int(ndimage.label(voxelize_shape(shape, rule="protocol"), structure=np.ones((3, 3, 3)))[1])


def _inside(shape: CSGShape, q) -> bool:
    """Whether the raw (program-frame) point q is inside the shape."""
    return bool(shape.sdf_numpy(np.asarray([q], float))[0] < 0)


# ------------------------------------------------------------------------------------------ vessel


def test_vessel_sample_sweep_covers_styles_options_and_ranges():
    recs = _records(vessel)
    assert {r.style for r in recs} == set(vessel.STYLES)
    cats = [r for r in recs if r.tunnel_w > 0]
    assert {r.style for r in cats} == {"ship", "sailboat", "speedboat"}
    assert min(r.tunnel_w for r in cats) < 0.45 and max(r.tunnel_w for r in cats) > 0.6
    wells = [r for r in recs if r.well_z1 > r.well_z0]
    assert {r.style for r in wells} == {"ship", "tanker"}
    sails = [r for r in recs if r.style == "sailboat"]
    assert min(r.sail_th for r in sails) < 0.065 and max(r.sail_th for r in sails) > 0.1
    assert min(r.sail_angle for r in sails) < -0.5 and max(r.sail_angle for r in sails) > 0.5
    assert {r.gaff > 0 for r in sails} == {False, True}
    assert {r.cockpit > 0 for r in sails} == {False, True}
    assert _span(recs, "wall")[0] < 0.06 and _span(recs, "wall")[1] > 0.095
    assert _span(recs, "beam")[0] < 0.1 and _span(recs, "beam")[1] > 0.45
    rows = [len(vessel.build(r).program) for r in recs[:60]]
    assert 5 <= min(rows) and max(rows) <= 30 and len(set(rows)) >= 5


def test_vessel_proportions_spread_and_objects_are_connected_and_labelled():
    ext = []
    for k in range(30):
        shape = make_shape("vessel", [48, k])
        lo, hi = shape.bounds
        ext.append(np.asarray(hi) - np.asarray(lo))
        assert len(shape.parts) >= 2 and "hull" in shape.parts, k
        if k < 12:
            assert _components(shape) == 1, k
    ext = np.array(ext)
    assert ext[:, 0].min() < 0.15 and ext[:, 0].max() > 0.35  # beam over the longest side
    assert ext[:, 1].min() < 0.15 and ext[:, 1].max() > 0.6  # height: hulls to sails


def test_vessel_tunnel_and_wells_are_open():
    """A catamaran's tunnel is empty under its bridge deck, which stays solid; a well deck is empty
    above its floor, a rowboat's open hull above its floor."""
    rec = dataclasses.replace(vessel.sample(np.random.default_rng([3, 1]), "speedboat"), tunnel_w=0.5, tunnel_h=0.5,
                              v_rise=0.0)
    s = vessel.build(rec)
    assert not _inside(s, (0.0, 0.01, 0.0)) and _inside(s, (rec.beam * 0.45, 0.01, 0.0))
    for k in range(6):
        rec = vessel.sample(np.random.default_rng([4, k]), "tanker")
        rec = dataclasses.replace(rec, well_z0=-0.2, well_z1=0.1, floor=0.4, cargo="none", sheer=0.0,
                                  v_rise=0.0, depth=0.15)
        s = vessel.build(rec)
        y = vessel._well(rec)[2]
        assert not _inside(s, (0.0, (y + rec.depth) / 2, -0.05)), k
        assert _inside(s, (0.0, y - 0.02, -0.05)), k
    rec = dataclasses.replace(vessel.sample(np.random.default_rng([5, 0]), "rowboat"), thwarts=0, oars=0.0,
                              motor=False)
    s = vessel.build(rec)
    assert not _inside(s, (0.0, rec.depth - 0.005, 0.1 - rec.stern_taper / 2))


# --------------------------------------------------------------------------------------------- car


def test_car_sample_sweep_covers_new_options_and_ranges():
    recs = _records(car)
    for flag in ("open_cab", "shell"):
        assert {getattr(r, flag) for r in recs} == {False, True}, flag
    assert not any(r.open_cab for r in recs if r.cargo == "cockpit")
    assert {r.under > 0 for r in recs} == {False, True}
    for name, lo, hi in (("wall", 0.065, 0.11), ("pillar", 0.065, 0.09), ("skirt", 0.07, 0.14),
                         ("sink", 0.05, 0.2), ("width", 0.3, 0.62), ("cab_h", 0.08, 0.45)):
        a, b = _span(recs, name)
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
        assert not _inside(s, (0.0, top - 0.12, 0.1)), k
        rec = dataclasses.replace(rec, open_cab=False, under=1.0, skirt=0.07, nose_drop=0.0, tail_drop=0.0,
                                  body_round=0.01)
        s = car.build(rec)
        assert not _inside(s, (0.0, rec.clearance + 0.02, 0.0)), k
        assert _inside(s, (rec.width / 2 - 0.035, rec.clearance + 0.02, 0.0)), k


def test_car_objects_are_connected_and_labelled():
    for k in range(12):
        shape = make_shape("car", [49, k])
        assert {"body", "wheels"} <= set(shape.parts), k
        assert _components(shape) == 1, k
