"""The procedural rifle, along z with the muzzle at z = -0.5 and the butt at 0.5, the barrel on the
axis (radius in ``AXIS_ROD``, or a heavy barrel 0.042-0.05). Five styles: "hunting" (solid stock
with a comb, wrist grip, long forestock, bolt handle, scope in 70%), "assault" (pistol grip, curved,
straight or drum magazine, handguard, skeleton, solid or tube stock, carry handle, sight rail or
scope, flash hider, optional foregrip), "sniper" (long barrel, big scope, bipod in 70%, solid stock
mostly with a thumbhole or a skeleton stock, muzzle brake or suppressor), "shotgun" (two barrels, or
one over a tube magazine with a pump) and "smg" (short and tall: pistol grip, long straight
magazine, tube, skeleton or no stock, optional suppressor). Every style draws the receiver's
position (front at -0.3..0.15), length (0.12-0.32, or to the butt without a stock), height and
width, the stock's height (0.06-0.3 at the butt), drop and profile, the grip's angle and length, the
magazine's length and tilt, the fore-end's length and depth, the scope's radius, length and height,
and the muzzle device's length from continuous ranges; parts that are not drawn are absent.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import (uniform, chance, frame, bar, cut_beyond, X, Y, ALONG_X, ALONG_Z,
                                                    AXIS_ROD, MIN_PART)

STYLES = ("hunting", "assault", "sniper", "shotgun", "smg")
STOCKS = ("solid", "thumbhole", "skeleton", "tube", "none")
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


def sample(rng: np.random.Generator, style: str) -> RifleParams:
    u = lambda lo, hi: uniform(rng, lo, hi)  # noqa: E731
    pick = lambda options, p: str(rng.choice(options, p=p))  # noqa: E731
    k = u(1.2, 1.7) if style == "smg" else u(0.8, 1.3)  # size of the parts against the length
    heavy = style in ("sniper", "shotgun", "hunting") and chance(rng, 0.3)  # a heavy barrel reaches well past the axis' voxels
    barrel_r = u(0.042, 0.05) if heavy else u(*AXIS_ROD)
    double = style == "shotgun" and chance(rng, 0.45)
    muzzle_z = -0.5
    if style == "hunting":
        recv_z, recv_len = u(-0.25, 0.1), u(0.14, 0.28)
        stock = "solid"
        grip = chance(rng, 0.15)
        magazine = "box" if chance(rng, 0.3) else "none"
        fore = "forestock"
        sight = "scope" if chance(rng, 0.7) else "none"
        muzzle = "none"
    elif style == "assault":
        recv_z, recv_len = u(-0.2, 0.12), u(0.14, 0.32)
        stock = pick(["skeleton", "solid", "tube"], [0.4, 0.35, 0.25])
        grip = True
        magazine = pick(["curved", "box", "drum"], [0.55, 0.33, 0.12])
        fore = "handguard"
        sight = pick(["carry", "rail", "scope", "none"], [0.35, 0.25, 0.2, 0.2])
        muzzle = "brake" if chance(rng, 0.7) else "none"
    elif style == "sniper":
        recv_z, recv_len = u(-0.1, 0.15), u(0.14, 0.3)
        stock = pick(["thumbhole", "solid", "skeleton"], [0.5, 0.25, 0.25])
        grip = stock == "skeleton" or chance(rng, 0.35)
        magazine = "box" if chance(rng, 0.6) else "none"
        fore = "forestock" if chance(rng, 0.75) else "handguard"
        sight = "scope"
        muzzle = pick(["brake", "suppressor", "none"], [0.5, 0.25, 0.25])
    elif style == "shotgun":
        recv_z, recv_len = u(-0.2, 0.1), u(0.12, 0.26)
        stock = "solid" if chance(rng, 0.85) else "skeleton"
        grip = stock == "skeleton" or chance(rng, 0.15)
        magazine = "none" if double else "tube"
        fore = "forestock" if double else "pump"
        sight = "none"
        muzzle = "none"
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
    recv_h = max(k * u(0.06, 0.13), 0.062)
    tall = style == "sniper"
    return RifleParams(
        style=style, barrel_r=barrel_r, double=double, muzzle_z=muzzle_z, recv_z=recv_z, recv_len=recv_len,
        recv_h=recv_h, recv_top=barrel_r + k * u(0.0, 0.045), half_w=u(0.039, 0.058) * (1.1 if style == "smg" else 1.0),
        stock=stock, stock_h=k * (u(0.14, 0.24) if tall else u(0.08, 0.2)),
        stock_drop=k * (u(-0.02, 0.04) if tall else u(-0.01, 0.1)), wrist=u(0.05, 0.13), grip=grip,
        grip_len=k * u(0.08, 0.15), grip_angle=u(0.05, 0.6), trigger_at=u(0.4, 0.7), magazine=magazine,
        mag_len=k * (u(0.1, 0.22) if style == "smg" else u(0.05, 0.16)), mag_depth=max(k * u(0.05, 0.075), 0.058),
        mag_tilt=u(-0.05, 0.3), mag_bend=u(0.15, 0.45), fore=fore,
        fore_len=u(0.18, 0.42) if fore != "pump" else u(0.1, 0.2), fore_h=k * u(0.025, 0.05), sight=sight,
        scope_r=u(0.042, 0.056) if tall else u(0.038, 0.048), scope_len=u(0.18, 0.34), scope_h=k * u(0.035, 0.075),
        muzzle=muzzle, muzzle_len=u(0.1, 0.2) if muzzle == "suppressor" else u(0.06, 0.1),
        bipod=k * u(0.14, 0.24) if (style == "sniper" and chance(rng, 0.7)) or (style == "assault" and chance(rng, 0.1))
        else 0.0, bolt=style in ("hunting", "sniper") and chance(rng, 0.9),
        foregrip=fore == "handguard" and chance(rng, 0.3), scope_z=u(-0.12, 0.06), mag_z=u(-0.08, 0.02))


def build(p: RifleParams) -> CSGShape:
    b = CSGBuilder()
    rr, rw = p.barrel_r, p.half_w
    zr0, zr1, zb = p.recv_z, min(p.recv_z + p.recv_len, 0.5), 0.5
    ytop = p.recv_top
    yb = ytop - p.recv_h
    tz = zr0 + (zr1 - zr0) * p.trigger_at
    b.part("stock")
    if p.stock in ("solid", "thumbhole"):  # first: its profile is cut by planes that must miss the rest
        z0, top0 = zr1 - 0.03, ytop - 0.005
        toe = top0 - p.stock_drop - p.stock_h
        b.box_between((-rw - 0.003, toe, z0), (rw + 0.003, top0, zb), rounding=0.01)
        if abs(p.stock_drop) > 0.005:
            cut_beyond(b, (0, top0, z0 + 0.03), (0, top0 - p.stock_drop, zb), X, (0, 1, 0), rw + 0.05, margin=0.1)
        zw, yw = zr1 + p.wrist, yb + 0.005  # the wrist's underside, level back to zw, then down to the toe
        if p.grip:
            yw = max(yw, toe + 0.06)
        cut_beyond(b, (0, yw, z0 - 0.05), (0, yw, zw), X, (0, -1, 0), rw + 0.05, margin=0.0)
        cut_beyond(b, (0, yw, zw), (0, toe, zb - 0.01), X, (0, -1, 0), rw + 0.05, margin=0.0)
        if p.stock == "thumbhole":  # where the stock is tall enough around it
            zh = zb - 0.2
            f = (zh - zw) / (zb - 0.01 - zw)
            y_top = top0 - p.stock_drop * (zh - z0) / (zb - z0)
            y_bot = yw + (toe - yw) * f
            if y_top - y_bot > 0.058 + 2 * MIN_PART:
                b.box((0, (y_top + y_bot) / 2, zh), (rw + 0.02, 0.029, 0.06), rounding=0.028, op="subtract")
    elif p.stock == "skeleton":  # upper strut, butt plate, lower strut (a hole between them)
        y_up = ytop - 0.035
        y_butt0 = y_up - p.stock_drop - p.stock_h
        b.box_between((-rw, y_up - 0.0285 - max(p.stock_drop, 0.0), zr1 - 0.02), (rw, y_up + 0.0285, zb - 0.05))
        b.box_between((-rw, y_butt0, zb - 0.06), (rw, y_up + 0.0285, zb))  # butt plate
        bar(b, (0, yb + 0.02, zr1 - 0.01), (0, y_butt0 + 0.03, zb - 0.05), 2 * rw, 0.055, X)
    elif p.stock == "tube":
        y_up = ytop - p.recv_h * 0.35
        b.box_between((-0.0285, y_up - 0.0285, zr1 - 0.02), (0.0285, y_up + 0.0285, zb - 0.04))
        b.box_between((-rw, y_up - p.stock_h * 0.75, zb - 0.06), (rw, y_up + 0.035, zb), rounding=0.01)

    b.part("receiver")
    b.box((0, ytop - p.recv_h / 2, (zr0 + zr1) / 2), (rw, p.recv_h / 2, (zr1 - zr0) / 2), rounding=0.01)
    b.torus((0, yb, tz), 0.05, 0.0275, frame(X, Y))  # the trigger guard: a ring (a hole)
    if p.grip:
        gl = p.grip_len
        rot = rotation(X, -p.grip_angle)
        b.box(np.array([0, yb, tz + 0.07]) + rot @ np.array([0, -gl / 2, 0]), (rw, gl / 2, 0.034), rot, rounding=0.01)
    if p.bolt:
        b.rod((0.0, ytop - 0.03, zr1 - 0.04), (0.09, ytop - 0.03 - 0.02, zr1 - 0.03), 0.0275)
        b.sphere((0.09, ytop - 0.05, zr1 - 0.03), 0.034)

    b.part("barrel")
    zm = p.muzzle_z
    if p.double:
        for s in (-1, 1):
            b.box((s * rr, 0.0, (zm + zr0) / 2), (rr, rr, (zr0 - zm) / 2 + 0.01), rounding=0.01)
    else:
        b.box((0, 0.0, (zm + zr0) / 2), (rr, rr, (zr0 - zm) / 2 + 0.01), rounding=0.01)
    if p.muzzle == "brake":
        b.cylinder((0, 0.0, zm + p.muzzle_len / 2), rr + 0.012, p.muzzle_len / 2, ALONG_Z)
    elif p.muzzle == "suppressor":
        b.cylinder((0, 0.0, zm + p.muzzle_len / 2), rr + 0.02, p.muzzle_len / 2, ALONG_Z)

    b.part("fore_end")
    fl = min(p.fore_len, zr0 - zm - 0.08)
    if p.fore == "forestock":
        b.box((0, -rr - p.fore_h / 2 + 0.02, zr0 - fl / 2 + 0.01), (rw + 0.003, p.fore_h / 2 + 0.02, fl / 2),
              rounding=0.01)
    elif p.fore == "handguard":
        b.box((0, -0.005, zr0 - fl / 2 + 0.01), (rw, rr + p.fore_h * 0.6, fl / 2), rounding=0.015)
        if p.foregrip:
            b.box((0, -rr - p.fore_h * 0.6 - 0.05, zr0 - fl * 0.6), (0.0285, 0.06, 0.03), rounding=0.01)
    elif p.fore == "pump":  # over the tube magazine under the barrel
        b.box((0, -2 * rr + 0.01, (zm + 0.05 + zr0) / 2), (rr, rr, (zr0 - zm - 0.05) / 2))
        b.box((0, -rr, zr0 - 0.1 - fl / 2), (rw + 0.005, 2 * rr + 0.01, fl / 2), rounding=0.02)
    if p.bipod > 0:  # legs splayed down from under the fore-end
        bz = zr0 - fl * 0.8
        for s in (-1, 1):
            b.rod((0, -rr - 0.02, bz), (s * 0.07, -rr - 0.02 - p.bipod, bz - 0.06), 0.0275)

    if p.magazine in ("box", "curved", "drum"):
        b.part("magazine")
        mz = max(tz - 0.05 - p.mag_depth / 2 - 0.03 + p.mag_z, zr0 + p.mag_depth / 2)
        if p.magazine == "drum":
            r = p.mag_len * 0.5 + 0.03
            b.cylinder((0, yb - r * 0.8, mz), r, rw + 0.005, ALONG_X)
        else:
            rot = rotation(X, p.mag_tilt)
            top = np.array([0.0, yb + 0.02, mz])
            b.box(top + rot @ np.array([0, -p.mag_len / 2, 0]), (rw, p.mag_len / 2 + 0.02, p.mag_depth / 2), rot)
            if p.magazine == "curved":
                end = top + rot @ np.array([0, -p.mag_len, 0])
                rot2 = rotation(X, p.mag_tilt + p.mag_bend)
                b.box(end + rot2 @ np.array([0, -p.mag_len * 0.35, 0]), (rw, max(p.mag_len * 0.4, 0.03), p.mag_depth / 2), rot2)

    if p.sight != "none":
        b.part("sight")
        if p.sight == "scope":  # on two mounts: a hole between scope and receiver
            sy = ytop + p.scope_h + p.scope_r
            s0 = (zr0 + zr1) / 2 - p.scope_len / 2 + p.scope_z
            b.cylinder((0, sy, s0 + p.scope_len / 2), p.scope_r, p.scope_len / 2, ALONG_Z)
            b.cone((0, sy, s0 - 0.035), 0.04, p.scope_r * 1.35, p.scope_r, ALONG_Z)  # objective bell
            for z in (zr0 + 0.035, zr1 - 0.035):  # under the scope, over the receiver
                z = min(max(z, s0 + 0.03, zr0 + 0.03), s0 + p.scope_len - 0.03, zr1 - 0.03)
                b.box((0, (ytop + sy) / 2, z), (rw, (sy - ytop) / 2, 0.0275))
        elif p.sight == "carry":  # a bridge over the receiver (a hole)
            b.box((0, ytop + 0.07, (zr0 + zr1) / 2), (rw, 0.0275, (zr1 - zr0) / 2 - 0.02))
            for z in (zr0 + 0.04, zr1 - 0.04):
                b.box((0, ytop + 0.03, z), (rw, 0.04, 0.0275))
        else:  # a rail with a sight block
            b.box((0, ytop + 0.025, (zr0 + zr1) / 2 + 0.02), (rw, 0.03, (zr1 - zr0) / 2 * 0.5))
    return b.shape()
