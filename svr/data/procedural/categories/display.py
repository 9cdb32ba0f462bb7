"""The procedural display (see ``make_display`` for its styles)."""
from __future__ import annotations

import math

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, chance, bar, recess


def make_display(rng: np.random.Generator, style: str) -> CSGShape:
    """A screen facing -z (a shallow recess inside a bezel). "monitor": on a neck and a foot,
    the neck sometimes with a cut-out (a hole); "tv": wide, on two feet; "wall": a flat slab
    with a wall bracket behind; "crt": a deep cathode-ray tube box on a swivel foot."""
    b = CSGBuilder()
    if style == "crt":
        w = uniform(rng, 0.75, 0.9)
        h = w * uniform(rng, 0.82, 0.95)
        fd = uniform(rng, 0.12, 0.18)
        foot = uniform(rng, 0.05, 0.1)
        y0 = foot + 0.03
        b.box((0, y0 + h / 2, 0), (w / 2, h / 2, fd / 2), rounding=0.02)
        bz = uniform(rng, 0.03, 0.05)
        recess(b, -w / 2 + bz, w / 2 - bz, y0 + bz * 1.4, y0 + h - bz, -fd / 2, 0.02)
        depth = uniform(rng, 0.35, 0.5)
        f1, f2 = uniform(rng, 0.8, 0.9), uniform(rng, 0.5, 0.65)
        b.box((0, y0 + h * 0.52, fd / 2 + depth * 0.25), (w * f1 / 2, h * f1 / 2, depth * 0.25), rounding=0.03)
        b.box((0, y0 + h * 0.55, fd / 2 + depth * 0.7), (w * f2 / 2, h * f2 / 2, depth * 0.2 + 0.02), rounding=0.03)
        b.cylinder((0, foot / 2 + 0.02, fd / 2 + depth * 0.3), uniform(rng, 0.08, 0.12), foot / 2 + 0.02)
        b.cylinder((0, 0.0275, fd / 2 + depth * 0.3), uniform(rng, 0.18, 0.25), 0.0275)
        return b.shape()
    if style == "tv":
        w, t = uniform(rng, 0.95, 1.0), uniform(rng, 0.068, 0.075)
        h = w * uniform(rng, 0.54, 0.6)
        cy = uniform(rng, 0.05, 0.12) + h / 2
    else:
        w, t = uniform(rng, 0.85, 1.0), uniform(rng, 0.068, 0.085)
        h = w * uniform(rng, 0.55, 0.68)
        cy = uniform(rng, 0.12, 0.25) + h / 2 if style == "monitor" else 0.0
    if style == "monitor":
        nw = uniform(rng, 0.08, 0.16)
        zn = t / 2 + 0.0275 - 0.005
        lean = uniform(rng, 0.0, 0.25)
        top = np.array([0.0, cy - h * 0.05, zn])
        foot_c = top + np.array([0.0, -top[1] + 0.05, math.tan(lean) * (top[1] - 0.05)])
        bar(b, foot_c, top, nw, 0.055)
        if nw > 0.1 and chance(rng, 0.6):  # a cable cut-out through the neck
            b.box((foot_c + top) / 2, (nw / 2 - 0.03, 0.05, 0.05), op="subtract")
    b.box((0, cy, 0), (w / 2, h / 2, t / 2), rounding=0.01)
    bz = uniform(rng, 0.025, 0.045)
    recess(b, -w / 2 + bz, w / 2 - bz, cy - h / 2 + bz * (1.6 if style == "tv" else 1.0), cy + h / 2 - bz, -t / 2,
            0.01)
    if style == "monitor":
        if chance(rng, 0.6):  # a housing bulge behind the panel
            b.box((0, cy, t / 2 + 0.02), (w * 0.3, h * 0.3, 0.03), rounding=0.01)
        if chance(rng, 0.5):
            b.box((0, 0.0275, foot_c[2] - 0.03), (uniform(rng, 0.15, 0.22), 0.0275, uniform(rng, 0.1, 0.13)), rounding=0.01)
        else:
            b.cylinder((0, 0.0275, foot_c[2] - 0.03), uniform(rng, 0.12, 0.17), 0.0275)
        return b.shape()
    if style == "tv":
        fx = w / 2 * uniform(rng, 0.6, 0.85)
        fz = uniform(rng, 0.09, 0.13)
        for s in (-1, 1):  # each foot an inverted V
            top = (s * fx, cy - h / 2 + 0.05, 0.0)
            bar(b, top, (s * fx, 0.0275, -fz), 0.06, 0.055)
            bar(b, top, (s * fx, 0.0275, fz), 0.06, 0.055)
        return b.shape()
    # wall: a bracket plate and an arm to the wall behind, sometimes a sound bar below
    b.box((0, 0, t / 2 + 0.0275), (w * 0.18, h * 0.2, 0.0275))
    b.box((0, 0, t / 2 + 0.07), (w * uniform(rng, 0.25, 0.35), h * uniform(rng, 0.25, 0.35), 0.0275))
    if chance(rng, 0.4):
        b.box((0, -h / 2 - 0.05, 0.0), (w * 0.4, 0.0325, 0.04), rounding=0.015)
    return b.shape()


STYLES = ('monitor', 'tv', 'wall', 'crt')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_display(*params)
