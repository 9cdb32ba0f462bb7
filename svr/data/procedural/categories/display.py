"""The procedural display: a screen facing -z, a recess (part "screen") inside a bezel with a chin,
on a stand. "monitor": aspect 1.2-2.4, panel 0.055-0.13 thick and tilted back 0-20 degrees, maybe a
housing behind, on a neck (straight or leaning, 0.1-0.45 of the height up) over a rectangular,
round or two-prong foot; "tv": aspect 1.5-2, on two feet (blades, inverted Vs or splayed legs) or a
central pedestal, or on a low console; "wall": a flat slab with a bracket behind, maybe a sound bar
below; "crt": a deep tube (depth 0.6-1.3 times the width) tapering back as two stepped boxes or a
cone, on a swivel foot or none. Every draw is in ``sample``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, chance, bar, frame, X, ALONG_Z

STYLES = ("monitor", "tv", "wall", "crt")
FEET = ("rect", "disc", "prongs")
TV_STANDS = ("blades", "vees", "splayed", "pedestal", "console")


@dataclass(frozen=True)
class DisplayParams:
    style: str
    width: float            # the panel (x)
    height: float           # the panel (y)
    thick: float            # the panel (z)
    tilt: float             # radians, the top leaning back
    bezel: float
    chin: float             # extra bezel at the bottom
    recess: float           # the screen's depth into the panel
    housing: tuple[float, float, float]  # a box behind the panel: width, height shares and depth; 0: none
    lift: float             # the panel's bottom above the floor
    stand: str              # monitor: FEET; tv: TV_STANDS; wall: "bracket"; crt: "swivel" or "none"
    neck_width: float
    lean: float             # monitor: the neck's lean back (radians)
    foot: tuple[float, float]  # foot or stand half width, half depth
    spread: float           # tv: feet apart, share of the half width
    soundbar: bool
    tube_depth: float       # crt: the tube behind the front box
    tube_round: bool        # crt: a cone, else two stepped boxes
    tube_scale: tuple[float, float]  # crt: the tube's sizes (shares of the front)


def sample(rng: np.random.Generator, style: str) -> DisplayParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    aspect = {"monitor": uniform(rng, 1.2, 2.4), "tv": uniform(rng, 1.5, 2.0), "wall": uniform(rng, 1.3, 2.2),
              "crt": uniform(rng, 1.05, 1.4)}[style]
    w = 1.0 if style != "crt" else uniform(rng, 0.6, 0.8)
    h = w / aspect
    thick = {"monitor": uniform(rng, 0.055, 0.13), "tv": uniform(rng, 0.055, 0.1), "wall": uniform(rng, 0.055, 0.09),
             "crt": uniform(rng, 0.08, 0.2)}[style]
    housing = (0.0, 0.0, 0.0)
    if style != "crt" and chance(rng, 0.5):
        housing = (uniform(rng, 0.3, 0.9), uniform(rng, 0.3, 0.8), uniform(rng, 0.055, 0.16))
    stand = {"monitor": str(rng.choice(FEET)), "tv": str(rng.choice(TV_STANDS)), "wall": "bracket",
             "crt": "swivel" if chance(rng, 0.7) else "none"}[style]
    lift = {"monitor": uniform(rng, 0.1, 0.45) * h + 0.055, "tv": uniform(rng, 0.04, 0.25) * h + 0.03,
            "wall": 0.0, "crt": uniform(rng, 0.055, 0.12) if stand == "swivel" else 0.0}[style]
    if stand == "console":
        lift = uniform(rng, 0.25, 0.6) * h
    k = min(1.0, 1.0 / (lift + h))  # the longest side at most 1
    w, h, lift = w * k, h * k, lift * k
    return DisplayParams(
        style=style, width=w, height=h, thick=thick,
        tilt={"monitor": uniform(rng, 0.0, 0.35), "crt": uniform(rng, 0.0, 0.12), "tv": uniform(rng, 0.0, 0.1),
              "wall": uniform(rng, -0.2, 0.25)}[style],
        bezel=uniform(rng, 0.02, 0.07), chin=uniform(rng, 0.0, 0.1) if chance(rng, 0.5) else 0.0,
        recess=uniform(rng, 0.01, 0.03), housing=housing, lift=lift, stand=stand,
        neck_width=uniform(rng, 0.07, 0.2), lean=uniform(rng, 0.0, 0.4) if chance(rng, 0.6) else 0.0,
        foot=(uniform(rng, 0.12, 0.35), uniform(rng, 0.08, 0.22)), spread=uniform(rng, 0.45, 0.9),
        soundbar=style in ("wall", "tv") and chance(rng, 0.3),
        tube_depth=min(uniform(rng, 0.6, 1.3) * w, 1.0 - thick) if style == "crt" else 0.0, tube_round=chance(rng, 0.35),
        tube_scale=(uniform(rng, 0.6, 0.98), uniform(rng, 0.3, 0.7)))


def _panel(b: CSGBuilder, p: DisplayParams, bottom: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The panel standing on ``bottom`` (its bottom edge's middle, front face), leaning back by the
    tilt; returns (its centre, up, back) directions."""
    up = np.array([0.0, math.cos(p.tilt), math.sin(p.tilt)])
    back = np.array([0.0, -math.sin(p.tilt), math.cos(p.tilt)])
    rot = frame(up, X)
    c = bottom + up * p.height / 2 + back * p.thick / 2
    b.part("body")
    b.box(c, (p.width / 2, p.height / 2, p.thick / 2), rot, rounding=0.01)
    hw, hh, hd = p.housing
    if hd > 0:
        b.box(c + back * (p.thick / 2 + hd / 2 - 0.01) + up * 0.0, (hw * p.width / 2, hh * p.height / 2, hd / 2 + 0.01),
              rot, rounding=0.02)
    b.part("screen")
    sh = p.height - 2 * p.bezel - p.chin
    sc = bottom + up * (p.bezel + p.chin + sh / 2)
    b.box(sc, (p.width / 2 - p.bezel, sh / 2, p.recess), rot, op="subtract")
    return c, up, back


