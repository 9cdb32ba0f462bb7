"""The procedural bench: a seat along x (about 1 long, 0.2-0.46 as deep, at 0.25-0.5), solid (0.055-0.14
thick) or of 2-5 slats, on 2 or 3 supports set 0-18% in from the ends, front to -z. Supports: four
legs (straight, round, tapered or splayed), A-frames, trestles, sled loops, blocks, end panels (with a
rectangular or round cut-out, or none) or a park bench's side frames; optional stretcher, back
(solid panel, 1-3 slats or 1-2 rails on posts; 0.12-0.42 high, tilted 0-0.35 rad) and arms (open
or panel). Styles: "park": slatted seat and slatted back on side frames, optional arms;
"panel": end panels, optionally rising into arms (a pew) and a panel back; "backless": any
support, no back; "rail_back": front legs, back posts that are the rear legs, 1-2 rails 0.055-0.11 high.
Everything thin is at least MIN_PART.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import (pick, ALONG_X, MIN_PART, UPRIGHT_LEGS, X, bar, chance, leg,
                                                   uniform)

STYLES = ("park", "panel", "backless", "rail_back")
SUPPORTS = ("legs", "aframe", "trestle", "sled", "panel", "block", "frame")
LEGS = ("straight", "round", "tapered", "splayed")
BACKS = ("none", "panel", "slats", "rails")
ARMS = ("none", "open", "panel")
CUTS = ("none", "rect", "round")
HALF = MIN_PART / 2


@dataclass(frozen=True)
class BenchParams:
    style: str
    length: float        # along x
    depth: float
    seat_h: float        # top of the supports
    seat_t: float
    slats: int           # 0: a solid seat (slats need a support with a top across the depth)
    slat_gap: float
    support: str         # SUPPORTS
    n_supports: int
    inset: float         # of the end supports, fraction of the length
    leg: str             # LEGS
    leg_t: float
    splay: float
    block_w: float       # of a block support, along x
    cut: str             # CUTS, in end panels
    cut_margin: float
    stretcher: bool
    stretcher_y: float   # fraction of the seat's height
    back: str            # BACKS
    back_h: float
    back_tilt: float
    back_n: int          # slats or rails
    back_t: float
    arms: str            # ARMS
    arm_h: float


def sample(rng: np.random.Generator, style: str) -> BenchParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    length = uniform(rng, 0.95, 1.05)  # the longest side: proportions are drawn against it
    depth = length * uniform(rng, 0.2, 0.46)
    seat_h = length * uniform(rng, 0.25, 0.5)
    support = {"park": "frame", "panel": "panel",
               "backless": pick(rng, ("legs", "aframe", "trestle", "sled", "panel", "block"),
                                 (0.35, 0.13, 0.13, 0.13, 0.13, 0.13)),
               "rail_back": "legs"}[style]
    slatted = style == "park" or (support in ("trestle", "panel", "block") and chance(rng, 0.4))
    back = {"park": "slats", "panel": pick(rng, ("none", "panel"), (0.45, 0.55)), "backless": "none",
            "rail_back": "rails"}[style]
    arms = {"park": pick(rng, ("none", "open"), (0.4, 0.6)), "panel": pick(rng, ("none", "panel"), (0.5, 0.5)),
            "rail_back": pick(rng, ("none", "open"), (0.7, 0.3))}.get(style, "none")
    seat_t = uniform(rng, MIN_PART, 0.14)
    back_h = min(uniform(rng, 0.12, 0.42), 0.98 - seat_h - seat_t)
    arm_h = uniform(rng, 0.1, 0.26) if back == "none" else back_h * uniform(rng, 0.4, 0.8)
    return BenchParams(
        style=style, length=length, depth=depth, seat_h=seat_h, seat_t=seat_t,
        slats=int(rng.integers(2, 5 if style == "park" else 6)) if slatted else 0,
        slat_gap=uniform(rng, 0.035, 0.07), support=support,
        n_supports=3 if chance(rng, 0.08) else 2, inset=uniform(rng, 0.0, 0.18),
        leg=pick(rng, LEGS), leg_t=uniform(rng, MIN_PART, 0.11), splay=uniform(rng, 0.02, 0.1),
        block_w=uniform(rng, 0.08, 0.3), cut=pick(rng, CUTS), cut_margin=uniform(rng, MIN_PART, 0.1),
        stretcher=chance(rng, 0.25),
        stretcher_y=uniform(rng, 0.15, 0.55), back=back, back_h=back_h,
        back_tilt=uniform(rng, 0.0, 0.35), back_n=int(rng.integers(1, 4 if style == "park" else 5)),
        back_t=uniform(rng, MIN_PART, 0.1),
        arms=arms, arm_h=arm_h)


# ----------------------------------------------------------------------------------- building


def _support(b: CSGBuilder, p: BenchParams, x: float, out: float) -> None:
    """One support at x; ``out`` is the sign of the nearer end (0 for a middle support)."""
    sh, d, t = p.seat_h, p.depth, p.leg_t
    lz = d / 2 - t / 2 - 0.02
    hh = sh / 2 + 0.005  # into the seat
    arm_top = sh + p.seat_t + p.arm_h if p.arms == "open" and out != 0 else 0.0  # a front leg runs up to an armrest
    if p.support == "legs":
        # a bench with a back stands on its back's posts behind (``_back``)
        for z in (-lz,) if p.style == "rail_back" else (-lz, lz):
            if z < 0 and arm_top:
                b.box((x, arm_top / 2, z), (t / 2, arm_top / 2, t / 2))
            elif p.leg in UPRIGHT_LEGS:
                leg(b, p.leg, x, z, 2 * hh, t)
            else:
                s = p.splay
                sx = min(s, max(0.0, p.length / 2 - abs(x) - t / 2))  # feet within the seat's ends
                b.rod((x, sh + 0.01, z), (x + out * sx, t / 2, z + math.copysign(s, z)), max(HALF, t / 2))
    elif p.support == "aframe":  # two legs meeting under the seat, a cross bar
        zt = max(t / 2, 0.25 * d)
        zf = d / 2 + p.splay
        for sz in (-1, 1):
            bar(b, (x, sh + 0.01, sz * zt), (x, t / 2, sz * zf), t, t)
        y = p.stretcher_y * sh
        zy = zt + (zf - zt) * (1 - y / sh)
        b.box((x, y, 0), (t / 2, HALF + 0.005, zy))
    elif p.support == "trestle":  # a post on a foot, under a cross beam
        b.box((x, sh / 2, 0), (t / 2, sh / 2, max(t, 0.12 * d)))
        b.box((x, MIN_PART / 2 + 0.005, 0), (t / 2 + 0.01, MIN_PART / 2 + 0.005, d / 2 + p.splay / 2), rounding=0.01)
        b.box((x, sh - HALF - 0.005, 0), (t / 2, HALF + 0.005, d / 2 - 0.02))
    elif p.support == "sled":  # a closed loop: floor runner, two uprights, a rail under the seat
        b.box((x, HALF + 0.005, 0), (t / 2, HALF + 0.005, d / 2), rounding=0.015)
        for z in (-lz, lz):
            b.box((x, sh / 2, z), (t / 2, sh / 2, t / 2))
    elif p.support == "panel":
        b.box((x, sh / 2, 0), (t / 2, sh / 2, d / 2 - 0.01))
    elif p.support == "block":  # a solid block, set in from the front and the back
        w = max(t, p.block_w)
        b.box((x - out * (w - t) / 2, sh / 2, 0), (w / 2, sh / 2 + 0.005, d / 2 - p.cut_margin / 2), rounding=0.01)
    else:  # park frame: front leg and seat rail; the rear leg runs up into the back (``_back``)
        zf = -d / 2 + t / 2 + 0.02
        top = max(sh, arm_top)
        b.box((x, top / 2, zf), (t / 2, top / 2, t / 2))
        b.box((x, sh - t / 2, 0), (t / 2, t / 2, d / 2))


def _panel_cut(b: CSGBuilder, p: BenchParams, x: float) -> None:
    """A cut-out through an end panel, leaving a margin on the sides and at the top."""
    sh, d, m = p.seat_h, p.depth, p.cut_margin
    t = p.leg_t
    r = d / 2 - 0.01 - m
    if r < 0.04 or sh - m - r < 0.06:
        return
    if p.cut == "round":  # a round opening under the seat
        r = min(r, (sh - m - MIN_PART) / 2)
        b.cylinder((x, sh - m - r, 0), r, t, ALONG_X, op="subtract")
    else:
        b.box((x, (sh - m) / 2 - 0.01, 0), (t, (sh - m) / 2 + 0.01, r), op="subtract")


def _seat(b: CSGBuilder, p: BenchParams) -> None:
    b.part("seat")
    L, d, sh, st = p.length, p.depth, p.seat_h, p.seat_t
    if not p.slats:
        b.box((0, sh + st / 2, 0), (L / 2, st / 2, d / 2), rounding=min(0.03, st / 2 - 0.001))
        return
    n = max(2, min(p.slats, int((d + p.slat_gap) / (MIN_PART + p.slat_gap))))
    w = (d - (n - 1) * p.slat_gap) / n
    t = max(MIN_PART, min(st, 0.08))
    for k in range(n):
        z = -d / 2 + w / 2 + k * (w + p.slat_gap)
        b.box((0, sh + t / 2, z), (L / 2, t / 2, w / 2), rounding=0.008)


def _back(b: CSGBuilder, p: BenchParams, xs: list[float]) -> None:
    if p.back == "none":
        return
    b.part("back")
    L, d, sh = p.length, p.depth, p.seat_h
    y0 = sh + (p.seat_t if not p.slats else max(MIN_PART, min(p.seat_t, 0.08)))
    rot = rotation(X, p.back_tilt)  # top towards +z
    t = p.back_t
    zb = d / 2 - t / 2
    pivot = np.array([0.0, y0, zb])
    bh = p.back_h
    if p.back == "panel":
        b.box(pivot + rot @ np.array([0.0, bh / 2 - 0.01, 0.0]), (L / 2 - 0.01, bh / 2, t / 2), rot,
              rounding=min(0.03, t / 2 - 0.001))
        return
    # posts over the end supports that are also the rear legs, then slats or rails
    post = max(MIN_PART, min(p.leg_t, 0.08))
    for x in (xs[0], xs[-1]):
        down = y0 / math.cos(p.back_tilt)  # down to the floor: the rear legs
        a = pivot + np.array([x, 0.0, 0.0]) + rot @ np.array([0.0, -down, 0.0])
        top = pivot + np.array([x, 0.0, 0.0]) + rot @ np.array([0.0, bh, 0.0])
        bar(b, a, top, post, post)
    n = p.back_n if p.back == "slats" else min(p.back_n, 2)
    n = max(1, min(n, int(bh / (2 * MIN_PART))))
    pitch = bh / n
    h = max(MIN_PART, min(0.6 * pitch if p.back == "slats" else p.back_t + 0.01, pitch - MIN_PART))
    for k in range(n):
        y = bh - h / 2 - k * pitch
        c = pivot + rot @ np.array([0.0, y, -post / 2 - HALF + 0.01 if p.style == "park" else 0.0])
        b.box(c, (L / 2 - 0.01, h / 2, HALF + 0.004), rot, rounding=0.008)


def _arms(b: CSGBuilder, p: BenchParams, xs: list[float]) -> None:
    if p.arms == "none":
        return
    b.part("arms")
    d, sh = p.depth, p.seat_h
    y = sh + p.seat_t + p.arm_h
    t = max(MIN_PART, min(p.leg_t, 0.09))
    for x in (xs[0], xs[-1]):
        if p.arms == "panel":  # the end panel rising above the seat
            b.box_between((x - t / 2, sh, -d / 2 + 0.01), (x + t / 2, y, d / 2), rounding=0.02)
        else:  # an armrest on the front leg, which runs up to it (``_support``)
            b.box_between((x - t / 2 - 0.01, y - MIN_PART, -d / 2), (x + t / 2 + 0.01, y, d / 2), rounding=0.012)


def build(p: BenchParams) -> CSGShape:
    b = CSGBuilder()
    L, d, sh, t = p.length, p.depth, p.seat_h, p.leg_t
    xe = L / 2 - t / 2 - p.inset * L
    xs = [-xe, xe] if p.n_supports == 2 else [-xe, 0.0, xe]
    b.part("supports")
    for x in xs:
        _support(b, p, x, float(np.sign(x)))
    if p.support == "panel" and p.cut != "none":  # before anything they must not cut
        for x in xs:
            _panel_cut(b, p, x)
    if p.stretcher and p.support != "panel":  # beams along the bench between the supports
        b.part("stretchers")
        h = HALF + 0.005
        if p.support == "legs":  # front and back, through the legs
            y = p.stretcher_y * sh
            out = p.splay * (1 - y / sh) if p.leg == "splayed" else 0.0
            lz = d / 2 - t / 2 - 0.02 + out
            for z in (-lz, lz):
                if z > 0 and p.style == "rail_back":  # through the back's posts
                    z = d / 2 - p.back_t / 2 - (sh + p.seat_t - y) * math.tan(p.back_tilt)
                b.box((0, y, z), (xe + out, h, h))
        elif p.support == "frame":  # between the rear legs, which lean with the back
            y = p.stretcher_y * sh
            y0 = sh + max(MIN_PART, min(p.seat_t, 0.08))
            b.box((0, y, d / 2 - p.back_t / 2 - (y0 - y) * math.tan(p.back_tilt)), (xe, h, h))
        else:  # along the middle: over a foot, through a post or a cross bar
            y = {"sled": h, "trestle": MIN_PART + 0.01 + h}.get(p.support, p.stretcher_y * sh)
            b.box((0, y, 0), (xe, h, h))
    _seat(b, p)
    _back(b, p, xs)
    _arms(b, p, xs)
    return b.shape()
