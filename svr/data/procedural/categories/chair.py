"""The procedural chair (see ``make_chair`` for its styles)."""
from __future__ import annotations

import math

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, bar, legs, X, Y


def _four_leg_chair(rng: np.random.Generator, style: str) -> CSGShape:
    b = CSGBuilder()
    sw, sd, st = uniform(rng, 0.42, 0.54), uniform(rng, 0.4, 0.5), uniform(rng, 0.055, 0.08)
    sh = uniform(rng, 0.38, 0.46)
    lt = uniform(rng, 0.055, 0.07)
    inset = uniform(rng, 0.0, 0.03)
    lx, lz = sw / 2 - lt / 2 - inset, sd / 2 - lt / 2 - inset
    legs(b, (-lx, lx), (-lz, lz), sh, lt, chance(rng, 0.5))
    b.box((0, sh + st / 2, 0), (sw / 2, st / 2, sd / 2), rounding=0.01)
    if style != "four_legs" and chance(rng, 0.4):  # side stretchers: loops with two legs and the seat
        y = uniform(rng, 0.08, 0.2)
        for x in (-lx, lx):
            b.box_between((x - 0.0275, y - 0.0275, -lz), (x + 0.0275, y + 0.0275, lz))
    # the back, built upright at the seat's rear edge and tilted backwards about the x axis
    bh, bt = uniform(rng, 0.36, 0.5), uniform(rng, 0.055, 0.07)
    tilt = uniform(rng, 0.0, 0.22)
    pivot = np.array([0.0, sh + st, sd / 2 - bt / 2])
    rot = rotation(X, -tilt)  # top towards +z

    def back_box(lo, hi):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        b.box(pivot + rot @ ((lo + hi) / 2), np.abs(hi - lo) / 2, rot)

    if style == "four_legs":
        back = "solid"
    elif style == "slatted":
        back = "slats" if chance(rng, 0.6) else "rails"
    else:
        back = ("solid", "slats", "rails")[int(rng.integers(0, 3))]
    if back == "solid":
        back_box((-sw / 2, 0, -bt / 2), (sw / 2, bh, bt / 2))
    else:
        pw = uniform(rng, 0.055, 0.07)
        rail = uniform(rng, 0.06, 0.1)
        back_box((-sw / 2, 0, -bt / 2), (-sw / 2 + pw, bh, bt / 2))
        back_box((sw / 2 - pw, 0, -bt / 2), (sw / 2, bh, bt / 2))
        back_box((-sw / 2, bh - rail, -bt / 2), (sw / 2, bh, bt / 2))
        inner = sw - 2 * pw
        if back == "slats":
            w = 0.055
            n = int(rng.integers(1, 1 + max(1, min(3, int((inner - 0.04) / (w + 0.04))))))
            for k in range(n):
                x = -inner / 2 + inner * (k + 1) / (n + 1)
                back_box((x - w / 2, 0, -0.0275), (x + w / 2, bh - rail, 0.0275))
        else:
            n = int(rng.integers(1, 3))
            for k in range(n):
                y = (bh - rail) * (k + 1) / (n + 1)
                back_box((-sw / 2 + pw, y - 0.03, -0.0275), (sw / 2 - pw, y + 0.03, 0.0275))
    if style == "armchair":  # rest + front post: each a loop with the seat and the back
        ah = uniform(rng, 0.17, 0.25)
        z_back = sd / 2 - bt + (ah + 0.03) * math.tan(tilt) + bt / 2
        for x in (-sw / 2 + 0.03, sw / 2 - 0.03):
            b.box_between((x - 0.035, sh + st + ah - 0.055, -sd / 2 + 0.01), (x + 0.035, sh + st + ah, z_back))
            b.box_between((x - 0.0275, sh + st, -sd / 2 + 0.03), (x + 0.0275, sh + st + ah, -sd / 2 + 0.085))
    return b.shape()


def _swivel_chair(rng: np.random.Generator) -> CSGShape:
    b = CSGBuilder()
    foot_r = uniform(rng, 0.24, 0.3)
    casters = chance(rng, 0.6)
    y_hub = uniform(rng, 0.09, 0.12)
    y_end = 0.065 if casters else 0.03
    a0 = uniform(rng, 0.0, 2 * math.pi / 5)
    for k in range(5):
        a = a0 + 2 * math.pi * k / 5
        end = (foot_r * math.cos(a), y_end, foot_r * math.sin(a))
        bar(b, (0, y_hub, 0), end, 0.055, 0.06, Y)
        if casters:
            b.sphere((end[0], 0.035, end[2]), 0.035)
    b.cylinder((0, y_hub, 0), uniform(rng, 0.045, 0.055), 0.04)
    sw, sd, st = uniform(rng, 0.44, 0.52), uniform(rng, 0.42, 0.5), uniform(rng, 0.07, 0.1)
    sh = uniform(rng, 0.4, 0.46)
    b.cylinder((0, (y_hub + sh) / 2, 0), uniform(rng, 0.03, 0.04), (sh - y_hub) / 2)
    b.box((0, sh - 0.03, 0), (uniform(rng, 0.07, 0.1), 0.03, uniform(rng, 0.07, 0.1)))
    b.box((0, sh + st / 2, 0), (sw / 2, st / 2, sd / 2), rounding=0.03)
    # back on a support bar behind the seat, with a gap between seat and back
    gap, bh, bt = uniform(rng, 0.03, 0.08), uniform(rng, 0.32, 0.45), uniform(rng, 0.06, 0.08)
    bw = uniform(rng, 0.8, 1.0) * sw
    zb = sd / 2 + 0.0275
    y_back = sh + st + gap
    b.box((0, sh + 0.0275 - 0.01, sd / 4 + 0.0275), (0.04, 0.0275, sd / 4 + 0.0275))
    b.box((0, (sh + y_back + 0.1) / 2, zb), (0.04, (y_back + 0.1 - sh) / 2, 0.0275))
    tilt = uniform(rng, 0.0, 0.2)
    rot = rotation(X, -tilt)
    b.box(np.array([0.0, y_back, zb + 0.0275 + bt / 2 - 0.01]) + rot @ np.array([0.0, bh / 2, 0.0]),
          (bw / 2, bh / 2, bt / 2), rot, rounding=0.03)
    if chance(rng, 0.5):  # arms: a post on each side of the seat and a pad on top
        ah = uniform(rng, 0.17, 0.24)
        for s in (-1, 1):
            x = s * (sw / 2 + 0.01)
            b.box((x, sh + (st + ah) / 2, 0.02), (0.0275, (st + ah) / 2, 0.035))
            b.box((x, sh + st + ah, 0.0), (0.04, 0.0275, uniform(rng, 0.1, 0.14)), rounding=0.015)
    return b.shape()


def make_chair(rng: np.random.Generator, style: str) -> CSGShape:
    """Seat at about 0.4 with the back at +z. "four_legs": solid back, no arms (genus 0);
    "slatted": back of posts with vertical slats or horizontal rails, optional side stretchers
    (holes); "armchair": four legs, any back, arms that make loops with seat and back; "swivel":
    office chair, seat and back on a column over a five-spoke base, optional casters and arms."""
    if style == "swivel":
        return _swivel_chair(rng)
    return _four_leg_chair(rng, style)


STYLES = ('four_legs', 'slatted', 'armchair', 'swivel')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_chair(*params)
