"""Helpers shared by the category tests: a category module's parameter records and the spread of their
fields, and measures of a built shape (its extent, its connected parts, its genus, whether a point is
inside it)."""
from __future__ import annotations

from typing import Optional

import numpy as np
import torch
from scipy import ndimage

from svr.data.procedural.categories import make_shape
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
