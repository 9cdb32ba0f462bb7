"""The procedural display: a panel facing -z with a screen recess (part "screen") inside a bezel of
0.02-0.07 and a chin of 0-0.1, maybe a housing behind it. "monitor": aspect 1.2-2.4, 0.055-0.13
thick, tilted back 0-20 degrees, on a neck (leaning back 0-23 degrees, maybe with a cable cut-out:
a hole) over a rectangular, round or two-prong foot, the panel 0.1-0.45 of its height up; "arm":
such a panel on an arm reaching 0.1-0.5 back to a pole on a desk clamp or a disc; "tv": aspect
1.5-2, on blades, inverted vees, splayed legs, a pedestal or a low console (with a sound bar);
"wall": a slab tilted -11 to 14 degrees on a bracket 0.06-0.45 behind it, maybe a sound bar below;
"crt": a front 0.08-0.3 deep and a tube 0.6-1.3 times the width deep, tapering back as two stepped
boxes (split 25-75%) or a cone, raised or lowered, on a swivel foot or none.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, chance, bar, frame, X, ALONG_Z

STYLES = ("monitor", "tv", "wall", "crt", "arm")
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
    arm: float              # wall: the bracket's distance behind the panel; monitor: > 0 a cable cut-out in the neck
    tube_depth: float       # crt: the tube behind the front box
    tube_round: bool        # crt: a cone, else two stepped boxes
    tube_scale: tuple[float, float]  # crt: the tube's sizes (shares of the front)
    tube_split: float       # crt: the first box's share of the tube's depth
    tube_lift: float        # crt: the tube's centre above the front's, share of the height


def sample(rng: np.random.Generator, style: str) -> DisplayParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    aspect = {"monitor": uniform(rng, 1.2, 2.4), "arm": uniform(rng, 1.2, 2.4), "tv": uniform(rng, 1.5, 2.0), "wall": uniform(rng, 1.3, 2.2),
              "crt": uniform(rng, 1.05, 1.4)}[style]
    w = 1.0 if style != "crt" else uniform(rng, 0.6, 0.8)
    h = w / aspect
    thick = {"monitor": uniform(rng, 0.055, 0.13), "arm": uniform(rng, 0.055, 0.12), "tv": uniform(rng, 0.055, 0.1), "wall": uniform(rng, 0.055, 0.09),
             "crt": uniform(rng, 0.08, 0.3)}[style]
    recess = uniform(rng, 0.01, 0.03)
    thick += recess  # the panel behind the screen at least 0.055 thick
    housing = (0.0, 0.0, 0.0)
    if style != "crt" and chance(rng, 0.5):
        housing = (uniform(rng, 0.3, 0.9), uniform(rng, 0.3, 0.8), uniform(rng, 0.055, 0.16))
    stand = {"monitor": str(rng.choice(FEET)), "arm": str(rng.choice(["clamp", "disc"])), "tv": str(rng.choice(TV_STANDS)), "wall": "bracket",
             "crt": "swivel" if chance(rng, 0.7) else "none"}[style]
    lift = {"monitor": uniform(rng, 0.1, 0.45) * h + 0.055, "arm": uniform(rng, 0.1, 0.6) * h + 0.055, "tv": uniform(rng, 0.04, 0.25) * h + 0.03,
            "wall": 0.0, "crt": uniform(rng, 0.055, 0.12) if stand == "swivel" else 0.0}[style]
    if stand == "console":
        lift = uniform(rng, 0.25, 0.6) * h
    k = min(1.0, 1.0 / (lift + h))  # the longest side at most 1
    w, h, lift = w * k, h * k, lift * k
    return DisplayParams(
        style=style, width=w, height=h, thick=thick,
        tilt={"monitor": uniform(rng, 0.0, 0.35), "arm": uniform(rng, -0.15, 0.35), "crt": uniform(rng, 0.0, 0.12), "tv": uniform(rng, 0.0, 0.1),
              "wall": uniform(rng, -0.2, 0.25)}[style],
        bezel=uniform(rng, 0.02, 0.07), chin=uniform(rng, 0.0, 0.1) if chance(rng, 0.5) else 0.0,
        recess=recess, housing=housing, lift=lift, stand=stand,
        neck_width=uniform(rng, 0.07, 0.2), lean=uniform(rng, 0.0, 0.4) if chance(rng, 0.6) else 0.0,
        foot=(uniform(rng, 0.12, 0.35), uniform(rng, 0.08, 0.22)), spread=uniform(rng, 0.45, 0.9),
        soundbar=style in ("wall", "tv") and chance(rng, 0.3),
        arm={"wall": uniform(rng, 0.06, 0.45), "monitor": float(chance(rng, 0.4)),
             "arm": uniform(rng, 0.1, 0.5)}.get(style, 0.0),
        tube_depth=min(uniform(rng, 0.6, 1.3) * w, 1.0 - thick) if style == "crt" else 0.0, tube_round=chance(rng, 0.35),
        tube_scale=(uniform(rng, 0.6, 0.98), uniform(rng, 0.3, 0.7)), tube_split=uniform(rng, 0.25, 0.75),
        tube_lift=uniform(rng, -0.12, 0.1))


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
        if p.arm > 0 and p.neck_width > 0.13:  # a cable cut-out through the neck
            bar(b, foot + (top - foot) * 0.35, foot + (top - foot) * 0.6, p.neck_width - 0.11, 0.2, op="subtract")
        fz = foot[2] - fd * 0.4
        if p.stand == "rect":
            b.box((0, 0.0275, fz), (fw, 0.0275, fd), rounding=0.01)
        elif p.stand == "disc":
            b.cylinder((0, 0.0275, fz), max(fw, fd), 0.0275)
        else:  # two prongs spreading forward
            for s in (-1, 1):
                bar(b, foot, (s * fw * 1.2, 0.0275, foot[2] - 2 * fd), 0.06, 0.055, x_hint=(0, 1, 0))
    elif p.style == "arm":  # an arm back from the panel to a pole on a desk clamp or a disc
        vesa = c + back * (t / 2 + p.housing[2])
        elbow = np.array([0.0, vesa[1] + (p.lean - 0.2) * 0.4, vesa[2] + p.arm])
        bar(b, vesa, elbow, 0.06, 0.055)
        b.cylinder((0, elbow[1] / 2 + 0.02, elbow[2]), 0.03, elbow[1] / 2 + 0.02)
        if p.stand == "clamp":
            b.box((0, 0.05, elbow[2] + 0.02), (0.05, 0.05, 0.07))
        else:
            b.cylinder((0, 0.0275, elbow[2]), fw * 0.8, 0.0275)
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
        b.box(c + back * (t / 2 + 0.0275), (w * 0.15, h * 0.2, 0.0275 + 0.01))
        b.box(c + back * (t / 2 + p.arm / 2 + 0.03), (0.04, 0.04, p.arm / 2 + 0.03))  # the arm
        b.box(c + back * (t / 2 + p.arm + 0.0275 + 0.03), (w * fw, h * 0.3, 0.0275))
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
    cy = c[1] + h * p.tube_lift * (1 - a)
    if p.tube_round:
        b.cone((0, cy, z0 + dd / 2), dd / 2, a * min(w, h) / 2 * 1.1, s2 * min(w, h) / 2, ALONG_Z)
    else:
        d1 = dd * p.tube_split
        b.box((0, cy, z0 + d1 / 2), (w * a / 2, h * a / 2, d1 / 2), rounding=0.03)
        cy2 = cy + h * p.tube_lift * (a - s2)
        b.box((0, cy2, z0 + (d1 + dd) / 2 - 0.01), (w * s2 / 2, h * s2 / 2, (dd - d1) / 2 + 0.01), rounding=0.03)
    if p.stand == "swivel":
        b.part("stand")
        zc = bottom[2] + t / 2  # under the panel's bottom edge
        b.cylinder((0, y0 / 2 + 0.02, zc), p.foot[1] * 0.6 + 0.03, y0 / 2 + 0.02)
        b.cylinder((0, 0.0275, zc), p.foot[0] * 0.8 + 0.05, 0.0275)
    return b.shape()
