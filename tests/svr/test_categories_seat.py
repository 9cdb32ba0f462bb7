"""The seat categories (chair, sofa, bench): their parameter records cover every style and option
and wide numeric ranges, built objects are one connected solid with named parts and widely varied
proportions, and the styles differ in structure."""
from __future__ import annotations

from dataclasses import asdict, fields

import numpy as np
import pytest
from scipy import ndimage

from svr.data.procedural.categories import bench, chair, make_shape, sofa
from svr.data.procedural.csg import CSGShape

MODULES = {"chair": chair, "sofa": sofa, "bench": bench}


def _records(module, n: int = 200) -> list:
    out = []
    for k in range(n):
        rng = np.random.default_rng([77, k])
        out.append(module.sample(rng, module.STYLES[k % len(module.STYLES)]))
    return out


def _values(records, name: str) -> list:
    return [getattr(r, name) for r in records]


def _grid(shape: CSGShape, n: int = 64) -> np.ndarray:
    ax = np.linspace(-0.55, 0.55, n)
    return shape.sdf_numpy(np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)) < 0


def _extent(shape: CSGShape) -> np.ndarray:
    """(x, y, z) extent of the normalised shape, measured on a 64^3 grid."""
    idx = np.argwhere(_grid(shape))
    return (idx.max(0) - idx.min(0) + 1) * (1.1 / 63)


# ------------------------------------------------------------------------------ records


def test_records_are_frozen_and_complete_and_build_deterministically():
    for name, module in MODULES.items():
        with pytest.raises(ValueError, match="style must be one of"):
            module.sample(np.random.default_rng(0), "teapot")
        rec = module.sample(np.random.default_rng(3), module.STYLES[0])
        assert fields(rec)[0].name == "style" and rec.style == module.STYLES[0]
        with pytest.raises(Exception):
            rec.style = "x"  # frozen
        again = module.sample(np.random.default_rng(3), module.STYLES[0])
        assert asdict(rec) == asdict(again)
        np.testing.assert_array_equal(module.build(rec).program, module.build(again).program)


def test_chair_sample_sweep_covers_options_and_ranges():
    recs = _records(chair)
    assert set(_values(recs, "style")) == set(chair.STYLES)
    for name, options in (("seat", chair.SEATS), ("base", chair.BASES), ("leg", chair.LEGS),
                          ("back", chair.BACKS), ("arms", chair.ARMS), ("stretcher", chair.STRETCHERS)):
        assert set(_values(recs, name)) == set(options), name
    assert len(set(_values([r for r in recs if r.back in ("slats", "spindles", "ladder")], "n_back"))) >= 4
    assert set(_values([r for r in recs if r.base == "star"], "spokes")) == {4, 5}
    for name, lo, hi in (("seat_h", 0.3, 0.6), ("back_h", 0.25, 0.5), ("back_tilt", 0.05, 0.3),
                         ("leg_t", 0.065, 0.09), ("seat_t", 0.07, 0.13), ("back_w", 0.65, 0.9)):
        v = np.array(_values(recs, name))
        assert v.min() < lo and v.max() > hi, (name, v.min(), v.max())


def test_sofa_sample_sweep_covers_options_and_ranges():
    recs = _records(sofa)
    assert set(_values(recs, "style")) == set(sofa.STYLES)
    for name, options in (("leg", sofa.LEGS), ("back", sofa.BACKS), ("arm", sofa.ARMS)):
        assert set(_values(recs, name)) == set(options), name
    assert set(_values(recs, "n_seats")) == {1, 2, 3, 4}
    assert set(_values(recs, "n_backs")) == {0, 1, 2, 3}
    assert set(_values(recs, "legs_per_side")) == {2, 3}
    assert {len(r.arm_sides) for r in recs} == {0, 1, 2}
    sectional = [r for r in recs if r.style == "sectional"]
    assert {r.u_shape for r in sectional} == {True, False} and {r.corner for r in sectional} == {True, False}
    curve = np.array([r.curve for r in recs if r.style == "curved"])
    assert curve.min() < -0.2 and curve.max() > 0.3
    for name, lo, hi in (("width", 0.65, 0.95), ("depth", 0.35, 0.55), ("back_h", 0.18, 0.36),
                         ("arm_w", 0.08, 0.18), ("base_h", 0.1, 0.2), ("back_tilt", 0.05, 0.25)):
        v = np.array(_values(recs, name))
        assert v.min() < lo and v.max() > hi, (name, v.min(), v.max())


def test_bench_sample_sweep_covers_options_and_ranges():
    recs = _records(bench)
    assert set(_values(recs, "style")) == set(bench.STYLES)
    for name, options in (("support", bench.SUPPORTS), ("leg", bench.LEGS), ("back", bench.BACKS),
                          ("arms", bench.ARMS), ("cut", bench.CUTS)):
        assert set(_values(recs, name)) == set(options), name
    assert set(_values(recs, "slats")) == {0, 2, 3, 4, 5}
    assert set(_values(recs, "n_supports")) == {2, 3}
    assert set(_values(recs, "back_n")) == {1, 2, 3, 4}
    for name, lo, hi in (("depth", 0.25, 0.4), ("seat_h", 0.3, 0.45), ("back_h", 0.18, 0.36),
                         ("inset", 0.03, 0.15), ("leg_t", 0.065, 0.1)):
        v = np.array(_values(recs, name))
        assert v.min() < lo and v.max() > hi, (name, v.min(), v.max())


