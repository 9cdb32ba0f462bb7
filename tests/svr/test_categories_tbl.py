"""The table and lamp generators (and the extras mug and shelf): parameter records, the ranges
their sweeps cover, proportions, connectedness, named parts and the structure of their styles."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from scipy import ndimage

from svr.data.procedural.categories import extras, lamp, make_shape, procedural_category, table
from svr.data.procedural.csg import CSGShape


def _records(module, n: int = 200, seed: int = 0):
    rng = np.random.default_rng(seed)
    return [module.sample(rng, module.STYLES[k % len(module.STYLES)]) for k in range(n)]


def _genus(shape: CSGShape, n: int = 64) -> int:
    from sdfcommon.numerics.meshing import sdf_to_mesh

    ax = np.linspace(-0.56, 0.56, n)
    values = torch.from_numpy(np.ascontiguousarray(shape.sdf_numpy(np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1))))
    parts = sdf_to_mesh(values, -0.56, 0.56).split(only_watertight=False)
    return sum(int(round((2 - p.euler_number) / 2)) for p in parts)


def _components(shape: CSGShape) -> int:
    from svr.data.procedural.generator import voxelize_shape

    _, n = ndimage.label(voxelize_shape(shape, rule="protocol"), structure=np.ones((3, 3, 3)))
    return n


def _extent(shape: CSGShape) -> np.ndarray:
    lo, hi = shape.bounds
    return hi - lo


# ------------------------------------------------------------------------------------ table


def test_table_sweep_covers_every_option_and_wide_ranges():
    recs = _records(table)
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
    ext = np.array([_extent(make_shape("table", [30, k])) for k in range(30)])
    assert ext[:, 1].min() < 0.45 and ext[:, 1].max() > 0.9
    assert ext[:, 2].min() < 0.55 and ext[:, 2].max() > 0.95


@pytest.mark.parametrize("style", table.STYLES)
def test_tables_are_one_solid_with_named_parts(style):
    for k in range(3):
        shape = make_shape("table", [31, k], style=style)
        assert _components(shape) == 1, (style, k)
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
    assert _genus(shape("lower_shelf", top="rect", leg="square")) >= 1
    assert _genus(shape("legs", top="rect", stretcher="box", leg="square")) >= 1
    desk = shape("desk", drawers=2)
    assert "drawers" in desk.parts


# ------------------------------------------------------------------------------------ lamp


def test_lamp_sweep_covers_every_option_and_wide_ranges():
    recs = _records(lamp, 240)
    assert {r.style for r in recs} == set(lamp.STYLES)
    assert {r.shade for r in recs} == set(lamp.SHADES)
    assert {r.base for r in recs if r.style == "floor"} == set(lamp.BASES)
    assert {r.base for r in recs if r.style == "table"} == set(lamp.BODIES)
    assert {r.light for r in recs if r.shade == "chandelier"} == set(lamp.LIGHTS)
    assert {len(r.segments) for r in recs if r.style == "desk"} == {1, 2, 3}
    assert {any(r.paired) for r in recs if r.style == "desk"} == {True, False}
    assert {r.arms for r in recs if r.style == "hanging" and r.shade != "chandelier"} == {1, 2, 3, 4}
    assert {r.arms for r in recs if r.shade == "chandelier"} == {3, 4, 5, 6}
    assert any(r.segments for r in recs if r.style == "floor") and any(not r.segments for r in recs if r.style == "floor")
    h = np.array([r.shade_h for r in recs if r.style == "floor"])
    assert h.min() < 0.13 and h.max() > 0.27
    assert min(r.wall for r in recs) >= 0.058 and min(r.rod for r in recs) >= 0.0275


def test_lamp_proportions_span_a_wide_range():
    """Tall floor lamps, squat table lamps and wide chandeliers: the normalised width (the larger
    of x and z) and height vary widely."""
    ext = np.array([_extent(make_shape("lamp", [32, k])) for k in range(30)])
    width = ext[:, [0, 2]].max(1)
    assert width.min() < 0.45 and width.max() > 0.9
    assert ext[:, 1].min() < 0.7 and ext[:, 1].max() > 0.99


@pytest.mark.parametrize("style", lamp.STYLES)
def test_lamps_are_one_solid_with_named_parts(style):
    for k in range(4):
        shape = make_shape("lamp", [33, k], style=style)
        assert _components(shape) == 1, (style, k)
        assert 2 <= len(shape.parts) <= 8 and ("shade" in shape.parts or "lights" in shape.parts), shape.parts


def test_lamp_styles_differ_in_structure():
    """A hanging lamp's top is its narrow canopy; a floor lamp's pole makes it tall and narrow; a
    desk lamp's paired arm makes a hole; a desk lamp's head is off the base's axis, in front."""
    rng = np.random.default_rng(6)
    for _ in range(3):
        p = lamp.sample(rng, "hanging")
        hanging = lamp.build(dataclasses.replace(p, shade="cone", arms=1)).normalized()
        lo, hi = hanging.bounds
        ax = np.linspace(-0.55, 0.55, 45)
        band = np.stack(np.meshgrid(ax, [hi[1] - 0.03], ax, indexing="ij"), -1).reshape(-1, 3)
        top = band[hanging.sdf_numpy(band) < 0]
        assert len(top) and np.abs(top[:, [0, 2]]).max() < 0.3 * float(max(hi[0] - lo[0], hi[2] - lo[2]))
        floor = lamp.build(dataclasses.replace(lamp.sample(rng, "floor"), segments=(), base="disc")).normalized()
        ext = _extent(floor)
        assert ext[1] > 1 - 1e-6 and max(ext[0], ext[2]) < 0.75
        desk = lamp.sample(rng, "desk")
        if len(desk.segments) == 1:
            desk = dataclasses.replace(desk, segments=desk.segments + ((0.3, 1.5),), paired=(False, False))
        desk = dataclasses.replace(desk, paired=(True,) + desk.paired[1:], yaw=0.0)
        assert _genus(lamp.build(desk).normalized()) >= 1


# ------------------------------------------------------------------------------------ extras


@pytest.mark.parametrize("name,module", [("mug", "MUG"), ("shelf", "SHELF")])
def test_extras_have_records_and_parts(name, module):
    cat = procedural_category(name)
    sample, build = getattr(extras, f"sample_{name}"), getattr(extras, f"build_{name}")
    rng = np.random.default_rng(0)
    for style in getattr(extras, f"{module}_STYLES"):
        rec = sample(rng, style)
        assert dataclasses.is_dataclass(rec) and rec.style == style
        assert np.array_equal(build(rec).program, build(rec).program)
    shapes = [make_shape(name, [34, k]) for k in range(4)]
    assert all(len(s.parts) >= 2 for s in shapes) and cat.styles
    assert all(_components(s) == 1 for s in shapes)
    if name == "mug":
        assert all(_genus(s) == 1 for s in shapes[:2])
