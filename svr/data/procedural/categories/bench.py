"""The procedural bench (see ``make_bench`` for its styles)."""
from __future__ import annotations

import math

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, bar, legs, X, ALONG_X


def make_bench(rng: np.random.Generator, style: str) -> CSGShape:
    """A long seat along x. "park": slatted seat and back on two side frames, optional armrests
    (holes between the slats and in the frames); "panel": solid seat on end panels with cut-outs,
    optional panel back; "backless": seat on four legs with an optional stretcher; "rail_back":
    four legs, back posts and 1-3 rails."""
    b = CSGBuilder()
    bw, sh = uniform(rng, 0.9, 1.0), uniform(rng, 0.36, 0.45)
    if style == "park":
        sh = uniform(rng, 0.3, 0.36)  # a park bench is long and low
        sd, st = uniform(rng, 0.32, 0.4), uniform(rng, 0.055, 0.065)
        gap = uniform(rng, 0.035, 0.05)
        n = int(rng.integers(3, 1 + int((sd + gap) / (0.065 + gap))))
        sw = (sd - (n - 1) * gap) / n
        for k in range(n):
            z = -sd / 2 + sw / 2 + k * (sw + gap)
            b.box((0, sh - st / 2, z), (bw / 2, st / 2, sw / 2), rounding=0.008)
        px = bw / 2 - uniform(rng, 0.06, 0.14)
        bh, lean = uniform(rng, 0.24, 0.32), uniform(rng, 0.1, 0.3)
        ft = uniform(rng, 0.06, 0.075)
        arms = chance(rng, 0.6)
        z_back = sd / 2
        top = np.array([0.0, sh + bh, z_back + bh * math.tan(lean)])
        for x in (-px, px):
            b.box((x, (sh - st) / 2, -sd / 2 + ft / 2 + 0.02), (ft / 2, (sh - st) / 2, ft / 2))  # front leg
            bar(b, (x, 0.0, z_back - ft / 2), (x, sh - st, z_back - ft / 2), ft, ft)  # back leg
            bar(b, (x, sh - st - 0.01, z_back - ft / 2), top + (x, 0, 0), ft, ft)  # back support
            b.box((x, sh - st - ft / 2, 0), (ft / 2, ft / 2, sd / 2))  # seat rail
            if arms:
                ay = sh + uniform(rng, 0.14, 0.19)
                za = z_back + (ay - sh) * math.tan(lean)
                b.box((x, ay, (-sd / 2 + za) / 2), (ft / 2 + 0.01, 0.03, (za + sd / 2) / 2 + 0.02))
                b.box((x, (sh + ay) / 2, -sd / 2 + ft / 2 + 0.02), (ft / 2, (ay - sh) / 2, ft / 2))
        nb = int(rng.integers(2, 4)) if bh > 0.29 else 2  # back slats, with gaps between them
        rot = rotation(X, -lean)
        bs = (bh - 0.06) / nb
        slat = max(0.6 * bs, 0.06)
        for k in range(nb):
            h = 0.08 + k * bs + slat / 2
            c = np.array([0.0, sh, z_back]) + rot @ np.array([0.0, h, 0.03])
            b.box(c, (bw / 2, slat / 2, 0.0275), rot, rounding=0.008)
        return b.shape()

    bd, st = uniform(rng, 0.3, 0.42), uniform(rng, 0.055, 0.075)
    b.box((0, sh + st / 2, 0), (bw / 2, st / 2, bd / 2), rounding=0.01)
    px = bw / 2 - uniform(rng, 0.04, 0.12)
    if style == "panel":
        pt = uniform(rng, 0.055, 0.07)
        for x in (-px, px):
            b.box((x, sh / 2, 0), (pt / 2, sh / 2, bd / 2 - 0.01))
        cut_w = uniform(rng, 0.08, 0.11)
        arch = chance(rng, 0.5)
        for x in (-px, px):
            if arch:  # a round-topped opening
                r = bd / 2 - cut_w
                b.cylinder((x, sh - cut_w - r, 0), r, pt, ALONG_X, op="subtract")
                b.box((x, (sh - cut_w - r) / 2 - 0.02, 0), (pt, (sh - cut_w - r) / 2 + 0.02, r), op="subtract")
            else:
                b.box((x, sh / 2 - 0.02, 0), (pt, sh / 2 - cut_w, bd / 2 - cut_w), op="subtract")
        if chance(rng, 0.5):  # solid back panel, set on the seat's rear edge
            bh = uniform(rng, 0.22, 0.35)
            b.box((0, sh + st + bh / 2, bd / 2 - 0.03), (bw / 2 - 0.02, bh / 2, 0.03), rotation(X, -0.12))
        return b.shape()

    lt = uniform(rng, 0.055, 0.075)
    lz = bd / 2 - lt / 2 - uniform(rng, 0.0, 0.04)
    legs(b, (-px, px), (-lz, lz), sh, lt, chance(rng, 0.5))
    if style == "backless":
        if chance(rng, 0.6):  # H stretcher: loops through the legs and the seat
            y = uniform(rng, 0.08, 0.18)
            b.box((0, y, 0), (px, 0.03, 0.03))
            for x in (-px, px):
                b.box((x, y, 0), (0.03, 0.03, lz))
        return b.shape()
    # rail_back
    bh = uniform(rng, 0.25, 0.4)
    z = bd / 2 - 0.035
    for x in (-px, px):
        b.box_between((x - 0.03, sh + st, z - 0.03), (x + 0.03, sh + st + bh, z + 0.03))
    n = int(rng.integers(1, 4))
    for k in range(n):
        y = sh + st + bh - 0.04 - k * (bh - 0.06) / n
        b.box_between((-bw / 2 + 0.02, y - 0.03, z - 0.0275), (bw / 2 - 0.02, y + 0.03, z + 0.0275))
    return b.shape()


STYLES = ('park', 'panel', 'backless', 'rail_back')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_bench(*params)
