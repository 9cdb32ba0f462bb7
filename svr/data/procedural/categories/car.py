"""The procedural car (see ``make_car`` for its styles)."""
from __future__ import annotations

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, cut_beyond, X, ALONG_X


def make_car(rng: np.random.Generator, style: str) -> CSGShape:
    """Length along z, bonnet to -z, four wheels in arches. "sedan": bonnet, cabin, boot;
    "wagon": the cabin runs to an upright tailgate; "pickup": a short cab and an open bed; "suv":
    tall, big wheels, boxy; "sports": low and wide, fastback."""
    b = CSGBuilder()
    length = uniform(rng, 0.95, 1.0)
    width = uniform(rng, 0.44, 0.48) if style == "sports" else uniform(rng, 0.4, 0.46)
    big = style in ("suv", "pickup")
    rw = uniform(rng, 0.078, 0.092) if big else (uniform(rng, 0.062, 0.072) if style == "sports" else uniform(rng, 0.066, 0.08))
    yb = rw * (uniform(rng, 0.5, 0.7) if big else uniform(rng, 0.35, 0.5))  # body bottom
    if style == "sports":
        bh, ch = uniform(rng, 0.1, 0.13), uniform(rng, 0.08, 0.1)
        zc0, zc1 = uniform(rng, -0.12, -0.02), uniform(rng, 0.22, 0.3)
        run_f, run_r = uniform(rng, 0.18, 0.24), uniform(rng, 0.16, 0.24)
    elif style == "suv":
        bh, ch = uniform(rng, 0.16, 0.2), uniform(rng, 0.13, 0.17)
        zc0, zc1 = uniform(rng, -0.2, -0.12), length / 2 - uniform(rng, 0.03, 0.06)
        run_f, run_r = uniform(rng, 0.1, 0.15), uniform(rng, 0.02, 0.06)
    elif style == "wagon":
        bh, ch = uniform(rng, 0.13, 0.16), uniform(rng, 0.11, 0.14)
        zc0, zc1 = uniform(rng, -0.2, -0.12), length / 2 - uniform(rng, 0.03, 0.06)
        run_f, run_r = uniform(rng, 0.12, 0.17), uniform(rng, 0.03, 0.07)
    elif style == "pickup":
        bh, ch = uniform(rng, 0.15, 0.18), uniform(rng, 0.11, 0.14)
        zc0, zc1 = uniform(rng, -0.18, -0.1), uniform(rng, 0.05, 0.12)
        run_f, run_r = uniform(rng, 0.08, 0.12), 0.0
    else:  # sedan
        bh, ch = uniform(rng, 0.13, 0.16), uniform(rng, 0.1, 0.13)
        zc0, zc1 = uniform(rng, -0.2, -0.12), uniform(rng, 0.18, 0.26)
        run_f, run_r = uniform(rng, 0.12, 0.18), uniform(rng, 0.1, 0.16)
    arch = rw + 0.012
    bed = uniform(rng, 0.06, 0.08)
    # the arches must stay inside the body (and under the bed's floor), or they cut it through
    yt = max(yb + bh, rw + arch + uniform(rng, 0.065, 0.085) + (bed + 0.02 if style == "pickup" else 0.0))
    tumble = uniform(rng, 0.02, 0.04)
    # the cabin first: its sloped windows are cuts that must not reach the body
    b.box((0, yt + (ch - 0.03) / 2, (zc0 + zc1) / 2), (width / 2 - tumble, (ch + 0.03) / 2, (zc1 - zc0) / 2),
          rounding=0.02)
    cut_beyond(b, (0, yt, zc0), (0, yt + ch, zc0 + run_f), X, (0, 0.3, -1), width / 2, margin=0.1)
    if run_r > 0:
        cut_beyond(b, (0, yt, zc1), (0, yt + ch, zc1 - run_r), X, (0, 0.3, 1), width / 2, margin=0.1)
    wy = yt + ch * 0.5
    wz0, wz1 = zc0 + run_f * 0.75 + 0.03, zc1 - run_r * 0.75 - 0.03
    if wz1 - wz0 > 0.1:  # side windows: shallow recesses that outline the glass in a render
        for s in (-1, 1):
            b.box((s * (width / 2 - tumble), wy, (wz0 + wz1) / 2), (0.012, ch * 0.25, (wz1 - wz0) / 2), op="subtract")
    b.box((0, (yb + yt) / 2, 0), (width / 2, (yt - yb) / 2, length / 2), rounding=uniform(rng, 0.03, 0.05))
    if style in ("sedan", "sports", "wagon"):  # bonnet sloping down to the nose
        cut_beyond(b, (0, yt - uniform(rng, 0.03, 0.05), -length / 2), (0, yt, -length / 2 + 0.3), X, (0, 1, -0.2),
                    width / 2 + 0.01, margin=0.05)
    zf, zr = -length / 2 + arch + uniform(rng, 0.07, 0.11), length / 2 - arch - uniform(rng, 0.07, 0.12)
    for z in (zf, zr):
        b.cylinder((0, rw, z), arch, width / 2 + 0.05, ALONG_X, op="subtract")
    if style == "pickup":
        b.box_between((-width / 2 + 0.06, yt - bed, zc1 + 0.06),
                      (width / 2 - 0.06, yt + 0.1, length / 2 - 0.06), op="subtract")
    ww = uniform(rng, 0.06, 0.075)
    for z in (zf, zr):
        for s in (-1, 1):
            b.cylinder((s * (width / 2 - ww / 2 - 0.005), rw, z), rw, ww / 2, ALONG_X)
    return b.shape()


STYLES = ('sedan', 'wagon', 'pickup', 'suv', 'sports')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_car(*params)
