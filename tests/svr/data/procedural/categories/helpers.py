"""Helpers shared by the category tests: a category module's parameter records and the spread of their
fields, and measures of a built shape (its extent, its connected parts, its genus, whether a point is
inside it)."""
from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np
import pytest
import torch
from scipy import ndimage

from svr.data.procedural.categories import make_shape, style_of
from svr.data.procedural.csg import CSGShape
from svr.data.procedural.generator import voxelize_shape

# ------------------------------------------------------------------------------------ records


def records(module, n: int = 200, seed: Optional[int] = None) -> list:
    """``n`` parameter records of a category module, cycling through its styles; record k is drawn
    from a generator of its own: ``default_rng(k)``, or ``default_rng([seed, k])`` given a seed."""
    return [module.sample(np.random.default_rng(k if seed is None else [seed, k]),
                          module.STYLES[k % len(module.STYLES)]) for k in range(n)]


def records_of_one_stream(module, n: int = 200, seed: int = 0) -> list:
    """``n`` parameter records cycling through the styles, drawn one after the other from one
    ``default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    return [module.sample(rng, module.STYLES[k % len(module.STYLES)]) for k in range(n)]


def values(recs, name: str) -> list:
    """The field ``name`` of every record."""
    return [getattr(r, name) for r in recs]


def span(vals) -> tuple[float, float]:
    """(smallest, largest) of some values."""
    return float(np.min(vals)), float(np.max(vals))


# ------------------------------------------------------------------------------------ shapes


def extent(shape: CSGShape) -> np.ndarray:
    """(x, y, z) size of the shape's bounding box."""
    lo, hi = shape.bounds
    return np.asarray(hi) - np.asarray(lo)


def occupancy(shape: CSGShape, n: int = 64) -> np.ndarray:
    """(n, n, n) bool: the samples of an n^3 grid over [-0.55, 0.55]^3 inside the shape."""
    ax = np.linspace(-0.55, 0.55, n)
    return shape.sdf_numpy(np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)) < 0


def grid_extent(shape: CSGShape) -> np.ndarray:
    """(x, y, z) extent of the normalised shape, measured on a 64^3 grid."""
    idx = np.argwhere(occupancy(shape))
    return (idx.max(0) - idx.min(0) + 1) * (1.1 / 63)


def components(shape: CSGShape) -> int:
    """The number of 26-connected solids of the shape's protocol voxels."""
    return int(ndimage.label(voxelize_shape(shape, rule="protocol"), structure=np.ones((3, 3, 3)))[1])


def inside(shape: CSGShape, x: float, y: float, z: float) -> bool:
    """Whether the point (x, y, z) of the shape's frame is inside it."""
    return bool(shape.sdf_numpy(np.array([[x, y, z]], float))[0] < 0)


def genus(shape: CSGShape, n: int = 64) -> int:
    """The number of holes of the shape's mesh at n^3, summed over its connected parts."""
    from sdfcommon.numerics.meshing import sdf_to_mesh

    ax = np.linspace(-0.56, 0.56, n)
    grid = np.stack(np.meshgrid(ax, ax, ax, indexing="ij"), -1)
    vals = torch.from_numpy(np.ascontiguousarray(shape.sdf_numpy(grid)))
    parts = sdf_to_mesh(vals, -0.56, 0.56).split(only_watertight=False)
    return sum(int(round((2 - p.euler_number) / 2)) for p in parts)


def checked_extents(name: str, styles, seed: int, count: int) -> np.ndarray:
    """Builds ``count`` objects cycling through the styles, checks that each has 2-8 parts and the
    first half one connected solid each; returns their (count, 3) extents."""
    ext = []
    for k in range(count):
        shape = make_shape(name, [seed, k], style=styles[k % len(styles)])
        ext.append(extent(shape))
        assert 2 <= len(shape.parts) <= 8, shape.parts
        if k < count // 2:
            assert components(shape) == 1, k
    return np.array(ext)


# ------------------------------------------------------------------------------------ checks several categories share


