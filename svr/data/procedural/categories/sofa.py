"""The procedural sofa (see ``make_sofa`` for its styles)."""
from __future__ import annotations

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, legs, X


def make_sofa(rng: np.random.Generator, style: str) -> CSGShape:
    """Back at +z. "straight": base, back and two arms, 2-3 seat cushions; "sectional": L-shaped
    with a chaise reaching forward on one side; "armless": on taller legs, no arms; "loveseat":
    two cushions, thick rolled arms."""
    b = CSGBuilder()
    if style == "loveseat":
        w, d = uniform(rng, 0.65, 0.8), uniform(rng, 0.42, 0.52)
    else:
        w, d = uniform(rng, 0.85, 1.0), uniform(rng, 0.38, 0.5)
    leg = uniform(rng, 0.09, 0.15) if style == "armless" else uniform(rng, 0.04, 0.07)
    bh = uniform(rng, 0.13, 0.2)
    b.box_between((-w / 2, leg, -d / 2), (w / 2, leg + bh, d / 2), rounding=0.03)
    chaise = 0.0
    side = 1 if chance(rng, 0.5) else -1
    if style == "sectional":
        chaise = uniform(rng, 0.25, 0.4)
        cw = uniform(rng, 0.3, 0.4)
        x0, x1 = sorted((side * w / 2, side * (w / 2 - cw)))
        b.box_between((x0, leg, -d / 2 - chaise), (x1, leg + bh, -d / 2 + 0.05), rounding=0.03)
    bt = uniform(rng, 0.1, 0.16)
    back_h = uniform(rng, 0.2, 0.33)
    b.box_between((-w / 2, leg + bh - 0.02, d / 2 - bt), (w / 2, leg + bh + back_h, d / 2), rounding=0.04)
    at = uniform(rng, 0.08, 0.14) if style != "loveseat" else uniform(rng, 0.1, 0.15)
    ah = uniform(rng, 0.1, 0.2)
    arm_sides = {"straight": (-1, 1), "loveseat": (-1, 1), "sectional": (-side,), "armless": ()}[style]
    for s in arm_sides:
        x0, x1 = sorted((s * w / 2, s * (w / 2 - at)))
        b.box_between((x0, leg + bh - 0.02, -d / 2), (x1, leg + bh + ah, d / 2), rounding=0.03)
        if style == "loveseat":  # rolled arm
            b.capsule(((x0 + x1) / 2, leg + bh + ah, -d / 2 + at / 2), ((x0 + x1) / 2, leg + bh + ah, d / 2 - 0.02),
                      at / 2 + 0.015)
    n = 2 if style == "loveseat" else int(rng.integers(1, 4))
    ch = uniform(rng, 0.05, 0.09)
    xl = -w / 2 + (at if -1 in arm_sides else 0.0)
    xr = w / 2 - (at if 1 in arm_sides else 0.0)
    for k in range(n):
        x0 = xl + (xr - xl) * k / n + 0.005
        x1 = xl + (xr - xl) * (k + 1) / n - 0.005
        b.box_between((x0, leg + bh - 0.01, -d / 2 + 0.01), (x1, leg + bh + ch, d / 2 - bt), rounding=0.025)
    if style == "sectional":
        x0, x1 = sorted((side * (w / 2 - 0.01), side * (w / 2 - cw + 0.01)))
        b.box_between((x0, leg + bh - 0.01, -d / 2 - chaise + 0.01), (x1, leg + bh + ch, -d / 2 + 0.05),
                      rounding=0.025)
    if chance(rng, 0.4):  # back cushions leaning on the back
        for k in range(n):
            x0 = xl + (xr - xl) * k / n + 0.01
            x1 = xl + (xr - xl) * (k + 1) / n - 0.01
            b.box(((x0 + x1) / 2, leg + bh + ch + back_h * 0.35, d / 2 - bt - 0.03),
                  ((x1 - x0) / 2, back_h * 0.35, 0.045), rotation(X, -0.2), rounding=0.03)
    lr = 0.035 if style == "armless" else 0.03
    zs = [-d / 2 + 0.06, d / 2 - 0.06]
    for x in (-w / 2 + 0.06, w / 2 - 0.06):
        for z in zs:
            b.cylinder((x, leg / 2 + 0.01, z), lr, leg / 2 + 0.01)
    if style == "sectional":
        b.cylinder((side * (w / 2 - 0.06), leg / 2 + 0.01, -d / 2 - chaise + 0.06), lr, leg / 2 + 0.01)
    return b.shape()


STYLES = ('straight', 'sectional', 'armless', 'loveseat')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_sofa(*params)
