"""The procedural table (see ``make_table`` for its styles)."""
from __future__ import annotations

import math

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, legs, Y


def make_table(rng: np.random.Generator, style: str) -> CSGShape:
    """"legs": rectangular top, four legs, optional apron and stretchers (holes); "lower_shelf":
    four legs joined by a shelf below the top (holes); "pedestal": round or rectangular top on a
    column with a disc or cross foot; "round_legs": round top on 3-4 splayed legs, optional ring
    stretcher (a hole); "trestle": long top on two end frames joined by a stretcher (a hole)."""
    b = CSGBuilder()
    tw, tt = uniform(rng, 0.85, 1.0), uniform(rng, 0.055, 0.08)
    td = tw * uniform(rng, 0.5, 0.9)
    th = uniform(rng, 0.45, 0.75)
    round_top = style == "round_legs" or (style == "pedestal" and chance(rng, 0.7))
    if round_top:
        r = tw / 2 * uniform(rng, 0.85, 1.0)
        b.cylinder((0, th - tt / 2, 0), r, tt / 2)
    else:
        b.box((0, th - tt / 2, 0), (tw / 2, tt / 2, td / 2), rounding=0.01)
    if style == "pedestal":
        pr = uniform(rng, 0.05, 0.09)
        b.cylinder((0, th / 2, 0), pr, th / 2)
        if chance(rng, 0.5):
            b.cylinder((0, 0.03, 0), uniform(rng, 0.2, 0.3), 0.03)
        else:  # a cross of four feet
            fl = uniform(rng, 0.22, 0.32)
            a = uniform(rng, 0.0, math.pi / 2) if round_top else math.pi / 4
            for k in range(2):
                b.box((0, 0.035, 0), (fl, 0.035, 0.035), rotation(Y, a + k * math.pi / 2))
        return b.shape()
    if style == "round_legs":
        n = int(rng.integers(3, 5))
        lt = uniform(rng, 0.028, 0.038)
        r_top, r_bot = r * uniform(rng, 0.5, 0.65), r * uniform(rng, 0.6, 0.8)
        a0 = uniform(rng, 0.0, math.pi)
        for k in range(n):
            a = a0 + 2 * math.pi * k / n
            c, s = math.cos(a), math.sin(a)
            b.rod((r_bot * c, 0.0, r_bot * s), (r_top * c, th - tt + 0.005, r_top * s), lt)
        if chance(rng, 0.5):  # ring stretcher through the legs
            y = uniform(rng, 0.15, 0.3) * th
            rr = r_bot + (r_top - r_bot) * y / (th - tt)
            b.torus((0, y, 0), rr, 0.0275)
        return b.shape()
    if style == "trestle":
        px = tw / 2 - uniform(rng, 0.08, 0.14)
        pt = uniform(rng, 0.055, 0.075)
        fz = td / 2 * uniform(rng, 0.7, 0.9)
        for x in (-px, px):
            b.box((x, (th - tt) / 2, 0), (pt / 2, (th - tt) / 2, uniform(rng, 0.05, 0.08)))  # post
            b.box((x, 0.035, 0), (pt / 2 + 0.005, 0.035, fz), rounding=0.01)  # foot
            b.box((x, th - tt - 0.03, 0), (pt / 2, 0.03, fz))  # cleat under the top
        y = uniform(rng, 0.3, 0.6) * (th - tt)
        b.box((0, y, 0), (px, 0.035, 0.03))
        return b.shape()
    # legs, lower_shelf
    lt = uniform(rng, 0.055, 0.08)
    inset = uniform(rng, 0.0, 0.06)
    lx, lz = tw / 2 - lt / 2 - inset, td / 2 - lt / 2 - inset
    legs(b, (-lx, lx), (-lz, lz), th - tt, lt, chance(rng, 0.5))
    if chance(rng, 0.4):  # apron under the top
        ah = uniform(rng, 0.06, 0.1)
        y0 = th - tt - ah
        b.box_between((-lx, y0, -lz - 0.0275), (lx, th - tt, -lz + 0.0275))
        b.box_between((-lx, y0, lz - 0.0275), (lx, th - tt, lz + 0.0275))
    if style == "lower_shelf":
        y = uniform(rng, 0.08, 0.25)
        b.box((0, y, 0), (lx + lt / 2, 0.03, lz + lt / 2))
    elif chance(rng, 0.5):  # stretchers
        y = uniform(rng, 0.1, 0.25)
        for z in (-lz, lz):
            b.box_between((-lx, y - 0.0275, z - 0.0275), (lx, y + 0.0275, z + 0.0275))
        if chance(rng, 0.5):
            b.box_between((-0.0275, y - 0.0275, -lz), (0.0275, y + 0.0275, lz))
    return b.shape()


STYLES = ('legs', 'lower_shelf', 'pedestal', 'round_legs', 'trestle')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_table(*params)
