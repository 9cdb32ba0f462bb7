"""The procedural rifle (see ``make_rifle`` for its styles)."""
from __future__ import annotations

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, frame, bar, cut_beyond, legs, X, Y, ALONG_Z, AXIS_ROD, MIN_PART


def make_rifle(rng: np.random.Generator, style: str) -> CSGShape:
    """Along z, muzzle to -z, butt to +z, about 1 long. "hunting": stock with a dropping comb and
    a forestock under the barrel, bolt handle, optional scope on two mounts (a hole); "assault":
    pistol grip, curved magazine, handguard, skeleton stock (a hole), carry handle or sight;
    "sniper": big scope, bipod, tall stock, mostly with a thumbhole (a hole); "shotgun": pump
    foregrip over a tube magazine, or two barrels. The trigger guard is a ring below the receiver
    (a hole)."""
    b = CSGBuilder()
    zm, zb = -0.5, 0.5  # muzzle, butt
    # the rifle is centred on x = 0, a voxel boundary (see AXIS_ROD): the barrel stays within the two
    # middle voxel columns and the receiver and stock reach well into the next ones
    rr = uniform(rng, *AXIS_ROD)  # barrel radius
    zr0 = uniform(rng, -0.05, 0.05)  # receiver front
    rl = uniform(rng, 0.18, 0.25)
    zr1 = zr0 + rl
    rh = uniform(rng, 0.075, 0.095)
    ytop = rr + uniform(rng, 0.0, 0.02)
    rw = uniform(rng, 0.038, 0.044)  # half width of the receiver and stock
    yb = ytop - rh  # receiver bottom
    if style != "assault":
        # the stock first: its profile is cut by planes, which must not reach the other parts
        drop = uniform(rng, 0.0, 0.03) if style == "sniper" else uniform(rng, 0.02, 0.06)
        bh = uniform(rng, 0.17, 0.2) if style == "sniper" else uniform(rng, 0.12, 0.16)
        z0, top0 = zr1 - 0.03, ytop - 0.005
        toe = top0 - drop - bh
        b.box_between((-rw - 0.003, toe, z0), (rw + 0.003, top0, zb), rounding=0.01)
        cut_beyond(b, (0, top0, z0 + 0.03), (0, top0 - drop, zb), X, (0, 1, 0), rw + 0.05, margin=0.1)
        zw, yw = z0 + uniform(rng, 0.06, 0.1), yb + 0.005  # the wrist's underside
        zt = zb - uniform(rng, 0.0, 0.03)
        cut_beyond(b, (0, yw, zw), (0, toe, zt), X, (0, -1, 0), rw + 0.05, margin=0.2)
        if style == "sniper" and chance(rng, 0.7):  # a thumbhole, where the stock is tall enough around it
            zh = zb - uniform(rng, 0.17, 0.22)
            y_top = top0 - drop * (zh - z0 - 0.03) / (zb - z0 - 0.03)
            y_bot = yw + (toe - yw) * (zh - zw) / (zt - zw)
            if y_top - y_bot > 0.058 + 2 * MIN_PART:
                b.box((0, (y_top + y_bot) / 2, zh), (rw + 0.02, 0.029, 0.06), rounding=0.028, op="subtract")
    b.box((0, ytop - rh / 2, (zr0 + zr1) / 2), (rw, rh / 2, rl / 2), rounding=0.01)  # receiver
    # the trigger guard ring (a hole) and a grip behind it
    tz = zr0 + rl * uniform(rng, 0.45, 0.6)
    b.torus((0, yb, tz), uniform(rng, 0.05, 0.06), 0.0275, frame(X, Y))
    pistol = style == "assault" or (style == "sniper" and chance(rng, 0.3))
    if pistol:
        b.box((0, yb - 0.06, tz + 0.09), (rw, 0.07, 0.035), rotation(X, -0.35), rounding=0.01)
    # barrel
    if style == "shotgun" and chance(rng, 0.5):
        for s in (-1, 1):
            b.box((s * rr, 0.0, (zm + zr0) / 2), (rr, rr, (zr0 - zm) / 2 + 0.01), rounding=0.01)
        b.box((0, -rr * 0.6, zr0 - 0.15), (rw + 0.005, max(rr * 0.8, 0.03), 0.15), rounding=0.01)  # forend
    else:
        z_muzzle = zm if style != "assault" else zm + uniform(rng, 0.0, 0.05)
        b.box((0, 0.0, (z_muzzle + zr0) / 2), (rr, rr, (zr0 - z_muzzle) / 2 + 0.01), rounding=0.01)
        if style == "shotgun":
            b.box((0, -2 * rr + 0.01, (zm + 0.05 + zr0) / 2), (rr, rr, (zr0 - zm - 0.05) / 2), rounding=0.01)  # tube
            pz = zr0 - uniform(rng, 0.12, 0.2)
            b.box((0, -rr, pz), (rw + 0.005, 2 * rr + 0.01, uniform(rng, 0.07, 0.1)), rounding=0.02)  # pump
        elif style == "assault":
            b.box((0, -0.005, zr0 - 0.14), (rw, rr + uniform(rng, 0.02, 0.03), 0.15), rounding=0.015)  # handguard
            b.cylinder((0, 0.0, z_muzzle + 0.03), rr + 0.012, 0.035, ALONG_Z)  # flash hider
            b.box((0, rr + 0.04, zr0 - 0.27), (rw, 0.045, 0.0275))  # front sight post
            # curved magazine in two segments
            mz = zr0 + 0.05
            b.box((0, yb - 0.06, mz), (rw, 0.08, 0.04), rotation(X, 0.2))
            b.box((0, yb - 0.17, mz - 0.05), (rw, 0.06, 0.04), rotation(X, 0.45))
        elif style == "sniper":
            b.cylinder((0, 0.0, zm + 0.03), rr + 0.012, 0.04, ALONG_Z)  # muzzle brake
    # stock
    if style == "assault":
        sz0 = zr1 - 0.01
        b.box((0, ytop - 0.05, (sz0 + zb) / 2), (rw, 0.035, (zb - sz0) / 2))  # upper strut
        b.box((0, ytop - 0.1, zb - 0.03), (rw, 0.09, 0.035))  # butt plate
        bar(b, (0, ytop - 0.12, sz0 + 0.03), (0, ytop - 0.17, zb - 0.05), 2 * rw, 0.055, X)  # lower strut: a hole
        if chance(rng, 0.5):  # carry handle: a bridge over the receiver (a hole)
            b.box((0, ytop + 0.07, (zr0 + zr1) / 2), (rw, 0.0275, rl / 2 - 0.02))
            for z in (zr0 + 0.04, zr1 - 0.04):
                b.box((0, ytop + 0.03, z), (rw, 0.04, 0.0275))
        return b.shape()
    if style in ("hunting", "sniper"):
        b.box((0, -rr - 0.01, zr0 - 0.13), (rw + 0.003, 0.035, 0.14), rounding=0.01)  # forestock
        b.rod((0.0, ytop - 0.03, zr1 - 0.04), (0.09, ytop - 0.03, zr1 - 0.04), 0.0275)  # bolt handle
        b.sphere((0.09, ytop - 0.03, zr1 - 0.04), 0.035)
        if style == "sniper" or chance(rng, 0.6):
            sr = uniform(rng, 0.032, 0.038) if style == "hunting" else uniform(rng, 0.04, 0.05)
            sy = ytop + uniform(rng, 0.06, 0.08) + sr
            s0, s1 = zr0 - uniform(rng, 0.02, 0.08), zr1 + uniform(rng, 0.0, 0.05)
            b.cylinder((0, sy, (s0 + s1) / 2), sr, (s1 - s0) / 2, ALONG_Z)
            b.cone((0, sy, s0 - 0.04), 0.04, sr * 1.5, sr, ALONG_Z)  # objective bell
            for z in (zr0 + 0.04, zr1 - 0.04):
                b.box((0, (ytop + sy) / 2, z), (rw, (sy - ytop) / 2, 0.0275))
        if style == "sniper":  # bipod legs splayed down from the forestock
            bz = zr0 - uniform(rng, 0.18, 0.24)
            leg = uniform(rng, 0.16, 0.22)
            for s in (-1, 1):
                b.rod((0, -rr - 0.03, bz), (s * 0.07, -rr - 0.03 - leg, bz - 0.06), 0.0275)
    return b.shape()


STYLES = ('hunting', 'assault', 'sniper', 'shotgun')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_rifle(*params)