def build(p: DisplayParams) -> CSGShape:
    b = CSGBuilder()
    w, h, t = p.width, p.height, p.thick
    if p.style == "crt":
        return _crt(b, p)
    bottom = np.array([0.0, p.lift, -t / 2])
    c, up, back = _panel(b, p, bottom)
    b.part("stand")
    fw, fd = p.foot
    if p.style == "monitor":
        # the neck from the back of the panel down to the foot, leaning back
        top = c + back * (t / 2 + (p.housing[2] if p.housing[2] > 0 else 0.0)) - up * h * 0.1
        foot = np.array([0.0, 0.0275, top[2] + math.tan(p.lean) * top[1]])
        bar(b, foot, top, p.neck_width, 0.055)
        fz = foot[2] - fd * 0.4
        if p.stand == "rect":
            b.box((0, 0.0275, fz), (fw, 0.0275, fd), rounding=0.01)
        elif p.stand == "disc":
            b.cylinder((0, 0.0275, fz), max(fw, fd), 0.0275)
        else:  # two prongs spreading forward
            for s in (-1, 1):
                bar(b, foot, (s * fw * 1.2, 0.0275, foot[2] - 2 * fd), 0.06, 0.055, x_hint=(0, 1, 0))
    elif p.style == "tv":
        xf = p.spread * w / 2
        yb = p.lift + 0.02
        if p.stand == "blades":
            for s in (-1, 1):
                b.box((s * xf, yb / 2 + 0.02, 0.0), (0.0275, yb / 2 + 0.02, fd), rounding=0.01)
        elif p.stand == "vees":
            for s in (-1, 1):
                bar(b, (s * xf, yb + 0.03, 0), (s * xf, 0.0275, -fd), 0.06, 0.055)
                bar(b, (s * xf, yb + 0.03, 0), (s * xf, 0.0275, fd), 0.06, 0.055)
        elif p.stand == "splayed":
            for s in (-1, 1):
                bar(b, (s * xf * 0.8, yb + 0.03, 0), (s * (xf + fw * 0.5), 0.0275, -fd * 0.3), 0.06, 0.055)
        elif p.stand == "pedestal":
            b.box((0, yb / 2 + 0.02, t / 2), (p.neck_width / 2 + 0.02, yb / 2 + 0.02, 0.04))
            b.box((0, 0.0275, t / 2), (fw * 1.3, 0.0275, fd), rounding=0.01)
        else:  # a low console under it
            b.box((0, p.lift / 2, t / 2), (w / 2 * p.spread + 0.05, p.lift / 2, max(fd * 1.4, 0.12)), rounding=0.01)
        if p.soundbar and p.stand == "console":  # a sound bar on the console in front of the screen
            b.part("soundbar")
            zc = t / 2 - max(fd * 1.4, 0.12) + 0.045
            b.box((0, p.lift + 0.035, zc), (w * 0.35, 0.04, 0.04), rounding=0.015)
    else:  # wall: a bracket and an arm behind, maybe a sound bar below
        b.box(c + back * (t / 2 + 0.06), (w * 0.15, h * 0.2, 0.06))
        b.box(c + back * (t / 2 + 0.12), (w * fw, h * 0.3, 0.0275))
        if p.soundbar:
            b.part("soundbar")
            b.box((0, -0.09, 0.0), (w * 0.4, 0.04, 0.045), rounding=0.015)
            b.box((0, -0.03, 0.02), (w * 0.05, 0.04, 0.0275))
    return b.shape()


def _crt(b: CSGBuilder, p: DisplayParams) -> CSGShape:
    w, h, t = p.width, p.height, p.thick
    y0 = p.lift
    bottom = np.array([0.0, y0, -t / 2])
    c, up, back = _panel(b, p, bottom)
    b.part("body")
    a, s2 = p.tube_scale
    dd = p.tube_depth
    z0 = c[2] + t / 2 - 0.01
    cy = c[1] + h * 0.03
    if p.tube_round:
        b.cone((0, cy, z0 + dd / 2), dd / 2, a * min(w, h) / 2 * 1.1, s2 * min(w, h) / 2, ALONG_Z)
    else:
        b.box((0, cy, z0 + dd * 0.25), (w * a / 2, h * a / 2, dd * 0.25), rounding=0.03)
        b.box((0, cy + h * 0.03, z0 + dd * 0.7), (w * s2 / 2, h * s2 / 2, dd * 0.2 + 0.02), rounding=0.03)
    if p.stand == "swivel":
        b.part("stand")
        zc = bottom[2] + t / 2  # under the panel's bottom edge
        b.cylinder((0, y0 / 2 + 0.02, zc), p.foot[1] * 0.6 + 0.03, y0 / 2 + 0.02)
        b.cylinder((0, 0.0275, zc), p.foot[0] * 0.8 + 0.05, 0.0275)
    return b.shape()
