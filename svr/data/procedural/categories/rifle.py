"""The procedural rifle, along z with the muzzle at z = -0.5 and the butt at 0.5, the barrel on the
axis (radius in ``AXIS_ROD``, or a heavy barrel 0.042-0.062 in 40% of the non-smg guns). Five styles:
"hunting" (solid, hollow or thumbhole stock with a comb, wrist grip, long forestock, bolt handle,
scope in 70%), "assault" (pistol grip, curved, straight or drum magazine, handguard, skeleton, solid,
tube or hollow stock, carry handle, sight rail or scope, flash hider, optional foregrip), "sniper"
(big scope, bipod in 75%, thumbhole, solid, hollow or skeleton stock, brake or suppressor),
"shotgun" (two barrels side by side or over and under, or one over a tube magazine 0.35-1 of the
barrel long with a pump; any stock, maybe a rail, scope or box magazine) and "smg" (short and tall:
pistol grip, long straight magazine, in 35% up through the grip, tube, skeleton or no stock). Every
style draws from continuous ranges, independently: the receiver's position (front at -0.3..0.15),
length (0.12-0.4), height and half width (0.0285-0.068), the stock's half width (0.0285-0.075),
height (0.07-0.26 at the butt, 0.2-0.28 if hollow), drop, opening (hollow: 0.3-0.75 of its length, 0.3-0.6 of its
height) and cheek riser (in 30%, 0.035-0.07), the grip's angle, length, width and depth, the
magazine's length, depth, half width (0.0285-0.06) and tilt, the fore-end's length, depth
(0.02-0.07) and half width (0.0285-0.07), the scope's radius (0.034-0.07), length, height, bell and
shift, the muzzle device's radius and length (a suppressor 0.08-0.26), a bipod's legs (folded along
the barrel in 35%, else swung -0.3..0.8 rad and splayed 0-0.6 rad) and a sling sagging 0.03-0.16
below its swivels (in 35%); parts that are not drawn are absent.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import (uniform, chance, frame, bar, cut_beyond, X, Y, ALONG_X, ALONG_Z,
                                                    AXIS_ROD, MIN_PART)

STYLES = ("hunting", "assault", "sniper", "shotgun", "smg")
STOCKS = ("solid", "thumbhole", "hollow", "skeleton", "tube", "none")
MAGAZINES = ("none", "box", "curved", "drum", "tube")
FORE_ENDS = ("none", "forestock", "handguard", "pump")
SIGHTS = ("none", "scope", "carry", "rail")
MUZZLES = ("none", "brake", "suppressor")


@dataclass(frozen=True)
class RifleParams:
    style: str
    barrel_r: float
    double: bool          # two barrels side by side
    muzzle_z: float
    recv_z: float         # receiver front
    recv_len: float
    recv_h: float
    recv_top: float       # receiver top above the barrel's axis
    half_w: float         # receiver and stock half width
    stock: str            # STOCKS
    stock_h: float        # at the butt
    stock_drop: float     # of the top line from the receiver to the butt
    wrist: float          # distance from the receiver to the wrist's lowest point
    grip: bool            # a pistol grip (else the stock's wrist is the grip)
    grip_len: float
    grip_angle: float
    trigger_at: float     # fraction of the receiver
    magazine: str         # MAGAZINES
    mag_len: float
    mag_depth: float
    mag_tilt: float
    mag_bend: float       # curved: the second segment's extra tilt
    fore: str             # FORE_ENDS
    fore_len: float
    fore_h: float
    sight: str            # SIGHTS
    scope_r: float
    scope_len: float
    scope_h: float
    muzzle: str           # MUZZLES
    muzzle_len: float
    bipod: float          # leg length (0: none)
    bolt: bool
    foregrip: bool
    scope_z: float = 0.0  # the scope's shift along z from over the receiver's middle
    mag_z: float = 0.0    # the magazine's shift along z from ahead of the trigger guard
    stock_w: float = 0.045   # the stock's half width (across x)
    fore_w: float = 0.045    # the fore-end's half width
    mag_w: float = 0.04      # the magazine's half width
    grip_w: float = 0.04     # the pistol grip's half width and half depth
    grip_t: float = 0.034
    hole_len: float = 0.5    # hollow / thumbhole stock: the opening's length and height (fractions)
    hole_h: float = 0.5
    bipod_angle: float = 0.0  # from straight down towards the muzzle (about 1.45: folded along the barrel)
    bipod_splay: float = 0.3
    sling: float = 0.0       # how far the sling sags below the line between its swivels (0: none)
    scope_bell: float = 1.35  # the objective bell's radius over the tube's
    comb: float = 0.0        # a cheek riser's height on a solid stock (0: none)
    muzzle_r: float = 0.02   # the muzzle device's radius over the barrel's
    stacked: bool = False    # double barrels over and under (else side by side)
    tube_len: float = 1.0    # shotgun: the tube magazine's length (fraction of the barrel ahead of the receiver)
    mag_in_grip: bool = False  # the magazine goes up through the pistol grip


def sample(rng: np.random.Generator, style: str) -> RifleParams:
    u = lambda lo, hi: uniform(rng, lo, hi)  # noqa: E731
    pick = lambda options, p: str(rng.choice(options, p=p))  # noqa: E731
    k = u(1.2, 1.7) if style == "smg" else u(0.8, 1.3)  # size of the parts against the length
    heavy = style != "smg" and chance(rng, 0.4)  # a heavy barrel reaches well past the axis' voxels
    barrel_r = u(0.042, 0.062) if heavy else u(*AXIS_ROD)
    double = style == "shotgun" and chance(rng, 0.45)
    muzzle_z = -0.5
    if style == "hunting":
        recv_z, recv_len = u(-0.25, 0.1), u(0.14, 0.28)
        stock = pick(["solid", "hollow", "thumbhole"], [0.55, 0.25, 0.2])
        grip = chance(rng, 0.15)
        magazine = "box" if chance(rng, 0.3) else "none"
        fore = "forestock"
        sight = "scope" if chance(rng, 0.7) else "none"
        muzzle = "none"
    elif style == "assault":
        recv_z, recv_len = u(-0.2, 0.12), u(0.14, 0.32)
        stock = pick(["skeleton", "solid", "tube", "hollow"], [0.35, 0.25, 0.25, 0.15])
        grip = True
        magazine = pick(["curved", "box", "drum"], [0.55, 0.33, 0.12])
        fore = "handguard"
        sight = pick(["carry", "rail", "scope", "none"], [0.35, 0.25, 0.2, 0.2])
        muzzle = "brake" if chance(rng, 0.7) else "none"
    elif style == "sniper":
        recv_z, recv_len = u(-0.1, 0.15), u(0.14, 0.3)
        stock = pick(["thumbhole", "solid", "skeleton", "hollow"], [0.35, 0.2, 0.25, 0.2])
        grip = stock == "skeleton" or chance(rng, 0.35)
        magazine = "box" if chance(rng, 0.6) else "none"
        fore = "forestock" if chance(rng, 0.75) else "handguard"
        sight = "scope"
        muzzle = pick(["brake", "suppressor", "none"], [0.5, 0.25, 0.25])
    elif style == "shotgun":
        recv_z, recv_len = u(-0.2, 0.1), u(0.12, 0.26)
        stock = pick(["solid", "skeleton", "hollow", "tube", "thumbhole"], [0.45, 0.15, 0.15, 0.15, 0.1])
        grip = stock in ("skeleton", "tube") or chance(rng, 0.25)
        magazine = "none" if double else ("box" if chance(rng, 0.2) else "tube")
        fore = "forestock" if double else "pump"
        sight = pick(["none", "rail", "scope"], [0.6, 0.25, 0.15])
        muzzle = "brake" if chance(rng, 0.2) else "none"
    elif style == "smg":
        stock = pick(["none", "tube", "skeleton"], [0.35, 0.35, 0.3])
        recv_z = u(-0.25, -0.05) if stock != "none" else u(-0.3, -0.1)
        recv_len = u(0.25, 0.4) if stock != "none" else 0.5 - recv_z
        grip = True
        magazine = "box" if chance(rng, 0.85) else "curved"
        fore = "handguard" if chance(rng, 0.5) else "none"
        sight = "rail" if chance(rng, 0.4) else "none"
        muzzle = "suppressor" if chance(rng, 0.3) else "none"
    else:
        raise ValueError(f"unknown rifle style {style!r}; expected one of {STYLES}")
    if chance(rng, 0.12) and style in ("hunting", "sniper"):
        muzzle = "suppressor"
    if stock == "hollow":  # a long stock, for its opening
        recv_z = max(recv_z - 0.15, -0.3)
    recv_h = max(k * u(0.05, 0.15), 0.062)
    tall = style == "sniper"
    return RifleParams(
        style=style, barrel_r=barrel_r, double=double, muzzle_z=muzzle_z, recv_z=recv_z, recv_len=recv_len,
        recv_h=recv_h, recv_top=barrel_r + k * u(0.0, 0.06), half_w=u(0.0285, 0.068),
        stock=stock, stock_h=k * (u(0.2, 0.28) if stock == "hollow" else u(0.12, 0.26) if tall else u(0.07, 0.22)),
        stock_drop=k * (u(-0.02, 0.04) if tall else u(-0.01, 0.1)), wrist=u(0.05, 0.13), grip=grip,
        grip_len=k * u(0.08, 0.15), grip_angle=u(0.05, 0.6), trigger_at=u(0.4, 0.7), magazine=magazine,
        mag_len=k * (u(0.1, 0.22) if style == "smg" else u(0.05, 0.16)), mag_depth=max(k * u(0.05, 0.075), 0.058),
        mag_tilt=u(-0.05, 0.3), mag_bend=u(0.15, 0.45), fore=fore,
        fore_len=u(0.18, 0.42) if fore != "pump" else u(0.1, 0.2), fore_h=k * u(0.02, 0.07), sight=sight,
        scope_r=u(0.04, 0.07) if tall else u(0.034, 0.056), scope_len=u(0.16, 0.38), scope_h=k * u(0.03, 0.09),
        muzzle=muzzle, muzzle_len=u(0.08, 0.26) if muzzle == "suppressor" else u(0.05, 0.12),
        bipod=k * u(0.12, 0.26) if (style == "sniper" and chance(rng, 0.75)) or (style in ("assault", "hunting")
                                                                                 and chance(rng, 0.2)) else 0.0,
        bolt=style in ("hunting", "sniper") and chance(rng, 0.9),
        foregrip=fore == "handguard" and chance(rng, 0.3), scope_z=u(-0.12, 0.06), mag_z=u(-0.08, 0.02),
        stock_w=u(0.0285, 0.075), fore_w=u(0.0285, 0.07), mag_w=u(0.0285, 0.06), grip_w=u(0.0285, 0.055),
        grip_t=u(0.0285, 0.05), hole_len=u(0.3, 0.75), hole_h=u(0.3, 0.6),
        bipod_angle=u(1.3, 1.5) if chance(rng, 0.35) else u(-0.3, 0.8), bipod_splay=u(0.0, 0.6),
        sling=u(0.03, 0.16) if chance(rng, 0.35) else 0.0, scope_bell=u(1.0, 1.6),
        comb=u(0.035, 0.07) if chance(rng, 0.3) else 0.0, muzzle_r=u(0.012, 0.04),
        stacked=double and chance(rng, 0.5), tube_len=u(0.35, 1.0),
        mag_in_grip=style == "smg" and magazine == "box" and chance(rng, 0.35))


def _line(z0: float, y0: float, z1: float, y1: float):
    """y on the straight line through (z0, y0) and (z1, y1), as a function of z."""
    return lambda z: y0 + (y1 - y0) * (z - z0) / (z1 - z0)


def build(p: RifleParams) -> CSGShape:
    b = CSGBuilder()
    rr, rw, sw = p.barrel_r, p.half_w, p.stock_w
    zr0, zr1, zb = p.recv_z, min(p.recv_z + p.recv_len, 0.5), 0.5
    ytop = p.recv_top
    yb = ytop - p.recv_h
    tz = zr0 + (zr1 - zr0) * p.trigger_at
    sling_rear = None
    b.part("stock")
    if p.stock in ("solid", "thumbhole", "hollow"):  # first: its profile is cut by planes that must miss the rest
        z0, top0 = zr1 - 0.03, ytop - 0.005
        toe = top0 - p.stock_drop - p.stock_h
        b.box_between((-sw, toe, z0), (sw, top0, zb), rounding=0.01)
        if abs(p.stock_drop) > 0.005:
            cut_beyond(b, (0, top0, z0 + 0.03), (0, top0 - p.stock_drop, zb), X, (0, 1, 0), sw + 0.05, margin=0.1)
        zw, yw = zr1 + p.wrist, yb + 0.005  # the wrist's underside, level back to zw, then down to the toe
        if p.grip:
            yw = max(yw, toe + 0.06)
        cut_beyond(b, (0, yw, z0 - 0.05), (0, yw, zw), X, (0, -1, 0), sw + 0.05, margin=0.0)
        cut_beyond(b, (0, yw, zw), (0, toe, zb - 0.01), X, (0, -1, 0), sw + 0.05, margin=0.0)
        top = _line(z0, top0, zb, top0 - p.stock_drop)
        under = _line(zw, yw, zb - 0.01, toe)
        sling_rear = np.array([0.0, under(zb - 0.1) + 0.03, zb - 0.1])
        if p.comb > 0:  # a cheek riser along the top line
            za = max(zw, z0 + 0.06)
            bar(b, (0, top(za) + p.comb / 2 - 0.01, za), (0, top(zb - 0.06) + p.comb / 2 - 0.01, zb - 0.06),
                2 * min(sw, 0.045), p.comb + 0.02, X)
        if p.stock == "thumbhole":  # where the stock is tall enough around it
            zh = zb - 0.2
            hh = 0.029 + 0.02 * p.hole_h
            if top(zh) - under(zh) > 2 * hh + 2 * MIN_PART + 0.01:
                b.box((0, (top(zh) + under(zh)) / 2, zh), (sw + 0.02, hh, 0.04 + 0.04 * p.hole_len), rounding=0.028,
                      op="subtract")
        elif p.stock == "hollow":  # a skeletonised butt: a long opening along the stock's mid line
            z2 = zb - 0.075
            z1 = zw + (1 - p.hole_len) * (z2 - zw) + 0.02
            tall = lambda z: top(z) - under(z)  # noqa: E731
            if tall(zw) < 0.19 < tall(z2):  # it starts where the stock is tall enough for it
                z1 = max(z1, zw + (0.19 - tall(zw)) / (tall(z2) - tall(zw)) * (z2 - zw))
            room = min(tall(z1), tall(z2)) - 0.12
            hh = min(room, p.hole_h * (room + 0.12))
            if hh > 0.058 and z2 - z1 > 0.06:
                mid0, mid1 = (top(z1) + under(z1)) / 2, (top(z2) + under(z2)) / 2
                bar(b, (0, mid0, z1), (0, mid1, z2), 2 * sw + 0.04, hh, X, op="subtract")
    elif p.stock == "skeleton":  # upper strut, butt plate, lower strut (a hole between them)
        y_up = ytop - 0.035
        y_butt0 = y_up - p.stock_drop - p.stock_h
        b.box_between((-sw, y_up - 0.0285 - max(p.stock_drop, 0.0), zr1 - 0.02), (sw, y_up + 0.0285, zb - 0.05))
        b.box_between((-sw, y_butt0, zb - 0.06), (sw, y_up + 0.0285, zb))  # butt plate
        bar(b, (0, yb + 0.02, zr1 - 0.01), (0, y_butt0 + 0.03, zb - 0.05), 2 * sw, 0.055, X)
        sling_rear = np.array([0.0, y_butt0 + 0.03, zb - 0.04])
    elif p.stock == "tube":
        y_up = ytop - p.recv_h * 0.35
        b.box_between((-0.0285, y_up - 0.0285, zr1 - 0.02), (0.0285, y_up + 0.0285, zb - 0.04))
        b.box_between((-sw, y_up - p.stock_h * 0.75, zb - 0.06), (sw, y_up + 0.035, zb), rounding=0.01)
        sling_rear = np.array([0.0, y_up - p.stock_h * 0.75 + 0.03, zb - 0.03])

    b.part("receiver")
    b.box((0, ytop - p.recv_h / 2, (zr0 + zr1) / 2), (rw, p.recv_h / 2, (zr1 - zr0) / 2), rounding=0.01)
    b.torus((0, yb, tz), 0.05, 0.0275, frame(X, Y))  # the trigger guard: a ring (a hole)
    if p.grip:
        gl = p.grip_len
        rot = rotation(X, -p.grip_angle)
        b.box(np.array([0, yb, tz + 0.07]) + rot @ np.array([0, -gl / 2, 0]), (p.grip_w, gl / 2, p.grip_t), rot,
              rounding=0.01)
    if p.bolt:
        b.rod((0.0, ytop - 0.03, zr1 - 0.04), (0.09, ytop - 0.03 - 0.02, zr1 - 0.03), 0.0275)
        b.sphere((0.09, ytop - 0.05, zr1 - 0.03), 0.034)

    b.part("barrel")
    zm = p.muzzle_z
    if p.double:
        for s in (-1, 1):
            at = (0.0, rr * (s - 1), (zm + zr0) / 2) if p.stacked else (s * rr, 0.0, (zm + zr0) / 2)
            b.box(at, (rr, rr, (zr0 - zm) / 2 + 0.01), rounding=0.01)
    else:
        b.box((0, 0.0, (zm + zr0) / 2), (rr, rr, (zr0 - zm) / 2 + 0.01), rounding=0.01)
    if p.muzzle != "none":
        r = rr + (p.muzzle_r if p.muzzle == "suppressor" else min(p.muzzle_r, 0.02))
        b.cylinder((0, 0.0, zm + p.muzzle_len / 2), r, p.muzzle_len / 2, ALONG_Z)

    b.part("fore_end")
    fl, fw = min(p.fore_len, zr0 - zm - 0.08), p.fore_w
    fore_bottom = -rr
    if p.fore == "forestock":
        b.box((0, -rr - p.fore_h / 2 + 0.02, zr0 - fl / 2 + 0.01), (fw, p.fore_h / 2 + 0.02, fl / 2), rounding=0.01)
        fore_bottom = -rr - p.fore_h
    elif p.fore == "handguard":
        b.box((0, -0.005, zr0 - fl / 2 + 0.01), (fw, rr + p.fore_h * 0.6, fl / 2), rounding=0.015)
        fore_bottom = -rr - p.fore_h * 0.6 - 0.005
        if p.foregrip:
            b.box((0, -rr - p.fore_h * 0.6 - 0.05, zr0 - fl * 0.6), (0.0285, 0.06, 0.03), rounding=0.01)
    elif p.fore == "pump":  # over the tube magazine under the barrel
        zt = max(zr0 - max(p.tube_len * (zr0 - zm - 0.05), fl + 0.12), zm + 0.05)
        b.box((0, -2 * rr + 0.01, (zt + zr0) / 2), (rr, rr, (zr0 - zt) / 2))
        b.box((0, -rr, zr0 - 0.1 - fl / 2), (fw, 2 * rr + 0.01, fl / 2), rounding=0.02)
        fore_bottom = -3 * rr - 0.01
    if p.bipod > 0:  # two legs from under the fore-end: splayed down, swung forward, or folded along the barrel
        b.part("bipod")
        bz = zr0 - fl * 0.8
        fwd = np.sin(p.bipod_angle) * np.cos(p.bipod_splay)
        leg = min(p.bipod, (bz - zm - 0.03) / fwd) if fwd > 0 else p.bipod
        for s in (-1, 1):
            d = np.array([s * np.sin(p.bipod_splay), -np.cos(p.bipod_splay) * np.cos(p.bipod_angle), -fwd])
            top = np.array([s * 0.03, fore_bottom + 0.01, bz])
            b.rod(top, top + leg * d, 0.0275)
    if p.sling > 0 and sling_rear is not None:  # a strap from a swivel under the fore-end to the stock
        b.part("sling")
        front = np.array([0.0, fore_bottom + 0.02, max(zr0 - fl * 0.75, zm + 0.1)])
        low = (front + sling_rear) / 2 - np.array([0.0, p.sling + 0.03, 0.0])
        bar(b, front, low, 0.055, 0.055, X)
        bar(b, low, sling_rear, 0.055, 0.055, X)

    if p.magazine in ("box", "curved", "drum"):
        b.part("magazine")
        mw = p.mag_w
        mz = max(tz - 0.05 - p.mag_depth / 2 - 0.03 + p.mag_z, zr0 + p.mag_depth / 2)
        if p.mag_in_grip and p.grip:  # up through the grip, out below it
            rot = rotation(X, -p.grip_angle)
            ml = p.grip_len + p.mag_len * 0.6
            b.box(np.array([0, yb + 0.02, tz + 0.07]) + rot @ np.array([0, -ml / 2, 0]),
                  (mw, ml / 2, min(p.mag_depth / 2, p.grip_t + 0.01)), rot)
        elif p.magazine == "drum":
            r = p.mag_len * 0.5 + 0.03
            b.cylinder((0, yb - r * 0.8, mz), r, mw + 0.005, ALONG_X)
        else:
            rot = rotation(X, p.mag_tilt)
            top = np.array([0.0, yb + 0.02, mz])
            b.box(top + rot @ np.array([0, -p.mag_len / 2, 0]), (mw, p.mag_len / 2 + 0.02, p.mag_depth / 2), rot)
            if p.magazine == "curved":
                end = top + rot @ np.array([0, -p.mag_len, 0])
                rot2 = rotation(X, p.mag_tilt + p.mag_bend)
                b.box(end + rot2 @ np.array([0, -p.mag_len * 0.35, 0]), (mw, max(p.mag_len * 0.4, 0.03), p.mag_depth / 2),
                      rot2)

    if p.sight != "none":
        b.part("sight")
        if p.sight == "scope":  # on two mounts: a hole between scope and receiver
            sy = ytop + p.scope_h + p.scope_r
            s0 = (zr0 + zr1) / 2 - p.scope_len / 2 + p.scope_z
            b.cylinder((0, sy, s0 + p.scope_len / 2), p.scope_r, p.scope_len / 2, ALONG_Z)
            b.cone((0, sy, s0 - 0.035), 0.04, p.scope_r * p.scope_bell, p.scope_r, ALONG_Z)  # objective bell
            for z in (zr0 + 0.035, zr1 - 0.035):  # under the scope, over the receiver
                z = min(max(z, s0 + 0.03, zr0 + 0.03), s0 + p.scope_len - 0.03, zr1 - 0.03)
                b.box((0, (ytop + sy) / 2, z), (min(rw, 0.04), (sy - ytop) / 2, 0.0275))
        elif p.sight == "carry":  # a bridge over the receiver (a hole)
            b.box((0, ytop + 0.07, (zr0 + zr1) / 2), (rw, 0.0275, (zr1 - zr0) / 2 - 0.02))
            for z in (zr0 + 0.04, zr1 - 0.04):
                b.box((0, ytop + 0.03, z), (rw, 0.04, 0.0275))
        else:  # a rail with a sight block
            b.box((0, ytop + 0.025, (zr0 + zr1) / 2 + 0.02), (rw, 0.03, (zr1 - zr0) / 2 * 0.5))
    return b.shape()
