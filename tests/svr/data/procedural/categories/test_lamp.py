"""The lamp generator: parameter records, the ranges its sweep covers, proportions, connectedness,
named parts and the structure of its styles."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svr.data.procedural.categories import lamp, make_shape

from .helpers import components, extent, genus, records_of_one_stream


def test_lamp_sweep_covers_every_option_and_wide_ranges():
    recs = records_of_one_stream(lamp, 240)
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
    ext = np.array([extent(make_shape("lamp", [32, k])) for k in range(30)])
    width = ext[:, [0, 2]].max(1)
    assert width.min() < 0.45 and width.max() > 0.9
    assert ext[:, 1].min() < 0.7 and ext[:, 1].max() > 0.99


@pytest.mark.parametrize("style", lamp.STYLES)
def test_lamps_are_one_solid_with_named_parts(style):
    for k in range(4):
        shape = make_shape("lamp", [33, k], style=style)
        assert components(shape) == 1, (style, k)
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
        ext = extent(floor)
        assert ext[1] > 1 - 1e-6 and max(ext[0], ext[2]) < 0.75
        desk = lamp.sample(rng, "desk")
        if len(desk.segments) == 1:
            desk = dataclasses.replace(desk, segments=desk.segments + ((0.3, 1.5),), paired=(False, False))
        desk = dataclasses.replace(desk, paired=(True,) + desk.paired[1:], yaw=0.0)
        assert genus(lamp.build(desk).normalized()) >= 1
