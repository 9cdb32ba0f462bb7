"""The two extra procedural categories (not in NMR ShapeNet): the mug, "straight" or "tapered" towards
the foot (radius 0.25-0.35, height 0.5-0.8, wall 0.055-0.07, a torus handle of drawn size, thickness
and height: genus 1), and the shelf, a bookcase with "closed_back" or "open_back" compartments (width
0.45-0.9, height 0.7-1.0, depth 0.25-0.4, two to four rows of one or two columns, an optional plinth).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, X

MUG_STYLES = ("straight", "tapered")
SHELF_STYLES = ("closed_back", "open_back")


@dataclass(frozen=True)
class MugParams:
    style: str
    radius: float
    height: float
    wall: float
    bottom: float
    taper: float         # the foot's radius is smaller by this
    handle_r: float      # the handle's major radius, a fraction of the height
    handle_t: float      # its tube radius
    handle_y: float      # its centre, a fraction of the height


def sample_mug(rng: np.random.Generator, style: str) -> MugParams:
    if style not in MUG_STYLES:
        raise ValueError(f"style must be one of {MUG_STYLES}, got {style!r}")
    return MugParams(style=style, radius=uniform(rng, 0.25, 0.35), height=uniform(rng, 0.5, 0.8),
                     wall=uniform(rng, 0.055, 0.07), bottom=uniform(rng, 0.055, 0.08),
                     taper=uniform(rng, 0.04, 0.09) if style == "tapered" else 0.0,
                     handle_r=uniform(rng, 0.18, 0.31), handle_t=uniform(rng, 0.035, 0.05),
                     handle_y=uniform(rng, 0.45, 0.55))


def build_mug(p: MugParams) -> CSGShape:
    """A cup with a bottom and a torus handle on +x (genus 1)."""
    b = CSGBuilder()
    r, h, taper = p.radius, p.height, p.taper
    b.part("body")
    b.cone((0, h / 2, 0), h / 2, r - taper, r)
    hr = min(p.handle_r * h, h / 2 - p.handle_t - 0.02)
    b.part("handle")
    b.torus((r - 0.02 + hr * 0.55, h * p.handle_y, 0), hr, p.handle_t, rotation(X, math.pi / 2))
    # the cavity, cut last so the handle never enters the cup
    b.part("inside")
    b.cone((0, p.bottom + (h - p.bottom) / 2 + 0.05, 0), (h - p.bottom) / 2 + 0.05,
           r - taper - p.wall, r - p.wall + 0.05 * taper / h, op="subtract")
    return b.shape()


@dataclass(frozen=True)
class ShelfParams:
    style: str
    width: float
    height: float
    depth: float
    thick: float
    rows: int
    cols: int
    plinth: float        # the plinth's height, 0 for none


def sample_shelf(rng: np.random.Generator, style: str) -> ShelfParams:
    if style not in SHELF_STYLES:
        raise ValueError(f"style must be one of {SHELF_STYLES}, got {style!r}")
    return ShelfParams(style=style, width=uniform(rng, 0.45, 0.9), height=uniform(rng, 0.7, 1.0),
                       depth=uniform(rng, 0.25, 0.4), thick=uniform(rng, 0.055, 0.065),
                       rows=int(rng.integers(2, 5)), cols=int(rng.integers(1, 3)),
                       plinth=uniform(rng, 0.055, 0.1) if chance(rng, 0.4) else 0.0)


def build_shelf(p: ShelfParams) -> CSGShape:
    """A box with a grid of compartments open at the front (and at the back: holes), on an optional
    plinth set back from the front."""
    b = CSGBuilder()
    w, h, d, t = p.width, p.height, p.depth, p.thick
    y0 = p.plinth
    b.part("case")
    b.box((0, y0 + (h - y0) / 2, 0), (w / 2, (h - y0) / 2, d / 2))
    cw = (w - (p.cols + 1) * t) / p.cols
    chh = (h - y0 - (p.rows + 1) * t) / p.rows
    z1 = d / 2 + 0.1 if p.style == "open_back" else d / 2 - t
    b.part("inside")
    for i in range(p.rows):
        for j in range(p.cols):
            x0 = -w / 2 + t + j * (cw + t)
            yb = y0 + t + i * (chh + t)
            b.box_between((x0, yb, -d / 2 - 0.1), (x0 + cw, yb + chh, z1), op="subtract")
    if p.plinth > 0:
        b.part("plinth")
        b.box_between((-w / 2 + 0.02, 0.0, -d / 2 + 0.03), (w / 2 - 0.02, y0 + 0.01, d / 2 - 0.01))
    return b.shape()
