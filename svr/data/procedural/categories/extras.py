"""The two extra procedural categories (not in NMR ShapeNet): mug and shelf."""
from __future__ import annotations

import math

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, X


def make_mug(rng: np.random.Generator, style: str) -> CSGShape:
    """A cup with a bottom and a torus handle (genus 1), "straight" or "tapered" towards the foot."""
    b = CSGBuilder()
    r, h = uniform(rng, 0.25, 0.35), uniform(rng, 0.5, 0.8)
    wall, bottom = uniform(rng, 0.055, 0.07), uniform(rng, 0.055, 0.08)
    taper = uniform(rng, 0.04, 0.09) if style == "tapered" else 0.0
    b.cone((0, h / 2, 0), h / 2, r - taper, r)
    hr, hm = uniform(rng, 0.12, 0.2) * h / 0.65, uniform(rng, 0.035, 0.05)
    hr = min(hr, h / 2 - hm - 0.02)
    b.torus((r - 0.02 + hr * 0.55, h * uniform(rng, 0.45, 0.55), 0), hr, hm, rotation(X, math.pi / 2))
    # the cavity, cut last so the handle never enters the cup
    b.cone((0, bottom + (h - bottom) / 2 + 0.05, 0), (h - bottom) / 2 + 0.05,
           r - taper - wall, r - wall + 0.05 * taper / h, op="subtract")
    return b.shape()


def make_shelf(rng: np.random.Generator, style: str) -> CSGShape:
    """A bookcase: a box with a grid of compartments open at the front, with a "closed_back" or an
    "open_back" (the compartments go through: holes)."""
    b = CSGBuilder()
    w, h, d = uniform(rng, 0.45, 0.9), uniform(rng, 0.7, 1.0), uniform(rng, 0.25, 0.4)
    t = uniform(rng, 0.055, 0.065)
    b.box((0, h / 2, 0), (w / 2, h / 2, d / 2))
    rows, cols = int(rng.integers(2, 5)), int(rng.integers(1, 3))
    cw = (w - (cols + 1) * t) / cols
    chh = (h - (rows + 1) * t) / rows
    z1 = d / 2 + 0.1 if style == "open_back" else d / 2 - t
    for i in range(rows):
        for j in range(cols):
            x0 = -w / 2 + t + j * (cw + t)
            y0 = t + i * (chh + t)
            b.box_between((x0, y0, -d / 2 - 0.1), (x0 + cw, y0 + chh, z1), op="subtract")
    return b.shape()


MUG_STYLES = ("straight", "tapered")
SHELF_STYLES = ("closed_back", "open_back")


def sample_mug(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build_mug(params) -> CSGShape:
    return make_mug(*params)


def sample_shelf(rng: np.random.Generator, style: str):
    return rng, style


def build_shelf(params) -> CSGShape:
    return make_shelf(*params)