def check_records_frozen_and_build_deterministic(module) -> None:
    """A category module's records are frozen dataclasses led by ``style``, ``build`` is
    deterministic and an unknown style is refused."""
    p = module.sample(np.random.default_rng(3), module.STYLES[0])
    assert dataclasses.is_dataclass(p) and dataclasses.fields(p)[0].name == "style"
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.style = "x"
    np.testing.assert_array_equal(module.build(p).program, module.build(p).program)
    with pytest.raises(ValueError, match="style must be one of"):
        module.sample(np.random.default_rng(0), "teapot")


def check_extents_reach(name: str, low, high) -> None:
    """30 objects' normalised bounding-box extents (x, y, z) reach at least ``low`` and ``high``."""
    ext = np.array([np.subtract(*make_shape(name, [21, k]).bounds[::-1]) for k in range(30)])
    assert (ext.min(0) <= np.array(low) + 1e-6).all() and (ext.max(0) >= np.array(high) - 1e-6).all(), \
        (ext.min(0), ext.max(0))


def check_every_style_connected_with_named_parts(name: str, module) -> None:
    """Two objects of every style are one 26-connected solid with 2-8 named parts."""
    for style in module.STYLES:
        for k in range(2):
            shape = make_shape(name, [22, k], style=style)
            assert ndimage.label(occupancy(shape), np.ones((3, 3, 3)))[1] == 1, (style, k)
            assert 2 <= len(shape.parts) <= 8, (style, shape.parts)


def check_ratio_spreads(name: str, height_width: float, depth_width: float) -> None:
    """The spread of 30 objects' height/width and depth/width ratios is at least the given ones."""
    hw, dw = [], []
    for k in range(30):
        lo, hi = make_shape(name, [21, k]).bounds
        ext = hi - lo
        hw.append(ext[1] / ext[0])
        dw.append(ext[2] / ext[0])
    assert np.ptp(hw) >= height_width and np.ptp(dw) >= depth_width, (np.ptp(hw), np.ptp(dw))


def check_one_solid_with_parts(name: str) -> None:
    """16 objects are each one solid in the benchmark's voxels, with 2-8 parts and a short program,
    in at least 3 styles."""
    styles = set()
    for k in range(16):
        shape = make_shape(name, [22, k])
        styles.add(style_of(name, [22, k]))
        vox = voxelize_shape(shape, rule="protocol")
        _, count = ndimage.label(vox, structure=np.ones((3, 3, 3)))
        assert count == 1, (k, count)
        assert 2 <= len(shape.parts) <= 8, shape.parts
        assert len(shape.program) <= 40
    assert len(styles) >= 3


def check_every_style_builds_one_labelled_solid(module) -> None:
    """24 records, cycling through the styles, build one solid with 2-8 parts and at most 45 rows."""
    for k in range(24):
        style = module.STYLES[k % len(module.STYLES)]
        shape = module.build(module.sample(np.random.default_rng([33, k]), style)).normalized()
        vox = voxelize_shape(shape, rule="protocol")
        _, count = ndimage.label(vox, structure=np.ones((3, 3, 3)))
        assert count == 1, (style, k, count)
        assert 2 <= len(shape.parts) <= 8, shape.parts
        assert len(shape.program) <= 45, (style, k, len(shape.program))


def check_seats_connected_with_named_parts(name: str) -> None:
    """Each of 24 objects is one 26-connected solid on a 64^3 sample, with 2-8 named parts."""
    for k in range(24):
        shape = make_shape(name, [78, k])
        _, n = ndimage.label(occupancy(shape), np.ones((3, 3, 3)))
        assert n == 1, (name, k, n)
        assert 2 <= len(shape.parts) <= 8 and "body" not in shape.parts, (name, k, shape.parts)


def check_normalised_ratio_spread(name: str, ratio: str, lo: float, hi: float) -> None:
    """30 objects' height/width or depth/width (measured on a 64^3 grid) reach below ``lo`` and above ``hi``."""
    ext = np.array([grid_extent(make_shape(name, [79, k])) for k in range(30)])
    num = ext[:, 1] if ratio.startswith("height") else ext[:, 2]
    r = num / ext[:, 0]
    assert r.min() < lo and r.max() > hi, (name, ratio, r.min(), r.max())