# ------------------------------------------------------------------------------ built shapes


@pytest.mark.parametrize("name", list(MODULES))
def test_built_objects_are_one_connected_solid_with_named_parts(name):
    """Each object is one 26-connected solid on a 64^3 sample, with 2-8 named parts."""
    for k in range(24):
        shape = make_shape(name, [78, k])
        _, n = ndimage.label(_grid(shape), np.ones((3, 3, 3)))
        assert n == 1, (name, k, n)
        assert 2 <= len(shape.parts) <= 8 and "body" not in shape.parts, (name, k, shape.parts)


@pytest.mark.parametrize("name,ratio,lo,hi", [
    ("chair", "height/width", 1.0, 1.8),   # a lounge chair is squat, a bar stool tall
    ("chair", "depth/width", 0.85, 1.2),
    ("sofa", "height/width", 0.45, 0.85),  # a long low daybed, a tall short loveseat
    ("sofa", "depth/width", 0.5, 0.85),
    ("bench", "height/width", 0.45, 0.75),  # low backless benches, tall backed ones
    ("bench", "depth/width", 0.3, 0.45),
])
def test_normalised_proportions_span_a_wide_range(name, ratio, lo, hi):
    ext = np.array([_extent(make_shape(name, [79, k])) for k in range(30)])
    num = ext[:, 1] if ratio.startswith("height") else ext[:, 2]
    r = num / ext[:, 0]
    assert r.min() < lo and r.max() > hi, (name, ratio, r.min(), r.max())


def _inside(shape: CSGShape, x: float, y: float, z: float) -> bool:
    return bool(shape.sdf_numpy(np.array([[x, y, z]]))[0] < 0)


def test_chair_styles_differ_in_structure():
    """Swivel chairs and pedestal stools stand on a central column where legged chairs have none;
    a bar stool's seat sits higher than a dining chair's; a cantilever frame leaves the floor
    under the back of the seat empty; a slatted back has holes."""
    def raw(style: str, k: int):
        rec = chair.sample(np.random.default_rng([80, k]), style)
        return rec, chair.build(rec)

    def column(style: str, k: int) -> bool:  # material all the way up the axis under the seat
        rec, shape = raw(style, k)
        ys = np.linspace(0.15, 0.85, 15) * rec.seat_h
        return bool((shape.sdf_numpy(np.stack([np.zeros_like(ys), ys, np.zeros_like(ys)], -1)) < 0).all())

    for k in range(4):
        assert column("swivel", k) and not column("four_legs", k) and not column("slatted", k)
        rec, cant = raw("cantilever", k)
        # nothing under the rear half of the seat between floor runners and seat rails
        pts = np.array([[x, y, z] for x in np.linspace(-rec.seat_w / 2, rec.seat_w / 2, 9)
                        for y in np.linspace(0.3, 0.7, 5) * rec.seat_h for z in np.linspace(0.1, 0.5, 5) * rec.seat_d])
        assert (cant.sdf_numpy(pts) > 0).all(), k
    # seat height over total height: bar stools sit high
    def seat_level(style: str, k: int) -> float:
        rec = chair.sample(np.random.default_rng([81, k]), style)
        return rec.seat_h / (rec.seat_h + rec.seat_t + rec.cushion_t + (rec.back_h if rec.back != "none" else 0))
    high = np.mean([seat_level("barstool", k) for k in range(20)])
    assert high > np.mean([seat_level("four_legs", k) for k in range(20)]) + 0.15
    from tests.svr.test_categories import _genus
    assert _genus(make_shape("chair", [80, 0], style="slatted")) >= 2


def test_sofa_and_bench_structure():
    """A sectional's chaise reaches forward on one side (an L) or both (a U); a curved sofa's
    corners are empty where a straight one's are full; a park bench has holes between its slats."""
    for k in range(6):
        rec = sofa.sample(np.random.default_rng([82, k]), "sectional")
        shape = sofa.build(rec)
        y = rec.leg_h + rec.base_h / 2
        z = -rec.depth / 2 - rec.chaise_len + 0.03
        ahead = [_inside(shape, sx * 0.45 * rec.width, y, z) for sx in (-1, 1)]
        assert ahead == ([True, True] if rec.u_shape else [rec.chaise_side < 0, rec.chaise_side > 0]), k
    for k in range(3):
        rec = sofa.sample(np.random.default_rng([83, k]), "curved")
        shape = sofa.build(rec)
        r, y = rec.width / 2, rec.leg_h + rec.base_h / 2
        assert _inside(shape, 0.0, y, 0.5 * r) and not _inside(shape, 0.95 * r, y, 0.95 * r)
    from tests.svr.test_categories import _genus
    assert _genus(make_shape("bench", [82, 0], style="park")) >= 1
