"""The procedural cabinet (see ``make_cabinet`` for its styles)."""
from __future__ import annotations

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, chance, legs, recess


def make_cabinet(rng: np.random.Generator, style: str) -> CSGShape:
    """A box with its front to -z. "doors": 1-3 doors with handles, on a plinth or legs;
    "open_shelves": compartments open at the front (and maybe the back: holes); "drawers": a chest
    of stacked drawers with knobs; "sideboard": wide and low on legs, drawers over doors."""
    b = CSGBuilder()
    if style == "sideboard":
        w, h, d = uniform(rng, 0.95, 1.05), uniform(rng, 0.4, 0.55), uniform(rng, 0.35, 0.45)
    elif style == "drawers":
        w, h, d = uniform(rng, 0.55, 0.9), uniform(rng, 0.6, 1.0), uniform(rng, 0.35, 0.5)
    else:
        w, h, d = uniform(rng, 0.5, 1.0), uniform(rng, 0.6, 1.0), uniform(rng, 0.3, 0.5)
    on_legs = style == "sideboard" or chance(rng, 0.35)
    base = uniform(rng, 0.1, 0.2) if on_legs else uniform(rng, 0.05, 0.08)
    y0 = base
    b.box((0, (y0 + h) / 2, 0), (w / 2, (h - y0) / 2, d / 2))
    front = -d / 2
    gap, groove = 0.022, 0.02
    if style == "open_shelves":
        t = uniform(rng, 0.055, 0.065)
        rows, cols = int(rng.integers(2, 5)), int(rng.integers(1, 4 if w > 0.7 else 3))
        open_back = chance(rng, 0.4)
        cw = (w - (cols + 1) * t) / cols
        chh = (h - y0 - (rows + 1) * t) / rows
        z1 = d / 2 + 0.1 if open_back else d / 2 - t
        for i in range(rows):
            for j in range(cols):
                x0 = -w / 2 + t + j * (cw + t)
                yy = y0 + t + i * (chh + t)
                b.box_between((x0, yy, front - 0.1), (x0 + cw, yy + chh, z1), op="subtract")
    elif style == "doors":
        n = 1 if w < 0.6 else (2 if w < 0.9 or chance(rng, 0.6) else 3)
        dw = w / n
        for k in range(1, n):
            x = -w / 2 + k * dw
            b.box((x, (y0 + h) / 2, front), (gap / 2, (h - y0) / 2 - 0.03, groove), op="subtract")
        if chance(rng, 0.5):  # framed door panels
            for k in range(n):
                x0 = -w / 2 + k * dw
                recess(b, x0 + 0.06, x0 + dw - 0.06, y0 + 0.07, h - 0.07, front, 0.012)
        hl = uniform(rng, 0.1, 0.2)
        hy = (y0 + h) / 2 + uniform(rng, 0.0, 0.15) * (h - y0)
        for k in range(n):
            # a handle on each door's edge next to its neighbour (the side it opens from)
            x = -w / 2 + (k + (0.0 if k % 2 else 1.0)) * dw + (0.06 if k % 2 else -0.06)
            if n == 1:
                x = w / 2 - 0.07
            b.box((x, hy, front), (0.0275, hl / 2, 0.045), rounding=0.01)
    else:  # drawers, sideboard
        if style == "drawers":
            rows = int(rng.integers(3, 6))
            cols = 2 if w > 0.75 and chance(rng, 0.5) else 1
            ys = np.linspace(y0, h, rows + 1)
        else:
            rows = 1
            cols = int(rng.integers(2, 4))
            ys = np.array([h - uniform(rng, 0.12, 0.16), h])
        for y in ys[1:-1]:
            b.box((0, y, front), (w / 2 - 0.03, gap / 2, groove), op="subtract")
        if style == "sideboard":  # the line under the drawers, and doors below it
            b.box((0, ys[0], front), (w / 2 - 0.03, gap / 2, groove), op="subtract")
        for k in range(1, cols):
            x = -w / 2 + k * w / cols
            b.box((x, (ys[0] + ys[-1]) / 2, front), (gap / 2, (ys[-1] - ys[0]) / 2 - 0.01, groove), op="subtract")
        if style == "sideboard":
            for k in range(1, cols):
                x = -w / 2 + k * w / cols
                b.box((x, (y0 + ys[0]) / 2, front), (gap / 2, (ys[0] - y0) / 2 - 0.03, groove), op="subtract")
        knob_r = uniform(rng, 0.028, 0.035)
        for i in range(rows):
            for j in range(cols):
                x = -w / 2 + (j + 0.5) * w / cols
                b.sphere((x, (ys[i] + ys[i + 1]) / 2, front - 0.01), knob_r)
        if style == "sideboard":
            for j in range(cols):
                x = -w / 2 + (j + 0.5) * w / cols + 0.5 * w / cols - 0.06
                b.box((x, ys[0] - 0.1, front), (0.0275, 0.06, 0.045), rounding=0.01)
    if on_legs:
        lt = uniform(rng, 0.055, 0.07)
        inset = uniform(rng, 0.0, 0.04)
        legs(b, (-w / 2 + lt / 2 + inset, w / 2 - lt / 2 - inset), (-d / 2 + lt / 2 + inset, d / 2 - lt / 2 - inset),
              y0 + 0.01, lt, chance(rng, 0.4))
    else:
        b.box((0, y0 / 2, 0.01), (w / 2 - 0.03, y0 / 2 + 0.005, d / 2 - 0.03))  # plinth
    if style != "open_shelves" and chance(rng, 0.5):  # a top that overhangs
        b.box((0, h + 0.0275, 0), (w / 2 + 0.02, 0.0275, d / 2 + 0.02), rounding=0.01)
    return b.shape()


STYLES = ('doors', 'open_shelves', 'drawers', 'sideboard')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_cabinet(*params)
