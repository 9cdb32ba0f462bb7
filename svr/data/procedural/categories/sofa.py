"""The procedural sofa, along x with its back at +z: a base (0.5-1.05 long, 0.3-0.75 deep, 0.05-0.32
thick) on a plinth or on 4-6 legs (straight, round or tapered, 0.05-0.28 high), 1-4 seat cushions
(0-0.12 thick), a back (0.1-0.5 above the base, 0.06-0.25 thick, tilted 0-0.3 rad, square, rounded
or with a camel hump) with 0-4 back cushions, and arms (6-24% of the length wide, 0.1-1.15 of the
back's height, boxy, rounded, rolled, sloped or open, 45-100% of the depth). Styles: "straight":
two arms; "sectional": a chaise (0.15-0.55) reaching forward on one side (one arm) or both (a U),
often with a back along the chaise (an L); "armless": no arms, often on taller legs; "loveseat":
short and deep, two arms; "chaise": a long daybed with one arm and a back over 30-100% of its
length; "curved": a slice of a round sofa whose back wall wraps round its sides. Everything thin
is at least MIN_PART.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import pick, MIN_PART, X, chance, uniform

STYLES = ("straight", "sectional", "armless", "loveseat", "chaise", "curved")
LEGS = ("plinth", "straight", "round", "tapered")
BACKS = ("square", "rounded", "camel")
ARMS = ("box", "rounded", "rolled", "sloped", "open")


@dataclass(frozen=True)
class SofaParams:
    style: str
    width: float         # along x
    depth: float
    base_h: float        # thickness of the base under the cushions
    base_round: float
    leg: str             # LEGS
    leg_h: float         # 0 on a plinth
    leg_t: float
    legs_per_side: int
    leg_inset: float
    n_seats: int         # seat cushions
    cushion_t: float     # 0: a flat seat
    back: str            # BACKS
    back_h: float
    back_t: float
    back_tilt: float
    back_w: float        # a chaise's back: the fraction of the length it covers
    n_backs: int         # back cushions (0: none)
    back_cushion_t: float
    arm_sides: tuple     # of -1 (left, -x) and 1
    arm: str             # ARMS
    arm_w: float
    arm_h: float         # above the base's top
    arm_len: float       # fraction of the depth, from the back
    chaise_side: int
    chaise_len: float    # how far the chaise reaches forward
    chaise_w: float
    corner: bool         # a sectional's chaise with a back of its own along its outer side: an L
    u_shape: bool        # a sectional with a chaise on both sides
    curve: float         # a curved sofa keeps the part of its disk with z > curve * radius


def sample(rng: np.random.Generator, style: str) -> SofaParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    width = {"loveseat": uniform(rng, 0.5, 0.8), "chaise": uniform(rng, 0.8, 1.05),
             "sectional": uniform(rng, 0.7, 1.05)}.get(style, uniform(rng, 0.55, 1.05))
    depth = uniform(rng, 0.4, 0.75) if style in ("loveseat", "chaise") else uniform(rng, 0.3, 0.7)
    if style == "sectional":
        depth = uniform(rng, 0.3, 0.6)
    leg = pick(rng, LEGS, (0.3, 0.3, 0.2, 0.2) if style != "armless" else (0.1, 0.3, 0.3, 0.3))
    leg_h = 0.0 if leg == "plinth" else (uniform(rng, 0.07, 0.28) if style == "armless"
                                         else uniform(rng, MIN_PART - 0.005, 0.25))
    side = 1 if chance(rng, 0.5) else -1
    u_shape = style == "sectional" and chance(rng, 0.3)
    arm_sides = {"straight": (-1, 1), "loveseat": (-1, 1), "sectional": () if u_shape else (-side,),
                 "armless": (), "chaise": (side,), "curved": ()}[style]
    n_seats = 1 if style == "chaise" else int(rng.integers(1, 3 if style == "loveseat" else 5))
    n_backs = int(rng.integers(1, 4)) if chance(rng, 0.4) else 0
    if style == "chaise":
        n_backs = int(chance(rng, 0.4))
    arm_w = max(MIN_PART, uniform(rng, 0.06, 0.24) * width)
    base_h = uniform(rng, 0.05, 0.32)
    back_h = min(uniform(rng, 0.1, 0.32 if style == "curved" else 0.5), 0.93 - leg_h - base_h)
    back_tilt = uniform(rng, 0.0, 0.3)
    reach = 1.03 - depth - back_h * math.sin(back_tilt)  # what a chaise may add to the depth
    cushion_t = uniform(rng, MIN_PART, 0.12) if chance(rng, 0.75) or style == "curved" else 0.0
    return SofaParams(
        style=style, width=width, depth=depth, base_h=base_h, base_round=uniform(rng, 0.0, 0.05),
        leg=leg, leg_h=leg_h, leg_t=uniform(rng, MIN_PART, 0.1), legs_per_side=int(rng.integers(2, 4)),
        leg_inset=uniform(rng, 0.0, 0.08), n_seats=n_seats,
        cushion_t=cushion_t,
        back=pick(rng, BACKS, (0.5, 0.35, 0.15)), back_h=back_h, back_t=uniform(rng, 0.06, 0.25),
        back_tilt=back_tilt, back_w=uniform(rng, 0.3, 1.0), n_backs=n_backs,
        back_cushion_t=uniform(rng, MIN_PART, 0.11), arm_sides=arm_sides, arm=pick(rng, ARMS), arm_w=arm_w,
        arm_h=back_h * uniform(rng, 0.1, 1.15), arm_len=uniform(rng, 0.45, 1.0), chaise_side=side,
        chaise_len=uniform(rng, 0.15, max(0.16, min(0.55, reach))),
        chaise_w=uniform(rng, 0.25, 0.38 if u_shape else 0.5),
        corner=style == "sectional" and chance(rng, 0.45), u_shape=u_shape, curve=uniform(rng, -0.3, 0.4))


def _legs(b: CSGBuilder, p: SofaParams, x0: float, x1: float, z0: float, z1: float, n: int) -> None:
    """n legs along the front and the back edges of the rectangle [x0, x1] x [z0, z1]."""
    h, t, m = p.leg_h + 0.01, p.leg_t, p.leg_inset + p.leg_t / 2
    for k in range(n):
        x = x0 + m + (x1 - x0 - 2 * m) * k / (n - 1)
        for z in (z0 + m, z1 - m):
            if p.leg == "straight":
                b.box((x, h / 2, z), (t / 2, h / 2, t / 2))
            elif p.leg == "round":
                b.cylinder((x, h / 2, z), t / 2, h / 2)
            else:
                b.cone((x, h / 2, z), h / 2, max(MIN_PART / 2, 0.35 * t), t / 2 + 0.01)


def _curved(b: CSGBuilder, p: SofaParams) -> CSGShape:
    """A round sofa: a slice of a disk (its back wall a slice of a tube) that keeps z > curve * r,
    on legs along the rim."""
    r, lh, top = p.width / 2, p.leg_h, p.leg_h + p.base_h
    z_cut = p.curve * r
    hi = top + p.back_h
    b.part("base")
    b.cylinder((0, (lh + hi) / 2, 0), r, (hi - lh) / 2)
    b.cylinder((0, (top + hi) / 2 + 0.05, 0), r - p.back_t, (hi - top) / 2 + 0.05, op="subtract")
    if p.cushion_t > 0:
        b.part("cushions")
        b.cylinder((0, top + p.cushion_t / 2 - 0.005, 0), r - p.back_t + 0.005, p.cushion_t / 2 + 0.005)
    b.box_between((-r - 0.1, lh - 0.1, -r - 0.1), (r + 0.1, hi + 0.1, z_cut), op="subtract")  # the open front
    if lh > 0:
        b.part("legs")
        t = p.leg_t
        rl = r - p.leg_inset - t
        front = math.acos(float(np.clip((z_cut + p.leg_inset + t) / rl, -1.0, 1.0)))
        h = lh + 0.01
        for a in (-front, -0.2 * math.pi, 0.2 * math.pi, front):
            x, z = rl * math.sin(a), rl * math.cos(a)
            if p.leg == "straight":
                b.box((x, h / 2, z), (t / 2, h / 2, t / 2))
            else:
                b.cylinder((x, h / 2, z), t / 2, h / 2)
    return b.shape()


def build(p: SofaParams) -> CSGShape:
    b = CSGBuilder()
    w, d, lh, bh = p.width, p.depth, p.leg_h, p.base_h
    top = lh + bh                    # top of the base
    if p.style == "curved":
        return _curved(b, p)
    s = p.chaise_side
    chaises = ((-1, 1) if p.u_shape else (s,)) if p.style == "sectional" else ()
    arm_l = -1 in p.arm_sides
    arm_r = 1 in p.arm_sides
    # the base (and a chaise's extension to the front)
    b.part("base")
    b.box_between((-w / 2, lh, -d / 2), (w / 2, top, d / 2), rounding=p.base_round)
    for c in chaises:
        cx0, cx1 = sorted((c * w / 2, c * (w / 2 - p.chaise_w * w)))
        b.box_between((cx0, lh, -d / 2 - p.chaise_len), (cx1, top, -d / 2 + 0.05), rounding=p.base_round)
    # the back: along the whole length, or over one end of a chaise
    b.part("back")
    bx0, bx1 = -w / 2, w / 2
    if p.style == "chaise":
        bx0, bx1 = sorted((s * w / 2, s * (w / 2 - p.back_w * w)))
    rot = rotation(X, p.back_tilt)  # top towards +z
    zb = d / 2 - p.back_t / 2
    bc = np.array([(bx0 + bx1) / 2, top - 0.02, zb]) + rot @ np.array([0.0, p.back_h / 2 + 0.01, 0.0])
    b.box(bc, ((bx1 - bx0) / 2, p.back_h / 2 + 0.01, p.back_t / 2), rot, rounding=min(0.04, p.back_t / 2 - 0.001))
    back_top = np.array([0.0, top - 0.02, zb]) + rot @ np.array([0.0, p.back_h, 0.0])
    if p.back == "rounded":  # a round top over the whole length
        b.capsule((bx0 + p.back_t / 2, back_top[1], back_top[2]), (bx1 - p.back_t / 2, back_top[1], back_top[2]),
                  p.back_t / 2 + 0.01)
    elif p.back == "camel":  # a hump in the middle
        hw = 0.25 * (bx1 - bx0)
        b.capsule(((bx0 + bx1) / 2 - hw, back_top[1], back_top[2]), ((bx0 + bx1) / 2 + hw, back_top[1], back_top[2]),
                  p.back_t / 2 + 0.035)
    for c in chaises if p.corner else ():  # the L's second back, along the chaise's outer side
        x0, x1 = sorted((c * w / 2, c * (w / 2 - p.back_t)))
        b.box_between((x0, top - 0.02, -d / 2 - p.chaise_len), (x1, top + p.back_h, d / 2),
                      rounding=min(0.04, p.back_t / 2 - 0.001))
    # arms
    b.part("arms")
    aw = p.arm_w
    for a in p.arm_sides:
        x0, x1 = sorted((a * w / 2, a * (w / 2 - aw)))
        z0 = d / 2 - p.arm_len * d
        if p.style == "chaise":
            z0 = -d / 2
        y1 = top + p.arm_h
        if p.arm == "sloped":  # rising towards the back
            b.box_between((x0, lh, z0), (x1, y1 - 0.5 * p.arm_h, d / 2), rounding=0.02)
            half = (aw / 2, max(MIN_PART / 2, 0.25 * p.arm_h + 0.02), (d / 2 - z0) / 2)
            b.box(((x0 + x1) / 2, y1 - 0.25 * p.arm_h, (z0 + d / 2) / 2), half,
                  rotation(X, -math.atan2(0.5 * p.arm_h, d / 2 - z0) * 0.8), rounding=0.02)
            continue
        if p.arm == "open":  # an armrest on a front post, open below
            t = max(MIN_PART, min(0.08, 0.5 * aw))
            b.box_between((x0, max(top, y1 - t), z0), (x1, max(top, y1 - t) + t, d / 2), rounding=0.015)
            pw = max(MIN_PART, min(aw, 0.08))
            xc = (x0 + x1) / 2
            b.box_between((xc - pw / 2, top - 0.02, z0 + 0.01), (xc + pw / 2, y1, z0 + 0.01 + pw))
            continue
        r = {"box": 0.01, "rounded": 0.45 * aw, "rolled": 0.02}[p.arm]
        b.box_between((x0, lh, z0), (x1, y1, d / 2), rounding=min(r, 0.06))
        if p.arm == "rolled":  # a roll overhanging the arm's outer side
            b.capsule(((x0 + x1) / 2 + a * 0.015, y1, z0 + aw / 2), ((x0 + x1) / 2 + a * 0.015, y1, d / 2 - 0.02),
                      aw / 2 + 0.015)
    # seat cushions between the arms (a chaise's runs the full length)
    xl = -w / 2 + (aw if arm_l else 0.0)
    xr = w / 2 - (aw if arm_r else 0.0)
    zf, zr = -d / 2 + 0.01, d / 2 - p.back_t
    ct = max(p.cushion_t, MIN_PART)
    y0 = top - 0.01 if p.cushion_t > 0 else top - MIN_PART + 0.01
    if p.cushion_t > 0 or p.style == "sectional":
        b.part("cushions")
        n = p.n_seats
        for k in range(n):
            x0 = xl + (xr - xl) * k / n + 0.005
            x1 = xl + (xr - xl) * (k + 1) / n - 0.005
            b.box_between((x0, y0, zf), (x1, y0 + ct, zr), rounding=0.025)
        for c in chaises:
            cx0, cx1 = sorted((c * w / 2, c * (w / 2 - p.chaise_w * w)))
            x0, x1 = cx0 + (0.0 if c < 0 else 0.01), cx1 - (0.01 if c < 0 else 0.0)
            b.box_between((x0, y0, -d / 2 - p.chaise_len + 0.01), (x1, y0 + ct, -d / 2 + 0.03), rounding=0.025)
    if p.n_backs:  # back cushions leaning on the back
        b.part("cushions")
        n = p.n_backs
        cb0, cb1 = max(bx0, xl), min(bx1, xr)
        h = max(0.04, 0.45 * (p.back_h - ct))
        for k in range(n):
            x0 = cb0 + (cb1 - cb0) * k / n + 0.01
            x1 = cb0 + (cb1 - cb0) * (k + 1) / n - 0.01
            c = np.array([(x0 + x1) / 2, y0 + ct, d / 2 - p.back_t - p.back_cushion_t / 2 + 0.02]) \
                + rotation(X, p.back_tilt) @ np.array([0.0, h, 0.0])
            b.box(c, ((x1 - x0) / 2, h, p.back_cushion_t / 2), rotation(X, p.back_tilt), rounding=0.03)
    # legs
    if lh > 0:
        b.part("legs")
        _legs(b, p, -w / 2, w / 2, -d / 2, d / 2, p.legs_per_side)
        for c in chaises:
            t, m = p.leg_t, p.leg_inset + p.leg_t / 2
            x = c * (w / 2 - m)
            z = -d / 2 - p.chaise_len + m
            if p.leg == "straight":
                b.box((x, (lh + 0.01) / 2, z), (t / 2, (lh + 0.01) / 2, t / 2))
            else:
                b.cylinder((x, (lh + 0.01) / 2, z), t / 2, (lh + 0.01) / 2)
    return b.shape()
