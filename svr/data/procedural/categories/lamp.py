"""The procedural lamp (see ``make_lamp`` for its styles)."""
from __future__ import annotations

import math

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, chance, frame, bar, hollow_cone, X, AXIS_ROD


def make_lamp(rng: np.random.Generator, style: str) -> CSGShape:
    """"desk": base, a parallelogram lower arm (a hole), an upper arm and a shade open at the
    bottom tilted forwards; "floor": tall pole on a disc with a shade open at both ends on spokes;
    "hanging": ceiling canopy, a rod and a cone, dome or drum shade; "table": a bulbous or
    columnar base with a drum shade on a harp."""
    b = CSGBuilder()
    wall = uniform(rng, 0.055, 0.065)
    if style == "desk":
        # the shade first: its cavity is a cut
        tilt = uniform(rng, 0.2, 0.7)
        down = np.array([0.0, -math.cos(tilt), -math.sin(tilt)])
        base_z = uniform(rng, 0.05, 0.12)
        l1, a1 = uniform(rng, 0.3, 0.42), uniform(rng, -0.35, 0.25)
        p0 = np.array([0.0, 0.09, base_z])
        d1 = np.array([0.0, math.cos(a1), -math.sin(a1)])
        joint = p0 + l1 * d1
        l2, a2 = uniform(rng, 0.25, 0.38), uniform(rng, -0.4, 0.4)
        head = joint + l2 * np.array([0.0, math.sin(a2), -math.cos(a2)])
        sh, rb, rt = uniform(rng, 0.07, 0.1), uniform(rng, 0.12, 0.17), uniform(rng, 0.06, 0.08)
        hollow_cone(b, head + down * sh, frame(-down), sh, rb, rt, wall, open_top=False)
        off = uniform(rng, 0.09, 0.11)
        n1 = np.array([0.0, -d1[2], d1[1]])
        for s in (-1, 1):
            b.rod(p0 + s * n1 * off / 2, joint + s * n1 * off / 2, 0.0275)
        bar(b, joint - n1 * (off / 2 + 0.03), joint + n1 * (off / 2 + 0.03), 0.065, 0.065, X)
        bar(b, p0 - n1 * (off / 2 + 0.03), p0 + n1 * (off / 2 + 0.03), 0.065, 0.065, X)
        b.rod(joint, head, 0.0275)
        if chance(rng, 0.5):
            b.cylinder((0, 0.03, base_z - 0.03), uniform(rng, 0.11, 0.15), 0.03)
        else:
            b.box((0, 0.03, base_z - 0.03), (uniform(rng, 0.1, 0.14), 0.03, uniform(rng, 0.08, 0.12)), rounding=0.01)
        b.box((0, 0.07, base_z), (0.05, 0.04, 0.04))
        return b.shape()
    if style == "floor":
        height = uniform(rng, 0.9, 1.0)
        shade_h = uniform(rng, 0.16, 0.28)
        rb = uniform(rng, 0.14, 0.22)
        rt = rb if chance(rng, 0.3) else uniform(rng, 0.08, 0.13)
        ys0 = height - shade_h
        hollow_cone(b, (0, ys0 + shade_h / 2, 0), np.eye(3), shade_h / 2, rb, rt, wall)
        hp = ys0 + shade_h * uniform(rng, 0.3, 0.5)
        b.cylinder((0, hp / 2, 0), uniform(rng, *AXIS_ROD) * height, hp / 2)  # the height is the longest side
        r_at = rb + (rt - rb) * (hp + 0.03 - ys0) / shade_h - wall / 2
        n = int(rng.integers(2, 4))
        a0 = uniform(rng, 0.0, math.pi)
        for k in range(n):
            a = a0 + 2 * math.pi * k / n
            b.rod((0, hp, 0), (r_at * math.cos(a), hp + 0.03, r_at * math.sin(a)), 0.0275)
        b.sphere((0, hp + 0.02, 0), uniform(rng, 0.04, 0.055))
        b.cylinder((0, 0.03, 0), uniform(rng, 0.13, 0.19), 0.03)
        return b.shape()
    if style == "hanging":
        cord = uniform(rng, 0.4, 0.75)
        if chance(rng, 0.3):  # chandelier: small shades on arms around a stem
            n = int(rng.integers(3, 6))
            arm = uniform(rng, 0.22, 0.32)
            sh, rb, rt = uniform(rng, 0.05, 0.07), uniform(rng, 0.08, 0.1), uniform(rng, 0.04, 0.05)
            a0 = uniform(rng, 0.0, math.pi)
            for k in range(n):
                a = a0 + 2 * math.pi * k / n
                hollow_cone(b, (arm * math.cos(a), sh, arm * math.sin(a)), np.eye(3), sh, rb, rt, wall,
                             open_top=False)
            top = 2 * sh
            for k in range(n):
                a = a0 + 2 * math.pi * k / n
                b.rod((0, top - 0.0275, 0), (arm * math.cos(a), top - 0.0275, arm * math.sin(a)), 0.0275)
            b.sphere((0, top - 0.03, 0), uniform(rng, 0.04, 0.05))  # finial
        else:
            kind = ("cone", "dome", "drum")[int(rng.integers(0, 3))]
            if kind == "cone":
                sh, rb, rt = uniform(rng, 0.08, 0.13), uniform(rng, 0.12, 0.2), uniform(rng, 0.04, 0.06)
                rb = min(rb, rt + 1.3 * sh)  # a flatter cone would end in a knife-thin rim
                hollow_cone(b, (0, sh, 0), np.eye(3), sh, rb, rt, wall, open_top=False)
                top = 2 * sh
            elif kind == "dome":
                r = uniform(rng, 0.12, 0.2)
                cut = uniform(rng, 0.0, 0.3) * r
                b.sphere((0, 0, 0), r)
                b.sphere((0, 0, 0), r - wall, op="subtract")
                b.box((0, -r / 2 - 0.05 + cut, 0), (r + 0.05, r / 2 + 0.05, r + 0.05), op="subtract")
                top = r
            else:
                r, sh = uniform(rng, 0.12, 0.18), uniform(rng, 0.07, 0.11)
                hollow_cone(b, (0, sh, 0), np.eye(3), sh, r, r, wall)
                b.box((0, 2 * sh - 0.0275, 0), (r - wall / 2, 0.0275, 0.0275))  # the cross it hangs from
                b.box((0, 2 * sh - 0.0275, 0), (0.0275, 0.0275, r - wall / 2))
                top = 2 * sh
            if kind != "drum":  # the bulb, hung from the shade's crown
                b.sphere((0, top - wall - 0.02, 0), uniform(rng, 0.04, 0.055))
                b.cylinder((0, top - wall / 2 - 0.01, 0), 0.0275, wall / 2 + 0.02)
        lo, hi = b.shape().bounds
        width = float((hi - lo)[[0, 2]].max())
        canopy = min(uniform(rng, 0.08, 0.11), 0.3 * width)  # narrower than the shade: it reads as a ceiling mount
        longest = max(width, top + cord + 0.04 - float(lo[1]))
        b.cylinder((0, top + cord / 2 - 0.02, 0), uniform(rng, *AXIS_ROD) * longest, cord / 2)
        b.cone((0, top + cord, 0), 0.04, canopy * uniform(rng, 0.65, 0.8), canopy)
        return b.shape()
    # table lamp
    shade_h = uniform(rng, 0.15, 0.24)
    rb = uniform(rng, 0.15, 0.22)
    rt = rb * uniform(rng, 0.6, 1.0)
    kind = ("sphere", "column", "vase")[int(rng.integers(0, 3))]
    if kind == "sphere":
        r, foot = uniform(rng, 0.1, 0.14), uniform(rng, 0.07, 0.1)
        base_top = 0.05 + 1.8 * r
    elif kind == "column":
        r, hc, foot = uniform(rng, 0.06, 0.1), uniform(rng, 0.2, 0.35), uniform(rng, 0.12, 0.16)
        base_top = 0.04 + hc
    else:
        r, hc = uniform(rng, 0.1, 0.14), uniform(rng, 0.18, 0.3)
        foot = r
        base_top = hc
    ys0 = base_top + uniform(rng, 0.08, 0.18)
    hollow_cone(b, (0, ys0 + shade_h / 2, 0), np.eye(3), shade_h / 2, rb, rt, wall)
    hp = ys0 + shade_h * 0.5
    longest = max(ys0 + shade_h, 2 * max(rb, rt, foot, r))
    b.cylinder((0, (base_top + hp) / 2, 0), uniform(rng, *AXIS_ROD) * longest, (hp - base_top) / 2 + 0.02)
    r_at = rb + (rt - rb) * (hp + 0.04 - ys0) / shade_h - wall / 2
    for s in (-1, 1):  # the harp's spokes
        b.rod((0, hp, 0), (s * r_at, hp + 0.04, 0), 0.0275)
    if kind == "sphere":
        b.cylinder((0, 0.025, 0), foot, 0.025)
        b.sphere((0, 0.05 + 0.9 * r, 0), r)
    elif kind == "column":
        b.cylinder((0, 0.02, 0), foot, 0.02 + 0.01)
        b.cylinder((0, 0.04 + hc / 2, 0), r, hc / 2 + 0.01)
    else:
        b.cone((0, hc / 2, 0), hc / 2, r, uniform(rng, 0.035, 0.05))
    return b.shape()


STYLES = ('desk', 'floor', 'hanging', 'table')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_lamp(*params)
