"""The procedural speaker (see ``make_speaker`` for its styles)."""
from __future__ import annotations

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, chance, frame, driver, Y, ALONG_X, ALONG_Z


def make_speaker(rng: np.random.Generator, style: str) -> CSGShape:
    """Drivers are conical dishes in the front (-z). "bookshelf": a box with a woofer and a
    tweeter, optional port and feet; "tower": tall and narrow, 2-4 drivers, on a plinth;
    "cylinder": a round speaker, upright or lying with drivers at both ends; "subwoofer": a cube
    with one big driver and feet."""
    b = CSGBuilder()
    if style == "cylinder":
        if chance(rng, 0.5):  # upright: a drum on a foot ring with a chamfered cap, drivers in front
            r, h = uniform(rng, 0.22, 0.32), uniform(rng, 0.6, 0.95)
            y0 = 0.04
            b.cylinder((0, y0 + h / 2, 0), r, h / 2)
            n = 1 if h < 0.8 else 2
            dr = r * uniform(rng, 0.5, 0.65)
            for k in range(n):
                driver(b, 0, y0 + h * (k + 1) / (n + 1), -r * 0.97, dr, uniform(rng, 0.05, 0.07))
            b.cone((0, y0 + h + 0.025, 0), 0.035, r, r * uniform(rng, 0.6, 0.8))
            b.cylinder((0, y0 / 2, 0), r * uniform(rng, 0.75, 0.9), y0 / 2 + 0.01)
        else:  # lying along x: passive radiators in both ends
            length, r = uniform(rng, 0.85, 1.0), uniform(rng, 0.16, 0.24)
            b.cylinder((0, r + 0.03, 0), r, length / 2, ALONG_X)
            for s in (-1, 1):
                b.cone((s * (length / 2 - 0.02), r + 0.03, 0), 0.03, r * 0.8, r * 0.35, frame((-s, 0, 0), Y),
                       op="subtract")
            for s in (-1, 1):
                b.torus((s * (length / 2 - 0.04), r + 0.03, 0), r, 0.03, ALONG_X)
            b.box((0, 0.03, 0), (length * 0.35, 0.03, r * 0.5), rounding=0.01)  # foot strip
        return b.shape()
    if style == "tower":
        w, h, d = uniform(rng, 0.22, 0.32), uniform(rng, 0.9, 1.0), uniform(rng, 0.3, 0.42)
    elif style == "subwoofer":
        w = uniform(rng, 0.6, 0.8)
        h, d = w * uniform(rng, 0.9, 1.1), w * uniform(rng, 0.9, 1.1)
    else:
        w, h, d = uniform(rng, 0.45, 0.6), uniform(rng, 0.75, 1.0), uniform(rng, 0.45, 0.7)
    feet = style == "subwoofer" or chance(rng, 0.4)
    y0 = 0.06 if feet else (0.05 if style == "tower" else 0.0)
    b.box((0, y0 + h / 2, 0), (w / 2, h / 2, d / 2), rounding=uniform(rng, 0.015, 0.04))
    front = -d / 2
    depth = uniform(rng, 0.05, 0.08)
    caps = []
    if style == "subwoofer":
        r = min(w, h) * uniform(rng, 0.32, 0.4)
        driver(b, 0, y0 + h / 2, front, r, depth)
        caps.append((0, y0 + h / 2, r))
        if chance(rng, 0.5):
            b.box((0, y0 + 0.06, front), (w * 0.3, 0.025, 0.05), op="subtract")  # port slot
    elif style == "tower":
        n = int(rng.integers(2, 5))
        r = w * uniform(rng, 0.32, 0.4)
        tw = uniform(rng, 0.04, 0.055)
        ys = [y0 + h - 0.08 - tw]
        y = ys[0] - tw - 0.04 - r
        for _ in range(n):
            if y - r < y0 + 0.08:
                break
            driver(b, 0, y, front, r, depth)
            caps.append((0, y, r))
            y -= 2 * r + 0.05
        driver(b, 0, ys[0], front, tw, 0.04)
    else:  # bookshelf
        r = w * uniform(rng, 0.3, 0.38)
        yw = y0 + h * uniform(rng, 0.3, 0.4)
        driver(b, 0, yw, front, r, depth)
        caps.append((0, yw, r))
        tw = uniform(rng, 0.05, 0.07)
        driver(b, 0, min(y0 + h - tw - 0.06, yw + r + tw + 0.08), front, tw, 0.04)
        if chance(rng, 0.4):
            b.cylinder((0, y0 + 0.07, front), 0.04, 0.06, ALONG_Z, op="subtract")  # port
    for x, y, r in caps:
        b.sphere((x, y, front + depth * 0.8), max(r * 0.3, 0.03))  # dust cap
    if style == "tower":
        b.box((0, 0.0275, 0), (w / 2 + 0.04, 0.0275, d / 2 + 0.04), rounding=0.01)  # plinth
    elif feet:
        fx, fz = w / 2 - 0.06, d / 2 - 0.06
        for x in (-fx, fx):
            for z in (-fz, fz):
                b.cylinder((x, 0.035, z), 0.035, 0.035)
    return b.shape()


STYLES = ('bookshelf', 'tower', 'cylinder', 'subwoofer')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_speaker(*params)
