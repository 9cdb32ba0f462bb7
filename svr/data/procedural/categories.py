"""The procedural shape categories of the ShapeNet-shaped benchmark, as parametric CSG shapes: the
13 categories of NMR ShapeNet (the same synset ids, in the order of
``svr.data.nmr.NMR_CATEGORIES``) and two extras (mug, shelf). Each category has a few *styles*,
structurally different variants (a swivel chair is not a four-legged chair with other
proportions); within a style the proportions and optional parts are drawn from a
``numpy.random.Generator``, so that an object is reproducible from its seed (``make_shape``,
which also normalises it: bounding box centred, longest side 1, as ShapeNet). The conventions
every raw shape keeps (orientation, thinnest part, holes, the size of a CSG program) are in the
docstring of ``ProceduralCategory``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence, Union

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation

Seed = Union[int, Sequence[int]]

# Raw-size limits behind the thinnest normalised part (see ProceduralCategory): MIN_PART / MAX_RAW_SIZE.
MIN_PART = 0.055
MAX_RAW_SIZE = 1.1

# Normalisation centres a symmetric object's bounding box on a corner of the benchmark's 32^3 voxel
# grid (voxel side 1/31). A rod on the symmetry axis whose radius just exceeds a voxel side touches
# the next ring of voxels by a sliver, and the protocol's voxels of it then hang on sub-voxel details
# of the mesh (even the exact shape loses a tenth of its IoU). Such rods get a normalised radius
# below one voxel side.
AXIS_ROD = (0.0255, 0.0285)

_X = (1.0, 0.0, 0.0)
_Y = (0.0, 1.0, 0.0)
_Z = (0.0, 0.0, 1.0)


# ---------------------------------------------------------------------------------------------
# Building blocks


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _chance(rng: np.random.Generator, p: float) -> bool:
    return bool(rng.random() < p)


def _frame(y_dir: Sequence[float], x_hint: Sequence[float] = _X) -> np.ndarray:
    """(3, 3) rotation (local -> world) whose local y is ``y_dir`` and whose local x is ``x_hint``
    made orthogonal to it, so that boxes keep a chosen roll (``csg.frame_with_y`` picks any)."""
    y = np.asarray(y_dir, dtype=np.float64)
    y = y / np.linalg.norm(y)
    x = np.asarray(x_hint, dtype=np.float64)
    x = x - (x @ y) * y
    x = x / np.linalg.norm(x)
    return np.stack([x, y, np.cross(x, y)], axis=1)


ALONG_X = _frame(_X, _Y)  # local y (a cylinder's or cone's axis) -> world x
ALONG_Z = _frame(_Z, _X)  # local y -> world z


def _bar(b: CSGBuilder, p0, p1, width: float, depth: float, x_hint: Sequence[float] = _X,
         op: str = "union") -> None:
    """A box from p0 to p1 (its axis) with a width x depth cross-section, width along ``x_hint``."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    b.box((p0 + p1) / 2, (width / 2, np.linalg.norm(p1 - p0) / 2, depth / 2), _frame(p1 - p0, x_hint), op=op)


def _cut_beyond(b: CSGBuilder, a, c, across: Sequence[float], away: Sequence[float], half_across: float,
                depth: float = 0.6, margin: float = 0.3) -> None:
    """Subtracts a box lying on the ``away`` side of the plane that holds the segment a-c and the
    direction ``across``: the box spans ``half_across`` either side of the segment along ``across``
    and runs ``margin`` past its ends, so that a cut stays local to the part it shapes."""
    a, c = np.asarray(a, dtype=np.float64), np.asarray(c, dtype=np.float64)
    u = np.asarray(across, dtype=np.float64)
    u = u / np.linalg.norm(u)
    n = np.cross(u, c - a)
    n = n / np.linalg.norm(n)
    if n @ np.asarray(away, dtype=np.float64) < 0:
        n = -n
    half = (half_across, depth / 2, np.linalg.norm(c - a) / 2 + margin)
    b.box((a + c) / 2 + n * depth / 2, half, _frame(n, u), op="subtract")


def _hollow_cone(b: CSGBuilder, centre, rot: np.ndarray, half: float, r_bottom: float, r_top: float,
                 wall: float, open_bottom: bool = True, open_top: bool = True) -> None:
    """A cone (``CSGBuilder.cone``) hollowed to a shell ``wall`` thick, open at either end.

    The cavity is a cone with the same slope whose radius is smaller by the wall measured across
    the slanted side, so the shell is ``wall`` thick everywhere."""
    k = (r_top - r_bottom) / (2 * half)  # radius change per unit of local y
    ext = 0.03
    y0 = -half - ext if open_bottom else -half + wall
    y1 = half + ext if open_top else half - wall
    delta = wall * math.sqrt(1 + k * k)
    rb = r_bottom + k * (y0 + half) - delta
    rt = r_bottom + k * (y1 + half) - delta
    centre = np.asarray(centre, dtype=np.float64)
    b.cone(centre, half, r_bottom, r_top, rot)
    b.cone(centre + rot @ np.array([0.0, (y0 + y1) / 2, 0.0]), (y1 - y0) / 2, rb, rt, rot, op="subtract")


def _tail_cone(b: CSGBuilder, z0: float, z1: float, r0: float, r1: float) -> None:
    """A fuselage's tail: a cone from radius r0 at z0 (axis on y = 0) to r1 at z1, its axis rising
    so that the top line stays level, as an airliner's tail sweeps up from the belly."""
    a, c = np.array([0.0, 0.0, z0]), np.array([0.0, r0 - r1, z1])
    b.cone((a + c) / 2, np.linalg.norm(c - a) / 2, r0, r1, _frame(c - a, _X))


def _legs(b: CSGBuilder, xs: Sequence[float], zs: Sequence[float], top: float, thick: float, round_legs: bool) -> None:
    for x in xs:
        for z in zs:
            if round_legs:
                b.cylinder((x, top / 2, z), thick / 2, top / 2)
            else:
                b.box((x, top / 2, z), (thick / 2, top / 2, thick / 2))


def _recess(b: CSGBuilder, x0: float, x1: float, y0: float, y1: float, z_face: float, depth: float) -> None:
    """Subtracts a shallow rectangular recess from a face at z = z_face that faces -z (a screen, a
    door panel): it reads as an outline in a render and barely changes the voxels."""
    b.box(((x0 + x1) / 2, (y0 + y1) / 2, z_face), (abs(x1 - x0) / 2, abs(y1 - y0) / 2, depth), op="subtract")


def _driver(b: CSGBuilder, x: float, y: float, z_face: float, radius: float, depth: float) -> None:
    """A loudspeaker driver in a face at z = z_face that faces -z: a conical dish."""
    half = depth / 2 + 0.005
    b.cone((x, y, z_face + half - 0.01), half, radius, 0.45 * radius, ALONG_Z, op="subtract")


# ---------------------------------------------------------------------------------------------
# Categories. Every ``make_*`` takes (rng, style) and returns the raw shape.


def make_airplane(rng: np.random.Generator, style: str) -> CSGShape:
    """Fuselage along z with the nose to -z. "airliner": swept wings with 2 or 4 engines under
    them; "fighter": delta wing cut from a plate, pointed nose, canopy, one or two fins;
    "propeller": straight high or low wing, propeller at the nose, optional struts (holes) and
    landing gear; "bizjet": swept wings, engines on the rear fuselage and a T-tail."""
    b = CSGBuilder()
    th = _u(rng, 0.055, 0.065)  # wing thickness
    if style == "fighter":
        length, fr = _u(rng, 0.95, 1.0), _u(rng, 0.055, 0.07)
        span = _u(rng, 0.55, 0.75)
        z_apex, z_trail = _u(rng, -0.2, -0.05), _u(rng, 0.3, 0.4)
        wy = _u(rng, -0.02, 0.0)
        # the delta: a plate whose leading edges are cut away; built first so the cuts hit only it
        b.box((0, wy, (z_apex + z_trail) / 2), (span / 2, th / 2, (z_trail - z_apex) / 2))
        tip = _u(rng, 0.0, 0.08)  # chord left at the tip (cropped delta)
        for s in (-1, 1):
            _cut_beyond(b, (0, wy, z_apex), (s * span / 2, wy, z_trail - tip), _Y, (s, 0, -1), th)
        b.capsule((0, 0, -length / 2 + 0.25), (0, 0, length / 2 - fr), fr)
        b.cone((0, 0, -length / 2 + 0.13), 0.13, 0.02, fr, ALONG_Z)  # pointed nose
        b.capsule((0, fr * 0.75, -length / 2 + 0.25), (0, fr * 0.75, -length / 2 + 0.42), _u(rng, 0.035, 0.045))
        for s in (-1, 1):  # intakes
            b.box((s * (fr + 0.02), -0.01, 0.0), (0.035, 0.04, 0.14), rounding=0.01)
        fin_h, fin_c = _u(rng, 0.13, 0.2), _u(rng, 0.14, 0.2)
        fz = length / 2 - fin_c / 2 - 0.02
        sweep = rotation(_X, _u(rng, 0.35, 0.6))
        if _chance(rng, 0.5):
            b.box((0, fr + fin_h / 2 - 0.03, fz), (0.03, fin_h / 2, fin_c / 2), sweep)
        else:
            cant = _u(rng, 0.2, 0.4)
            for s in (-1, 1):
                rot = rotation(_Z, -s * cant) @ sweep
                b.box((s * fr * 0.8, fr + fin_h / 2 - 0.04, fz), (0.03, fin_h / 2, fin_c / 2), rot)
        if _chance(rng, 0.5):  # tailplanes
            sspan = _u(rng, 0.14, 0.2)
            for s in (-1, 1):
                b.box((s * (fr + sspan / 2 - 0.02), wy, length / 2 - 0.08), (sspan / 2, th / 2, 0.06))
        b.cylinder((0, 0, length / 2 - 0.02), fr * 0.85, 0.03, ALONG_Z)
        return b.shape()

    if style == "propeller":
        length, fr = _u(rng, 0.7, 0.85), _u(rng, 0.06, 0.08)
        span, chord = _u(rng, 0.9, 1.0), _u(rng, 0.13, 0.18)
        nose = -length / 2
        tail = length / 2
        b.capsule((0, 0, nose + fr), (0, 0, 0.05), fr)
        _tail_cone(b, 0.05, tail, fr, 0.03)
        high = _chance(rng, 0.6)
        wy = fr + th / 2 - 0.01 if high else -fr + th / 2 + 0.01
        wz = nose + _u(rng, 0.2, 0.28)
        b.box((0, wy, wz), (span / 2, th / 2, chord / 2), rounding=0.015)
        if high:
            b.box((0, fr * 0.55, wz - chord * 0.3), (fr * 0.8, fr * 0.6, chord * 0.45), rounding=0.02)  # cabin
            if _chance(rng, 0.6):  # wing struts from the fuselage's belly: two triangles (holes)
                for s in (-1, 1):
                    b.rod((s * fr * 0.6, -fr * 0.5, wz), (s * span * 0.28, wy - th / 2, wz), 0.028)
        b.cone((0, 0, nose - 0.03), 0.04, 0.055, 0.01, _frame((0, 0, -1), _X))  # spinner
        blade = _u(rng, 0.17, 0.24)
        roll = _u(rng, 0.0, math.pi)
        b.box((0, 0, nose - 0.02), (0.035, blade, 0.028), rotation(_Z, roll))
        fin_h, fin_c = _u(rng, 0.13, 0.18), _u(rng, 0.12, 0.16)
        b.box((0, 0.03 + fin_h / 2, tail - fin_c / 2), (0.028, fin_h / 2, fin_c / 2), rotation(_X, 0.35))
        b.box((0, 0.04, tail - 0.06), (_u(rng, 0.16, 0.22), th / 2, 0.055))
        if _chance(rng, 0.6):  # fixed landing gear
            gy = -fr - _u(rng, 0.06, 0.1)
            for s in (-1, 1):
                b.rod((s * 0.02, -fr * 0.5, wz), (s * 0.12, gy, wz), 0.026)
                b.cylinder((s * 0.12, gy, wz), 0.045, 0.028, ALONG_X)
        return b.shape()

    # airliner / bizjet: capsule fuselage with a raised tail cone, swept wings
    if style == "airliner":
        length, fr = _u(rng, 0.9, 1.0), _u(rng, 0.055, 0.075)
        span, chord = _u(rng, 0.85, 1.0), _u(rng, 0.14, 0.2)
        sweep, dihedral = _u(rng, 0.35, 0.6), _u(rng, 0.04, 0.1)
    else:
        length, fr = _u(rng, 0.85, 1.0), _u(rng, 0.055, 0.065)
        span, chord = _u(rng, 0.7, 0.85), _u(rng, 0.12, 0.16)
        sweep, dihedral = _u(rng, 0.3, 0.5), _u(rng, 0.02, 0.07)
    tl = _u(rng, 0.18, 0.25)
    b.capsule((0, 0, -length / 2 + fr), (0, 0, length / 2 - tl), fr)
    _tail_cone(b, length / 2 - tl, length / 2, fr, 0.03)
    wz, wy = _u(rng, -0.1, 0.0), -fr * 0.45
    for side in (-1, 1):
        rot = rotation(_Y, -side * sweep) @ rotation(_Z, side * dihedral)
        centre = np.array([0.0, wy, wz]) + rot @ np.array([side * span / 4, 0, 0])
        b.box(centre, (span / 4, th / 2, chord / 2), rot, rounding=0.015)
    fin_h, fin_c = _u(rng, 0.13, 0.19), _u(rng, 0.12, 0.17)
    fin_sweep = rotation(_X, _u(rng, 0.45, 0.7))
    root = np.array([0.0, fr - 0.02, length / 2 - fin_c / 2 - 0.03])  # on the tail's level top line
    b.box(root + fin_sweep @ np.array([0.0, fin_h / 2, 0.0]), (0.028, fin_h / 2, fin_c / 2), fin_sweep)
    sspan = _u(rng, 0.22, 0.32)
    if style == "airliner":  # on the tail cone's axis
        sz = length / 2 - 0.08
        sy = (fr - 0.03) * (sz - length / 2 + tl) / tl
    else:  # T-tail: the stabiliser sits on the swept fin's tip
        _, sy, sz = root + fin_sweep @ np.array([0.0, fin_h - 0.03, 0.0])
    for side in (-1, 1):
        rot = rotation(_Y, -side * sweep * 0.8)
        b.box(np.array([0.0, sy, sz]) + rot @ np.array([side * sspan / 4, 0, 0]), (sspan / 4, 0.0275, 0.05), rot)
    if style == "airliner":
        er, el = _u(rng, 0.035, 0.05), _u(rng, 0.07, 0.1)
        xs = (0.3,) if _chance(rng, 0.65) else (0.25, 0.55)
        for side in (-1, 1):
            for f in xs:
                x = side * span / 2 * f
                z = wz + math.tan(sweep) * abs(x)
                y = wy + math.tan(dihedral) * abs(x)
                pylon = (0.0275, max(er * 0.6, 0.0275), chord * 0.3)
                b.box((x, y - th / 2 - er * 0.5, z - chord * 0.2), pylon)
                b.cylinder((x, y - th / 2 - er * 0.9, z - chord * 0.45), er, el, ALONG_Z)
    else:
        er, el = _u(rng, 0.035, 0.045), _u(rng, 0.07, 0.09)
        ez = length / 2 - tl - _u(rng, 0.02, 0.08)
        for side in (-1, 1):
            b.box((side * (fr + 0.02), fr * 0.3, ez), (0.04, 0.0275, 0.05))  # pylon
            b.cylinder((side * (fr + er + 0.02), fr * 0.4, ez), er, el, ALONG_Z)
    return b.shape()


def make_bench(rng: np.random.Generator, style: str) -> CSGShape:
    """A long seat along x. "park": slatted seat and back on two side frames, optional armrests
    (holes between the slats and in the frames); "panel": solid seat on end panels with cut-outs,
    optional panel back; "backless": seat on four legs with an optional stretcher; "rail_back":
    four legs, back posts and 1-3 rails."""
    b = CSGBuilder()
    bw, sh = _u(rng, 0.9, 1.0), _u(rng, 0.36, 0.45)
    if style == "park":
        sh = _u(rng, 0.3, 0.36)  # a park bench is long and low
        sd, st = _u(rng, 0.32, 0.4), _u(rng, 0.055, 0.065)
        gap = _u(rng, 0.035, 0.05)
        n = int(rng.integers(3, 1 + int((sd + gap) / (0.065 + gap))))
        sw = (sd - (n - 1) * gap) / n
        for k in range(n):
            z = -sd / 2 + sw / 2 + k * (sw + gap)
            b.box((0, sh - st / 2, z), (bw / 2, st / 2, sw / 2), rounding=0.008)
        px = bw / 2 - _u(rng, 0.06, 0.14)
        bh, lean = _u(rng, 0.24, 0.32), _u(rng, 0.1, 0.3)
        ft = _u(rng, 0.06, 0.075)
        arms = _chance(rng, 0.6)
        z_back = sd / 2
        top = np.array([0.0, sh + bh, z_back + bh * math.tan(lean)])
        for x in (-px, px):
            b.box((x, (sh - st) / 2, -sd / 2 + ft / 2 + 0.02), (ft / 2, (sh - st) / 2, ft / 2))  # front leg
            _bar(b, (x, 0.0, z_back - ft / 2), (x, sh - st, z_back - ft / 2), ft, ft)  # back leg
            _bar(b, (x, sh - st - 0.01, z_back - ft / 2), top + (x, 0, 0), ft, ft)  # back support
            b.box((x, sh - st - ft / 2, 0), (ft / 2, ft / 2, sd / 2))  # seat rail
            if arms:
                ay = sh + _u(rng, 0.14, 0.19)
                za = z_back + (ay - sh) * math.tan(lean)
                b.box((x, ay, (-sd / 2 + za) / 2), (ft / 2 + 0.01, 0.03, (za + sd / 2) / 2 + 0.02))
                b.box((x, (sh + ay) / 2, -sd / 2 + ft / 2 + 0.02), (ft / 2, (ay - sh) / 2, ft / 2))
        nb = int(rng.integers(2, 4)) if bh > 0.29 else 2  # back slats, with gaps between them
        rot = rotation(_X, -lean)
        bs = (bh - 0.06) / nb
        slat = max(0.6 * bs, 0.06)
        for k in range(nb):
            h = 0.08 + k * bs + slat / 2
            c = np.array([0.0, sh, z_back]) + rot @ np.array([0.0, h, 0.03])
            b.box(c, (bw / 2, slat / 2, 0.0275), rot, rounding=0.008)
        return b.shape()

    bd, st = _u(rng, 0.3, 0.42), _u(rng, 0.055, 0.075)
    b.box((0, sh + st / 2, 0), (bw / 2, st / 2, bd / 2), rounding=0.01)
    px = bw / 2 - _u(rng, 0.04, 0.12)
    if style == "panel":
        pt = _u(rng, 0.055, 0.07)
        for x in (-px, px):
            b.box((x, sh / 2, 0), (pt / 2, sh / 2, bd / 2 - 0.01))
        cut_w = _u(rng, 0.08, 0.11)
        arch = _chance(rng, 0.5)
        for x in (-px, px):
            if arch:  # a round-topped opening
                r = bd / 2 - cut_w
                b.cylinder((x, sh - cut_w - r, 0), r, pt, ALONG_X, op="subtract")
                b.box((x, (sh - cut_w - r) / 2 - 0.02, 0), (pt, (sh - cut_w - r) / 2 + 0.02, r), op="subtract")
            else:
                b.box((x, sh / 2 - 0.02, 0), (pt, sh / 2 - cut_w, bd / 2 - cut_w), op="subtract")
        if _chance(rng, 0.5):  # solid back panel, set on the seat's rear edge
            bh = _u(rng, 0.22, 0.35)
            b.box((0, sh + st + bh / 2, bd / 2 - 0.03), (bw / 2 - 0.02, bh / 2, 0.03), rotation(_X, -0.12))
        return b.shape()

    lt = _u(rng, 0.055, 0.075)
    lz = bd / 2 - lt / 2 - _u(rng, 0.0, 0.04)
    _legs(b, (-px, px), (-lz, lz), sh, lt, _chance(rng, 0.5))
    if style == "backless":
        if _chance(rng, 0.6):  # H stretcher: loops through the legs and the seat
            y = _u(rng, 0.08, 0.18)
            b.box((0, y, 0), (px, 0.03, 0.03))
            for x in (-px, px):
                b.box((x, y, 0), (0.03, 0.03, lz))
        return b.shape()
    # rail_back
    bh = _u(rng, 0.25, 0.4)
    z = bd / 2 - 0.035
    for x in (-px, px):
        b.box_between((x - 0.03, sh + st, z - 0.03), (x + 0.03, sh + st + bh, z + 0.03))
    n = int(rng.integers(1, 4))
    for k in range(n):
        y = sh + st + bh - 0.04 - k * (bh - 0.06) / n
        b.box_between((-bw / 2 + 0.02, y - 0.03, z - 0.0275), (bw / 2 - 0.02, y + 0.03, z + 0.0275))
    return b.shape()


def make_cabinet(rng: np.random.Generator, style: str) -> CSGShape:
    """A box with its front to -z. "doors": 1-3 doors with handles, on a plinth or legs;
    "open_shelves": compartments open at the front (and maybe the back: holes); "drawers": a chest
    of stacked drawers with knobs; "sideboard": wide and low on legs, drawers over doors."""
    b = CSGBuilder()
    if style == "sideboard":
        w, h, d = _u(rng, 0.95, 1.05), _u(rng, 0.4, 0.55), _u(rng, 0.35, 0.45)
    elif style == "drawers":
        w, h, d = _u(rng, 0.55, 0.9), _u(rng, 0.6, 1.0), _u(rng, 0.35, 0.5)
    else:
        w, h, d = _u(rng, 0.5, 1.0), _u(rng, 0.6, 1.0), _u(rng, 0.3, 0.5)
    on_legs = style == "sideboard" or _chance(rng, 0.35)
    base = _u(rng, 0.1, 0.2) if on_legs else _u(rng, 0.05, 0.08)
    y0 = base
    b.box((0, (y0 + h) / 2, 0), (w / 2, (h - y0) / 2, d / 2))
    front = -d / 2
    gap, groove = 0.022, 0.02
    if style == "open_shelves":
        t = _u(rng, 0.055, 0.065)
        rows, cols = int(rng.integers(2, 5)), int(rng.integers(1, 4 if w > 0.7 else 3))
        open_back = _chance(rng, 0.4)
        cw = (w - (cols + 1) * t) / cols
        chh = (h - y0 - (rows + 1) * t) / rows
        z1 = d / 2 + 0.1 if open_back else d / 2 - t
        for i in range(rows):
            for j in range(cols):
                x0 = -w / 2 + t + j * (cw + t)
                yy = y0 + t + i * (chh + t)
                b.box_between((x0, yy, front - 0.1), (x0 + cw, yy + chh, z1), op="subtract")
    elif style == "doors":
        n = 1 if w < 0.6 else (2 if w < 0.9 or _chance(rng, 0.6) else 3)
        dw = w / n
        for k in range(1, n):
            x = -w / 2 + k * dw
            b.box((x, (y0 + h) / 2, front), (gap / 2, (h - y0) / 2 - 0.03, groove), op="subtract")
        if _chance(rng, 0.5):  # framed door panels
            for k in range(n):
                x0 = -w / 2 + k * dw
                _recess(b, x0 + 0.06, x0 + dw - 0.06, y0 + 0.07, h - 0.07, front, 0.012)
        hl = _u(rng, 0.1, 0.2)
        hy = (y0 + h) / 2 + _u(rng, 0.0, 0.15) * (h - y0)
        for k in range(n):
            # a handle on each door's edge next to its neighbour (the side it opens from)
            x = -w / 2 + (k + (0.0 if k % 2 else 1.0)) * dw + (0.06 if k % 2 else -0.06)
            if n == 1:
                x = w / 2 - 0.07
            b.box((x, hy, front), (0.0275, hl / 2, 0.045), rounding=0.01)
    else:  # drawers, sideboard
        if style == "drawers":
            rows = int(rng.integers(3, 6))
            cols = 2 if w > 0.75 and _chance(rng, 0.5) else 1
            ys = np.linspace(y0, h, rows + 1)
        else:
            rows = 1
            cols = int(rng.integers(2, 4))
            ys = np.array([h - _u(rng, 0.12, 0.16), h])
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
        knob_r = _u(rng, 0.028, 0.035)
        for i in range(rows):
            for j in range(cols):
                x = -w / 2 + (j + 0.5) * w / cols
                b.sphere((x, (ys[i] + ys[i + 1]) / 2, front - 0.01), knob_r)
        if style == "sideboard":
            for j in range(cols):
                x = -w / 2 + (j + 0.5) * w / cols + 0.5 * w / cols - 0.06
                b.box((x, ys[0] - 0.1, front), (0.0275, 0.06, 0.045), rounding=0.01)
    if on_legs:
        lt = _u(rng, 0.055, 0.07)
        inset = _u(rng, 0.0, 0.04)
        _legs(b, (-w / 2 + lt / 2 + inset, w / 2 - lt / 2 - inset), (-d / 2 + lt / 2 + inset, d / 2 - lt / 2 - inset),
              y0 + 0.01, lt, _chance(rng, 0.4))
    else:
        b.box((0, y0 / 2, 0.01), (w / 2 - 0.03, y0 / 2 + 0.005, d / 2 - 0.03))  # plinth
    if style != "open_shelves" and _chance(rng, 0.5):  # a top that overhangs
        b.box((0, h + 0.0275, 0), (w / 2 + 0.02, 0.0275, d / 2 + 0.02), rounding=0.01)
    return b.shape()


def make_car(rng: np.random.Generator, style: str) -> CSGShape:
    """Length along z, bonnet to -z, four wheels in arches. "sedan": bonnet, cabin, boot;
    "wagon": the cabin runs to an upright tailgate; "pickup": a short cab and an open bed; "suv":
    tall, big wheels, boxy; "sports": low and wide, fastback."""
    b = CSGBuilder()
    length = _u(rng, 0.95, 1.0)
    width = _u(rng, 0.44, 0.48) if style == "sports" else _u(rng, 0.4, 0.46)
    big = style in ("suv", "pickup")
    rw = _u(rng, 0.078, 0.092) if big else (_u(rng, 0.062, 0.072) if style == "sports" else _u(rng, 0.066, 0.08))
    yb = rw * (_u(rng, 0.5, 0.7) if big else _u(rng, 0.35, 0.5))  # body bottom
    if style == "sports":
        bh, ch = _u(rng, 0.1, 0.13), _u(rng, 0.08, 0.1)
        zc0, zc1 = _u(rng, -0.12, -0.02), _u(rng, 0.22, 0.3)
        run_f, run_r = _u(rng, 0.18, 0.24), _u(rng, 0.16, 0.24)
    elif style == "suv":
        bh, ch = _u(rng, 0.16, 0.2), _u(rng, 0.13, 0.17)
        zc0, zc1 = _u(rng, -0.2, -0.12), length / 2 - _u(rng, 0.03, 0.06)
        run_f, run_r = _u(rng, 0.1, 0.15), _u(rng, 0.02, 0.06)
    elif style == "wagon":
        bh, ch = _u(rng, 0.13, 0.16), _u(rng, 0.11, 0.14)
        zc0, zc1 = _u(rng, -0.2, -0.12), length / 2 - _u(rng, 0.03, 0.06)
        run_f, run_r = _u(rng, 0.12, 0.17), _u(rng, 0.03, 0.07)
    elif style == "pickup":
        bh, ch = _u(rng, 0.15, 0.18), _u(rng, 0.11, 0.14)
        zc0, zc1 = _u(rng, -0.18, -0.1), _u(rng, 0.05, 0.12)
        run_f, run_r = _u(rng, 0.08, 0.12), 0.0
    else:  # sedan
        bh, ch = _u(rng, 0.13, 0.16), _u(rng, 0.1, 0.13)
        zc0, zc1 = _u(rng, -0.2, -0.12), _u(rng, 0.18, 0.26)
        run_f, run_r = _u(rng, 0.12, 0.18), _u(rng, 0.1, 0.16)
    arch = rw + 0.012
    bed = _u(rng, 0.06, 0.08)
    # the arches must stay inside the body (and under the bed's floor), or they cut it through
    yt = max(yb + bh, rw + arch + _u(rng, 0.065, 0.085) + (bed + 0.02 if style == "pickup" else 0.0))
    tumble = _u(rng, 0.02, 0.04)
    # the cabin first: its sloped windows are cuts that must not reach the body
    b.box((0, yt + (ch - 0.03) / 2, (zc0 + zc1) / 2), (width / 2 - tumble, (ch + 0.03) / 2, (zc1 - zc0) / 2),
          rounding=0.02)
    _cut_beyond(b, (0, yt, zc0), (0, yt + ch, zc0 + run_f), _X, (0, 0.3, -1), width / 2, margin=0.1)
    if run_r > 0:
        _cut_beyond(b, (0, yt, zc1), (0, yt + ch, zc1 - run_r), _X, (0, 0.3, 1), width / 2, margin=0.1)
    wy = yt + ch * 0.5
    wz0, wz1 = zc0 + run_f * 0.75 + 0.03, zc1 - run_r * 0.75 - 0.03
    if wz1 - wz0 > 0.1:  # side windows: shallow recesses that outline the glass in a render
        for s in (-1, 1):
            b.box((s * (width / 2 - tumble), wy, (wz0 + wz1) / 2), (0.012, ch * 0.25, (wz1 - wz0) / 2), op="subtract")
    b.box((0, (yb + yt) / 2, 0), (width / 2, (yt - yb) / 2, length / 2), rounding=_u(rng, 0.03, 0.05))
    if style in ("sedan", "sports", "wagon"):  # bonnet sloping down to the nose
        _cut_beyond(b, (0, yt - _u(rng, 0.03, 0.05), -length / 2), (0, yt, -length / 2 + 0.3), _X, (0, 1, -0.2),
                    width / 2 + 0.01, margin=0.05)
    zf, zr = -length / 2 + arch + _u(rng, 0.07, 0.11), length / 2 - arch - _u(rng, 0.07, 0.12)
    for z in (zf, zr):
        b.cylinder((0, rw, z), arch, width / 2 + 0.05, ALONG_X, op="subtract")
    if style == "pickup":
        b.box_between((-width / 2 + 0.06, yt - bed, zc1 + 0.06),
                      (width / 2 - 0.06, yt + 0.1, length / 2 - 0.06), op="subtract")
    ww = _u(rng, 0.06, 0.075)
    for z in (zf, zr):
        for s in (-1, 1):
            b.cylinder((s * (width / 2 - ww / 2 - 0.005), rw, z), rw, ww / 2, ALONG_X)
    return b.shape()


def _four_leg_chair(rng: np.random.Generator, style: str) -> CSGShape:
    b = CSGBuilder()
    sw, sd, st = _u(rng, 0.42, 0.54), _u(rng, 0.4, 0.5), _u(rng, 0.055, 0.08)
    sh = _u(rng, 0.38, 0.46)
    lt = _u(rng, 0.055, 0.07)
    inset = _u(rng, 0.0, 0.03)
    lx, lz = sw / 2 - lt / 2 - inset, sd / 2 - lt / 2 - inset
    _legs(b, (-lx, lx), (-lz, lz), sh, lt, _chance(rng, 0.5))
    b.box((0, sh + st / 2, 0), (sw / 2, st / 2, sd / 2), rounding=0.01)
    if style != "four_legs" and _chance(rng, 0.4):  # side stretchers: loops with two legs and the seat
        y = _u(rng, 0.08, 0.2)
        for x in (-lx, lx):
            b.box_between((x - 0.0275, y - 0.0275, -lz), (x + 0.0275, y + 0.0275, lz))
    # the back, built upright at the seat's rear edge and tilted backwards about the x axis
    bh, bt = _u(rng, 0.36, 0.5), _u(rng, 0.055, 0.07)
    tilt = _u(rng, 0.0, 0.22)
    pivot = np.array([0.0, sh + st, sd / 2 - bt / 2])
    rot = rotation(_X, -tilt)  # top towards +z

    def back_box(lo, hi):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        b.box(pivot + rot @ ((lo + hi) / 2), np.abs(hi - lo) / 2, rot)

    if style == "four_legs":
        back = "solid"
    elif style == "slatted":
        back = "slats" if _chance(rng, 0.6) else "rails"
    else:
        back = ("solid", "slats", "rails")[int(rng.integers(0, 3))]
    if back == "solid":
        back_box((-sw / 2, 0, -bt / 2), (sw / 2, bh, bt / 2))
    else:
        pw = _u(rng, 0.055, 0.07)
        rail = _u(rng, 0.06, 0.1)
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
        ah = _u(rng, 0.17, 0.25)
        z_back = sd / 2 - bt + (ah + 0.03) * math.tan(tilt) + bt / 2
        for x in (-sw / 2 + 0.03, sw / 2 - 0.03):
            b.box_between((x - 0.035, sh + st + ah - 0.055, -sd / 2 + 0.01), (x + 0.035, sh + st + ah, z_back))
            b.box_between((x - 0.0275, sh + st, -sd / 2 + 0.03), (x + 0.0275, sh + st + ah, -sd / 2 + 0.085))
    return b.shape()


def _swivel_chair(rng: np.random.Generator) -> CSGShape:
    b = CSGBuilder()
    foot_r = _u(rng, 0.24, 0.3)
    casters = _chance(rng, 0.6)
    y_hub = _u(rng, 0.09, 0.12)
    y_end = 0.065 if casters else 0.03
    a0 = _u(rng, 0.0, 2 * math.pi / 5)
    for k in range(5):
        a = a0 + 2 * math.pi * k / 5
        end = (foot_r * math.cos(a), y_end, foot_r * math.sin(a))
        _bar(b, (0, y_hub, 0), end, 0.055, 0.06, _Y)
        if casters:
            b.sphere((end[0], 0.035, end[2]), 0.035)
    b.cylinder((0, y_hub, 0), _u(rng, 0.045, 0.055), 0.04)
    sw, sd, st = _u(rng, 0.44, 0.52), _u(rng, 0.42, 0.5), _u(rng, 0.07, 0.1)
    sh = _u(rng, 0.4, 0.46)
    b.cylinder((0, (y_hub + sh) / 2, 0), _u(rng, 0.03, 0.04), (sh - y_hub) / 2)
    b.box((0, sh - 0.03, 0), (_u(rng, 0.07, 0.1), 0.03, _u(rng, 0.07, 0.1)))
    b.box((0, sh + st / 2, 0), (sw / 2, st / 2, sd / 2), rounding=0.03)
    # back on a support bar behind the seat, with a gap between seat and back
    gap, bh, bt = _u(rng, 0.03, 0.08), _u(rng, 0.32, 0.45), _u(rng, 0.06, 0.08)
    bw = _u(rng, 0.8, 1.0) * sw
    zb = sd / 2 + 0.0275
    y_back = sh + st + gap
    b.box((0, sh + 0.0275 - 0.01, sd / 4 + 0.0275), (0.04, 0.0275, sd / 4 + 0.0275))
    b.box((0, (sh + y_back + 0.1) / 2, zb), (0.04, (y_back + 0.1 - sh) / 2, 0.0275))
    tilt = _u(rng, 0.0, 0.2)
    rot = rotation(_X, -tilt)
    b.box(np.array([0.0, y_back, zb + 0.0275 + bt / 2 - 0.01]) + rot @ np.array([0.0, bh / 2, 0.0]),
          (bw / 2, bh / 2, bt / 2), rot, rounding=0.03)
    if _chance(rng, 0.5):  # arms: a post on each side of the seat and a pad on top
        ah = _u(rng, 0.17, 0.24)
        for s in (-1, 1):
            x = s * (sw / 2 + 0.01)
            b.box((x, sh + (st + ah) / 2, 0.02), (0.0275, (st + ah) / 2, 0.035))
            b.box((x, sh + st + ah, 0.0), (0.04, 0.0275, _u(rng, 0.1, 0.14)), rounding=0.015)
    return b.shape()


def make_chair(rng: np.random.Generator, style: str) -> CSGShape:
    """Seat at about 0.4 with the back at +z. "four_legs": solid back, no arms (genus 0);
    "slatted": back of posts with vertical slats or horizontal rails, optional side stretchers
    (holes); "armchair": four legs, any back, arms that make loops with seat and back; "swivel":
    office chair, seat and back on a column over a five-spoke base, optional casters and arms."""
    if style == "swivel":
        return _swivel_chair(rng)
    return _four_leg_chair(rng, style)


def make_display(rng: np.random.Generator, style: str) -> CSGShape:
    """A screen facing -z (a shallow recess inside a bezel). "monitor": on a neck and a foot,
    the neck sometimes with a cut-out (a hole); "tv": wide, on two feet; "wall": a flat slab
    with a wall bracket behind; "crt": a deep cathode-ray tube box on a swivel foot."""
    b = CSGBuilder()
    if style == "crt":
        w = _u(rng, 0.75, 0.9)
        h = w * _u(rng, 0.82, 0.95)
        fd = _u(rng, 0.12, 0.18)
        foot = _u(rng, 0.05, 0.1)
        y0 = foot + 0.03
        b.box((0, y0 + h / 2, 0), (w / 2, h / 2, fd / 2), rounding=0.02)
        bz = _u(rng, 0.03, 0.05)
        _recess(b, -w / 2 + bz, w / 2 - bz, y0 + bz * 1.4, y0 + h - bz, -fd / 2, 0.02)
        depth = _u(rng, 0.35, 0.5)
        f1, f2 = _u(rng, 0.8, 0.9), _u(rng, 0.5, 0.65)
        b.box((0, y0 + h * 0.52, fd / 2 + depth * 0.25), (w * f1 / 2, h * f1 / 2, depth * 0.25), rounding=0.03)
        b.box((0, y0 + h * 0.55, fd / 2 + depth * 0.7), (w * f2 / 2, h * f2 / 2, depth * 0.2 + 0.02), rounding=0.03)
        b.cylinder((0, foot / 2 + 0.02, fd / 2 + depth * 0.3), _u(rng, 0.08, 0.12), foot / 2 + 0.02)
        b.cylinder((0, 0.0275, fd / 2 + depth * 0.3), _u(rng, 0.18, 0.25), 0.0275)
        return b.shape()
    if style == "tv":
        w, t = _u(rng, 0.95, 1.0), _u(rng, 0.068, 0.075)
        h = w * _u(rng, 0.54, 0.6)
        cy = _u(rng, 0.05, 0.12) + h / 2
    else:
        w, t = _u(rng, 0.85, 1.0), _u(rng, 0.068, 0.085)
        h = w * _u(rng, 0.55, 0.68)
        cy = _u(rng, 0.12, 0.25) + h / 2 if style == "monitor" else 0.0
    if style == "monitor":
        nw = _u(rng, 0.08, 0.16)
        zn = t / 2 + 0.0275 - 0.005
        lean = _u(rng, 0.0, 0.25)
        top = np.array([0.0, cy - h * 0.05, zn])
        foot_c = top + np.array([0.0, -top[1] + 0.05, math.tan(lean) * (top[1] - 0.05)])
        _bar(b, foot_c, top, nw, 0.055)
        if nw > 0.1 and _chance(rng, 0.6):  # a cable cut-out through the neck
            b.box((foot_c + top) / 2, (nw / 2 - 0.03, 0.05, 0.05), op="subtract")
    b.box((0, cy, 0), (w / 2, h / 2, t / 2), rounding=0.01)
    bz = _u(rng, 0.025, 0.045)
    _recess(b, -w / 2 + bz, w / 2 - bz, cy - h / 2 + bz * (1.6 if style == "tv" else 1.0), cy + h / 2 - bz, -t / 2,
            0.01)
    if style == "monitor":
        if _chance(rng, 0.6):  # a housing bulge behind the panel
            b.box((0, cy, t / 2 + 0.02), (w * 0.3, h * 0.3, 0.03), rounding=0.01)
        if _chance(rng, 0.5):
            b.box((0, 0.0275, foot_c[2] - 0.03), (_u(rng, 0.15, 0.22), 0.0275, _u(rng, 0.1, 0.13)), rounding=0.01)
        else:
            b.cylinder((0, 0.0275, foot_c[2] - 0.03), _u(rng, 0.12, 0.17), 0.0275)
        return b.shape()
    if style == "tv":
        fx = w / 2 * _u(rng, 0.6, 0.85)
        fz = _u(rng, 0.09, 0.13)
        for s in (-1, 1):  # each foot an inverted V
            top = (s * fx, cy - h / 2 + 0.05, 0.0)
            _bar(b, top, (s * fx, 0.0275, -fz), 0.06, 0.055)
            _bar(b, top, (s * fx, 0.0275, fz), 0.06, 0.055)
        return b.shape()
    # wall: a bracket plate and an arm to the wall behind, sometimes a sound bar below
    b.box((0, 0, t / 2 + 0.0275), (w * 0.18, h * 0.2, 0.0275))
    b.box((0, 0, t / 2 + 0.07), (w * _u(rng, 0.25, 0.35), h * _u(rng, 0.25, 0.35), 0.0275))
    if _chance(rng, 0.4):
        b.box((0, -h / 2 - 0.05, 0.0), (w * 0.4, 0.0325, 0.04), rounding=0.015)
    return b.shape()


def make_lamp(rng: np.random.Generator, style: str) -> CSGShape:
    """"desk": base, a parallelogram lower arm (a hole), an upper arm and a shade open at the
    bottom tilted forwards; "floor": tall pole on a disc with a shade open at both ends on spokes;
    "hanging": ceiling canopy, a rod and a cone, dome or drum shade; "table": a bulbous or
    columnar base with a drum shade on a harp."""
    b = CSGBuilder()
    wall = _u(rng, 0.055, 0.065)
    if style == "desk":
        # the shade first: its cavity is a cut
        tilt = _u(rng, 0.2, 0.7)
        down = np.array([0.0, -math.cos(tilt), -math.sin(tilt)])
        base_z = _u(rng, 0.05, 0.12)
        l1, a1 = _u(rng, 0.3, 0.42), _u(rng, -0.35, 0.25)
        p0 = np.array([0.0, 0.09, base_z])
        d1 = np.array([0.0, math.cos(a1), -math.sin(a1)])
        joint = p0 + l1 * d1
        l2, a2 = _u(rng, 0.25, 0.38), _u(rng, -0.4, 0.4)
        head = joint + l2 * np.array([0.0, math.sin(a2), -math.cos(a2)])
        sh, rb, rt = _u(rng, 0.07, 0.1), _u(rng, 0.12, 0.17), _u(rng, 0.06, 0.08)
        _hollow_cone(b, head + down * sh, _frame(-down), sh, rb, rt, wall, open_top=False)
        off = _u(rng, 0.09, 0.11)
        n1 = np.array([0.0, -d1[2], d1[1]])
        for s in (-1, 1):
            b.rod(p0 + s * n1 * off / 2, joint + s * n1 * off / 2, 0.0275)
        _bar(b, joint - n1 * (off / 2 + 0.03), joint + n1 * (off / 2 + 0.03), 0.065, 0.065, _X)
        _bar(b, p0 - n1 * (off / 2 + 0.03), p0 + n1 * (off / 2 + 0.03), 0.065, 0.065, _X)
        b.rod(joint, head, 0.0275)
        if _chance(rng, 0.5):
            b.cylinder((0, 0.03, base_z - 0.03), _u(rng, 0.11, 0.15), 0.03)
        else:
            b.box((0, 0.03, base_z - 0.03), (_u(rng, 0.1, 0.14), 0.03, _u(rng, 0.08, 0.12)), rounding=0.01)
        b.box((0, 0.07, base_z), (0.05, 0.04, 0.04))
        return b.shape()
    if style == "floor":
        height = _u(rng, 0.9, 1.0)
        shade_h = _u(rng, 0.16, 0.28)
        rb = _u(rng, 0.14, 0.22)
        rt = rb if _chance(rng, 0.3) else _u(rng, 0.08, 0.13)
        ys0 = height - shade_h
        _hollow_cone(b, (0, ys0 + shade_h / 2, 0), np.eye(3), shade_h / 2, rb, rt, wall)
        hp = ys0 + shade_h * _u(rng, 0.3, 0.5)
        b.cylinder((0, hp / 2, 0), _u(rng, *AXIS_ROD) * height, hp / 2)  # the height is the longest side
        r_at = rb + (rt - rb) * (hp + 0.03 - ys0) / shade_h - wall / 2
        n = int(rng.integers(2, 4))
        a0 = _u(rng, 0.0, math.pi)
        for k in range(n):
            a = a0 + 2 * math.pi * k / n
            b.rod((0, hp, 0), (r_at * math.cos(a), hp + 0.03, r_at * math.sin(a)), 0.0275)
        b.sphere((0, hp + 0.02, 0), _u(rng, 0.04, 0.055))
        b.cylinder((0, 0.03, 0), _u(rng, 0.13, 0.19), 0.03)
        return b.shape()
    if style == "hanging":
        cord = _u(rng, 0.4, 0.75)
        if _chance(rng, 0.3):  # chandelier: small shades on arms around a stem
            n = int(rng.integers(3, 6))
            arm = _u(rng, 0.22, 0.32)
            sh, rb, rt = _u(rng, 0.05, 0.07), _u(rng, 0.08, 0.1), _u(rng, 0.04, 0.05)
            a0 = _u(rng, 0.0, math.pi)
            for k in range(n):
                a = a0 + 2 * math.pi * k / n
                _hollow_cone(b, (arm * math.cos(a), sh, arm * math.sin(a)), np.eye(3), sh, rb, rt, wall,
                             open_top=False)
            top = 2 * sh
            for k in range(n):
                a = a0 + 2 * math.pi * k / n
                b.rod((0, top - 0.0275, 0), (arm * math.cos(a), top - 0.0275, arm * math.sin(a)), 0.0275)
            b.sphere((0, top - 0.03, 0), _u(rng, 0.04, 0.05))  # finial
        else:
            kind = ("cone", "dome", "drum")[int(rng.integers(0, 3))]
            if kind == "cone":
                sh, rb, rt = _u(rng, 0.08, 0.13), _u(rng, 0.12, 0.2), _u(rng, 0.04, 0.06)
                rb = min(rb, rt + 1.3 * sh)  # a flatter cone would end in a knife-thin rim
                _hollow_cone(b, (0, sh, 0), np.eye(3), sh, rb, rt, wall, open_top=False)
                top = 2 * sh
            elif kind == "dome":
                r = _u(rng, 0.12, 0.2)
                cut = _u(rng, 0.0, 0.3) * r
                b.sphere((0, 0, 0), r)
                b.sphere((0, 0, 0), r - wall, op="subtract")
                b.box((0, -r / 2 - 0.05 + cut, 0), (r + 0.05, r / 2 + 0.05, r + 0.05), op="subtract")
                top = r
            else:
                r, sh = _u(rng, 0.12, 0.18), _u(rng, 0.07, 0.11)
                _hollow_cone(b, (0, sh, 0), np.eye(3), sh, r, r, wall)
                b.box((0, 2 * sh - 0.0275, 0), (r - wall / 2, 0.0275, 0.0275))  # the cross it hangs from
                b.box((0, 2 * sh - 0.0275, 0), (0.0275, 0.0275, r - wall / 2))
                top = 2 * sh
            if kind != "drum":  # the bulb, hung from the shade's crown
                b.sphere((0, top - wall - 0.02, 0), _u(rng, 0.04, 0.055))
                b.cylinder((0, top - wall / 2 - 0.01, 0), 0.0275, wall / 2 + 0.02)
        lo, hi = b.shape().bounds
        width = float((hi - lo)[[0, 2]].max())
        canopy = min(_u(rng, 0.08, 0.11), 0.3 * width)  # narrower than the shade: it reads as a ceiling mount
        longest = max(width, top + cord + 0.04 - float(lo[1]))
        b.cylinder((0, top + cord / 2 - 0.02, 0), _u(rng, *AXIS_ROD) * longest, cord / 2)
        b.cone((0, top + cord, 0), 0.04, canopy * _u(rng, 0.65, 0.8), canopy)
        return b.shape()
    # table lamp
    shade_h = _u(rng, 0.15, 0.24)
    rb = _u(rng, 0.15, 0.22)
    rt = rb * _u(rng, 0.6, 1.0)
    kind = ("sphere", "column", "vase")[int(rng.integers(0, 3))]
    if kind == "sphere":
        r, foot = _u(rng, 0.1, 0.14), _u(rng, 0.07, 0.1)
        base_top = 0.05 + 1.8 * r
    elif kind == "column":
        r, hc, foot = _u(rng, 0.06, 0.1), _u(rng, 0.2, 0.35), _u(rng, 0.12, 0.16)
        base_top = 0.04 + hc
    else:
        r, hc = _u(rng, 0.1, 0.14), _u(rng, 0.18, 0.3)
        foot = r
        base_top = hc
    ys0 = base_top + _u(rng, 0.08, 0.18)
    _hollow_cone(b, (0, ys0 + shade_h / 2, 0), np.eye(3), shade_h / 2, rb, rt, wall)
    hp = ys0 + shade_h * 0.5
    longest = max(ys0 + shade_h, 2 * max(rb, rt, foot, r))
    b.cylinder((0, (base_top + hp) / 2, 0), _u(rng, *AXIS_ROD) * longest, (hp - base_top) / 2 + 0.02)
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
        b.cone((0, hc / 2, 0), hc / 2, r, _u(rng, 0.035, 0.05))
    return b.shape()


def make_phone(rng: np.random.Generator, style: str) -> CSGShape:
    """Standing upright, screen to -z. "slab": a smartphone with a recessed screen and a camera
    bump; "flip": an open flip phone, the lid tilted back on a hinge; "desk": a desk telephone
    with a sloped keypad and a handset on its cradle (a hole under the handset); "candybar": a
    thick phone with a small screen, a keypad grid and an antenna stub."""
    b = CSGBuilder()
    if style == "desk":
        w, d, h = _u(rng, 0.85, 1.0), _u(rng, 0.6, 0.8), _u(rng, 0.16, 0.24)
        b.box((0, h / 2, 0), (w / 2, h / 2, d / 2), rounding=0.03)
        # the right part slopes down to the front; the left part stays flat under the handset
        ledge = _u(rng, 0.3, 0.36)
        x0 = -w / 2 + ledge
        y0 = h * _u(rng, 0.35, 0.55)
        xc = (x0 + w / 2 + 0.05) / 2
        _cut_beyond(b, (xc, y0, -d / 2), (xc, h, d / 2 - 0.05), _X, (0, 1, -0.3), (w / 2 + 0.05 - x0) / 2, margin=0.1)
        theta = math.atan2(h - y0, d - 0.05)
        slope = rotation(_X, -theta)
        zk = _u(rng, -0.06, 0.04)
        pad = np.array([(x0 + w / 2) / 2, y0 + (zk + d / 2) * math.tan(theta), zk]) + slope @ np.array([0, 0.01, 0])
        b.box(pad, (0.16, 0.03, 0.13), slope, rounding=0.01)
        for gx in (-0.053, 0.053):  # a 3 x 4 grid of keys
            b.box(pad + slope @ np.array([gx, 0.03, 0.0]), (0.008, 0.012, 0.14), slope, op="subtract")
        for gz in (-0.065, 0.0, 0.065):
            b.box(pad + slope @ np.array([0.0, 0.03, gz]), (0.17, 0.012, 0.008), slope, op="subtract")
        hx = -w / 2 + ledge / 2
        hl = d * _u(rng, 0.75, 0.9)
        hy = h + _u(rng, 0.09, 0.11)
        b.capsule((hx, hy, -hl / 2 + 0.06), (hx, hy, hl / 2 - 0.06), _u(rng, 0.04, 0.045))
        for s in (-1, 1):  # ear and mouth pieces rest on the cradle: the handset bridges a gap (a hole)
            b.box((hx, hy - 0.04, s * (hl / 2 - 0.07)), (0.06, 0.045, 0.07), rounding=0.02)
            b.box((hx, h + 0.01, s * (hl / 2 - 0.07)), (0.08, 0.035, 0.075), rounding=0.01)
        return b.shape()
    if style == "flip":
        w, t = _u(rng, 0.42, 0.5), _u(rng, 0.075, 0.09)
        hb = _u(rng, 0.46, 0.52)
        ht = hb * _u(rng, 0.9, 1.0)
        open_a = _u(rng, 0.25, 0.5)
        # lid first: its recess is a cut
        hinge = np.array([0.0, hb, t / 2])
        rot = rotation(_X, -open_a)
        b.box(hinge + rot @ np.array([0.0, ht / 2, -t / 2]), (w / 2, ht / 2, t / 2), rot, rounding=0.03)
        b.box(hinge + rot @ np.array([0.0, ht * 0.55, -t]), (w / 2 - 0.05, ht * 0.3, 0.012), rot, op="subtract")
        b.box((0, hb / 2, 0), (w / 2, hb / 2, t / 2), rounding=0.03)
        b.box((0, hb * 0.45, -t / 2), (w / 2 - 0.06, hb * 0.3, 0.012), op="subtract")
        for k in range(1, 4):  # keypad grid
            b.box((0, hb * 0.15 + hb * 0.6 * k / 4, -t / 2), (w / 2 - 0.06, 0.009, 0.015), op="subtract")
        b.box((0, hb * 0.45, -t / 2), (0.009, hb * 0.3, 0.015), op="subtract")
        b.cylinder(hinge - np.array([0.0, 0.0, 0.01]), 0.045, w / 2 - 0.02, ALONG_X)
        return b.shape()
    h = _u(rng, 0.88, 0.95) if style == "candybar" else _u(rng, 0.95, 1.0)  # room for the antenna
    if style == "candybar":
        w, t = _u(rng, 0.4, 0.5), _u(rng, 0.12, 0.18)
    else:
        w, t = _u(rng, 0.45, 0.52), _u(rng, 0.07, 0.09)
    b.box((0, h / 2, 0), (w / 2, h / 2, t / 2), rounding=_u(rng, 0.025, 0.045))
    if style == "slab":
        bz, top, bot = _u(rng, 0.025, 0.04), _u(rng, 0.05, 0.1), _u(rng, 0.05, 0.1)
        _recess(b, -w / 2 + bz, w / 2 - bz, bot, h - top, -t / 2, 0.01)
        if _chance(rng, 0.5):  # home button
            b.cylinder((0, bot / 2, -t / 2), min(0.035, bot / 2 - 0.005), 0.01, ALONG_Z, op="subtract")
        cam = _u(rng, 0.1, 0.16)
        b.box((-w / 2 + cam / 2 + 0.04, h - cam / 2 - 0.04, t / 2), (cam / 2, cam / 2, 0.0275), rounding=0.02)
        b.box((w / 2, h * 0.7, 0), (0.0275, 0.07, 0.0275), rounding=0.01)  # side button
        return b.shape()
    # candybar: screen in the upper half, a keypad grid below, an antenna stub
    _recess(b, -w / 2 + 0.06, w / 2 - 0.06, h * 0.55, h - 0.08, -t / 2, 0.02)
    for k in range(1, 5):
        b.box((0, h * 0.06 + h * 0.4 * k / 5, -t / 2), (w / 2 - 0.06, 0.009, 0.02), op="subtract")
    for s in (-1, 1):
        b.box((s * (w / 2 - 0.06) / 3, h * 0.26, -t / 2), (0.009, h * 0.2, 0.02), op="subtract")
    if _chance(rng, 0.6):
        b.cylinder((w / 2 - 0.07, h + 0.05, 0), 0.03, 0.07)
    return b.shape()


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
    rr = _u(rng, *AXIS_ROD)  # barrel radius
    zr0 = _u(rng, -0.05, 0.05)  # receiver front
    rl = _u(rng, 0.18, 0.25)
    zr1 = zr0 + rl
    rh = _u(rng, 0.075, 0.095)
    ytop = rr + _u(rng, 0.0, 0.02)
    rw = _u(rng, 0.038, 0.044)  # half width of the receiver and stock
    yb = ytop - rh  # receiver bottom
    if style != "assault":
        # the stock first: its profile is cut by planes, which must not reach the other parts
        drop = _u(rng, 0.0, 0.03) if style == "sniper" else _u(rng, 0.02, 0.06)
        bh = _u(rng, 0.17, 0.2) if style == "sniper" else _u(rng, 0.12, 0.16)
        z0, top0 = zr1 - 0.03, ytop - 0.005
        toe = top0 - drop - bh
        b.box_between((-rw - 0.003, toe, z0), (rw + 0.003, top0, zb), rounding=0.01)
        _cut_beyond(b, (0, top0, z0 + 0.03), (0, top0 - drop, zb), _X, (0, 1, 0), rw + 0.05, margin=0.1)
        zw, yw = z0 + _u(rng, 0.06, 0.1), yb + 0.005  # the wrist's underside
        zt = zb - _u(rng, 0.0, 0.03)
        _cut_beyond(b, (0, yw, zw), (0, toe, zt), _X, (0, -1, 0), rw + 0.05, margin=0.2)
        if style == "sniper" and _chance(rng, 0.7):  # a thumbhole, where the stock is tall enough around it
            zh = zb - _u(rng, 0.17, 0.22)
            y_top = top0 - drop * (zh - z0 - 0.03) / (zb - z0 - 0.03)
            y_bot = yw + (toe - yw) * (zh - zw) / (zt - zw)
            if y_top - y_bot > 0.058 + 2 * MIN_PART:
                b.box((0, (y_top + y_bot) / 2, zh), (rw + 0.02, 0.029, 0.06), rounding=0.028, op="subtract")
    b.box((0, ytop - rh / 2, (zr0 + zr1) / 2), (rw, rh / 2, rl / 2), rounding=0.01)  # receiver
    # the trigger guard ring (a hole) and a grip behind it
    tz = zr0 + rl * _u(rng, 0.45, 0.6)
    b.torus((0, yb, tz), _u(rng, 0.05, 0.06), 0.0275, _frame(_X, _Y))
    pistol = style == "assault" or (style == "sniper" and _chance(rng, 0.3))
    if pistol:
        b.box((0, yb - 0.06, tz + 0.09), (rw, 0.07, 0.035), rotation(_X, -0.35), rounding=0.01)
    # barrel
    if style == "shotgun" and _chance(rng, 0.5):
        for s in (-1, 1):
            b.box((s * rr, 0.0, (zm + zr0) / 2), (rr, rr, (zr0 - zm) / 2 + 0.01), rounding=0.01)
        b.box((0, -rr * 0.6, zr0 - 0.15), (rw + 0.005, max(rr * 0.8, 0.03), 0.15), rounding=0.01)  # forend
    else:
        z_muzzle = zm if style != "assault" else zm + _u(rng, 0.0, 0.05)
        b.box((0, 0.0, (z_muzzle + zr0) / 2), (rr, rr, (zr0 - z_muzzle) / 2 + 0.01), rounding=0.01)
        if style == "shotgun":
            b.box((0, -2 * rr + 0.01, (zm + 0.05 + zr0) / 2), (rr, rr, (zr0 - zm - 0.05) / 2), rounding=0.01)  # tube
            pz = zr0 - _u(rng, 0.12, 0.2)
            b.box((0, -rr, pz), (rw + 0.005, 2 * rr + 0.01, _u(rng, 0.07, 0.1)), rounding=0.02)  # pump
        elif style == "assault":
            b.box((0, -0.005, zr0 - 0.14), (rw, rr + _u(rng, 0.02, 0.03), 0.15), rounding=0.015)  # handguard
            b.cylinder((0, 0.0, z_muzzle + 0.03), rr + 0.012, 0.035, ALONG_Z)  # flash hider
            b.box((0, rr + 0.04, zr0 - 0.27), (rw, 0.045, 0.0275))  # front sight post
            # curved magazine in two segments
            mz = zr0 + 0.05
            b.box((0, yb - 0.06, mz), (rw, 0.08, 0.04), rotation(_X, 0.2))
            b.box((0, yb - 0.17, mz - 0.05), (rw, 0.06, 0.04), rotation(_X, 0.45))
        elif style == "sniper":
            b.cylinder((0, 0.0, zm + 0.03), rr + 0.012, 0.04, ALONG_Z)  # muzzle brake
    # stock
    if style == "assault":
        sz0 = zr1 - 0.01
        b.box((0, ytop - 0.05, (sz0 + zb) / 2), (rw, 0.035, (zb - sz0) / 2))  # upper strut
        b.box((0, ytop - 0.1, zb - 0.03), (rw, 0.09, 0.035))  # butt plate
        _bar(b, (0, ytop - 0.12, sz0 + 0.03), (0, ytop - 0.17, zb - 0.05), 2 * rw, 0.055, _X)  # lower strut: a hole
        if _chance(rng, 0.5):  # carry handle: a bridge over the receiver (a hole)
            b.box((0, ytop + 0.07, (zr0 + zr1) / 2), (rw, 0.0275, rl / 2 - 0.02))
            for z in (zr0 + 0.04, zr1 - 0.04):
                b.box((0, ytop + 0.03, z), (rw, 0.04, 0.0275))
        return b.shape()
    if style in ("hunting", "sniper"):
        b.box((0, -rr - 0.01, zr0 - 0.13), (rw + 0.003, 0.035, 0.14), rounding=0.01)  # forestock
        b.rod((0.0, ytop - 0.03, zr1 - 0.04), (0.09, ytop - 0.03, zr1 - 0.04), 0.0275)  # bolt handle
        b.sphere((0.09, ytop - 0.03, zr1 - 0.04), 0.035)
        if style == "sniper" or _chance(rng, 0.6):
            sr = _u(rng, 0.032, 0.038) if style == "hunting" else _u(rng, 0.04, 0.05)
            sy = ytop + _u(rng, 0.06, 0.08) + sr
            s0, s1 = zr0 - _u(rng, 0.02, 0.08), zr1 + _u(rng, 0.0, 0.05)
            b.cylinder((0, sy, (s0 + s1) / 2), sr, (s1 - s0) / 2, ALONG_Z)
            b.cone((0, sy, s0 - 0.04), 0.04, sr * 1.5, sr, ALONG_Z)  # objective bell
            for z in (zr0 + 0.04, zr1 - 0.04):
                b.box((0, (ytop + sy) / 2, z), (rw, (sy - ytop) / 2, 0.0275))
        if style == "sniper":  # bipod legs splayed down from the forestock
            bz = zr0 - _u(rng, 0.18, 0.24)
            leg = _u(rng, 0.16, 0.22)
            for s in (-1, 1):
                b.rod((0, -rr - 0.03, bz), (s * 0.07, -rr - 0.03 - leg, bz - 0.06), 0.0275)
    return b.shape()


def make_sofa(rng: np.random.Generator, style: str) -> CSGShape:
    """Back at +z. "straight": base, back and two arms, 2-3 seat cushions; "sectional": L-shaped
    with a chaise reaching forward on one side; "armless": on taller legs, no arms; "loveseat":
    two cushions, thick rolled arms."""
    b = CSGBuilder()
    if style == "loveseat":
        w, d = _u(rng, 0.65, 0.8), _u(rng, 0.42, 0.52)
    else:
        w, d = _u(rng, 0.85, 1.0), _u(rng, 0.38, 0.5)
    leg = _u(rng, 0.09, 0.15) if style == "armless" else _u(rng, 0.04, 0.07)
    bh = _u(rng, 0.13, 0.2)
    b.box_between((-w / 2, leg, -d / 2), (w / 2, leg + bh, d / 2), rounding=0.03)
    chaise = 0.0
    side = 1 if _chance(rng, 0.5) else -1
    if style == "sectional":
        chaise = _u(rng, 0.25, 0.4)
        cw = _u(rng, 0.3, 0.4)
        x0, x1 = sorted((side * w / 2, side * (w / 2 - cw)))
        b.box_between((x0, leg, -d / 2 - chaise), (x1, leg + bh, -d / 2 + 0.05), rounding=0.03)
    bt = _u(rng, 0.1, 0.16)
    back_h = _u(rng, 0.2, 0.33)
    b.box_between((-w / 2, leg + bh - 0.02, d / 2 - bt), (w / 2, leg + bh + back_h, d / 2), rounding=0.04)
    at = _u(rng, 0.08, 0.14) if style != "loveseat" else _u(rng, 0.1, 0.15)
    ah = _u(rng, 0.1, 0.2)
    arm_sides = {"straight": (-1, 1), "loveseat": (-1, 1), "sectional": (-side,), "armless": ()}[style]
    for s in arm_sides:
        x0, x1 = sorted((s * w / 2, s * (w / 2 - at)))
        b.box_between((x0, leg + bh - 0.02, -d / 2), (x1, leg + bh + ah, d / 2), rounding=0.03)
        if style == "loveseat":  # rolled arm
            b.capsule(((x0 + x1) / 2, leg + bh + ah, -d / 2 + at / 2), ((x0 + x1) / 2, leg + bh + ah, d / 2 - 0.02),
                      at / 2 + 0.015)
    n = 2 if style == "loveseat" else int(rng.integers(1, 4))
    ch = _u(rng, 0.05, 0.09)
    xl = -w / 2 + (at if -1 in arm_sides else 0.0)
    xr = w / 2 - (at if 1 in arm_sides else 0.0)
    for k in range(n):
        x0 = xl + (xr - xl) * k / n + 0.005
        x1 = xl + (xr - xl) * (k + 1) / n - 0.005
        b.box_between((x0, leg + bh - 0.01, -d / 2 + 0.01), (x1, leg + bh + ch, d / 2 - bt), rounding=0.025)
    if style == "sectional":
        x0, x1 = sorted((side * (w / 2 - 0.01), side * (w / 2 - cw + 0.01)))
        b.box_between((x0, leg + bh - 0.01, -d / 2 - chaise + 0.01), (x1, leg + bh + ch, -d / 2 + 0.05),
                      rounding=0.025)
    if _chance(rng, 0.4):  # back cushions leaning on the back
        for k in range(n):
            x0 = xl + (xr - xl) * k / n + 0.01
            x1 = xl + (xr - xl) * (k + 1) / n - 0.01
            b.box(((x0 + x1) / 2, leg + bh + ch + back_h * 0.35, d / 2 - bt - 0.03),
                  ((x1 - x0) / 2, back_h * 0.35, 0.045), rotation(_X, -0.2), rounding=0.03)
    lr = 0.035 if style == "armless" else 0.03
    zs = [-d / 2 + 0.06, d / 2 - 0.06]
    for x in (-w / 2 + 0.06, w / 2 - 0.06):
        for z in zs:
            b.cylinder((x, leg / 2 + 0.01, z), lr, leg / 2 + 0.01)
    if style == "sectional":
        b.cylinder((side * (w / 2 - 0.06), leg / 2 + 0.01, -d / 2 - chaise + 0.06), lr, leg / 2 + 0.01)
    return b.shape()


def make_speaker(rng: np.random.Generator, style: str) -> CSGShape:
    """Drivers are conical dishes in the front (-z). "bookshelf": a box with a woofer and a
    tweeter, optional port and feet; "tower": tall and narrow, 2-4 drivers, on a plinth;
    "cylinder": a round speaker, upright or lying with drivers at both ends; "subwoofer": a cube
    with one big driver and feet."""
    b = CSGBuilder()
    if style == "cylinder":
        if _chance(rng, 0.5):  # upright: a drum on a foot ring with a chamfered cap, drivers in front
            r, h = _u(rng, 0.22, 0.32), _u(rng, 0.6, 0.95)
            y0 = 0.04
            b.cylinder((0, y0 + h / 2, 0), r, h / 2)
            n = 1 if h < 0.8 else 2
            dr = r * _u(rng, 0.5, 0.65)
            for k in range(n):
                _driver(b, 0, y0 + h * (k + 1) / (n + 1), -r * 0.97, dr, _u(rng, 0.05, 0.07))
            b.cone((0, y0 + h + 0.025, 0), 0.035, r, r * _u(rng, 0.6, 0.8))
            b.cylinder((0, y0 / 2, 0), r * _u(rng, 0.75, 0.9), y0 / 2 + 0.01)
        else:  # lying along x: passive radiators in both ends
            length, r = _u(rng, 0.85, 1.0), _u(rng, 0.16, 0.24)
            b.cylinder((0, r + 0.03, 0), r, length / 2, ALONG_X)
            for s in (-1, 1):
                b.cone((s * (length / 2 - 0.02), r + 0.03, 0), 0.03, r * 0.8, r * 0.35, _frame((-s, 0, 0), _Y),
                       op="subtract")
            for s in (-1, 1):
                b.torus((s * (length / 2 - 0.04), r + 0.03, 0), r, 0.03, ALONG_X)
            b.box((0, 0.03, 0), (length * 0.35, 0.03, r * 0.5), rounding=0.01)  # foot strip
        return b.shape()
    if style == "tower":
        w, h, d = _u(rng, 0.22, 0.32), _u(rng, 0.9, 1.0), _u(rng, 0.3, 0.42)
    elif style == "subwoofer":
        w = _u(rng, 0.6, 0.8)
        h, d = w * _u(rng, 0.9, 1.1), w * _u(rng, 0.9, 1.1)
    else:
        w, h, d = _u(rng, 0.45, 0.6), _u(rng, 0.75, 1.0), _u(rng, 0.45, 0.7)
    feet = style == "subwoofer" or _chance(rng, 0.4)
    y0 = 0.06 if feet else (0.05 if style == "tower" else 0.0)
    b.box((0, y0 + h / 2, 0), (w / 2, h / 2, d / 2), rounding=_u(rng, 0.015, 0.04))
    front = -d / 2
    depth = _u(rng, 0.05, 0.08)
    caps = []
    if style == "subwoofer":
        r = min(w, h) * _u(rng, 0.32, 0.4)
        _driver(b, 0, y0 + h / 2, front, r, depth)
        caps.append((0, y0 + h / 2, r))
        if _chance(rng, 0.5):
            b.box((0, y0 + 0.06, front), (w * 0.3, 0.025, 0.05), op="subtract")  # port slot
    elif style == "tower":
        n = int(rng.integers(2, 5))
        r = w * _u(rng, 0.32, 0.4)
        tw = _u(rng, 0.04, 0.055)
        ys = [y0 + h - 0.08 - tw]
        y = ys[0] - tw - 0.04 - r
        for _ in range(n):
            if y - r < y0 + 0.08:
                break
            _driver(b, 0, y, front, r, depth)
            caps.append((0, y, r))
            y -= 2 * r + 0.05
        _driver(b, 0, ys[0], front, tw, 0.04)
    else:  # bookshelf
        r = w * _u(rng, 0.3, 0.38)
        yw = y0 + h * _u(rng, 0.3, 0.4)
        _driver(b, 0, yw, front, r, depth)
        caps.append((0, yw, r))
        tw = _u(rng, 0.05, 0.07)
        _driver(b, 0, min(y0 + h - tw - 0.06, yw + r + tw + 0.08), front, tw, 0.04)
        if _chance(rng, 0.4):
            b.cylinder((0, y0 + 0.07, front), 0.04, 0.06, ALONG_Z, op="subtract")  # port
    for x, y, r in caps:
        b.sphere((x, y, front + depth * 0.8), max(r * 0.3, 0.03))  # dust cap
    if style == "tower":
        b.box((0, 0.0275, 0), (w / 2 + 0.04, 0.0275, d / 2 + 0.04), rounding=0.01)  # plinth
    elif feet:
        fx, fz = w / 2 - 0.06, d / 2 - 0.06
        for x in (-fx, fx):
            for z in (-fz, fz):
                b.cylinder((x, 0.035, z), 0.035, 0.035)
    return b.shape()


def make_table(rng: np.random.Generator, style: str) -> CSGShape:
    """"legs": rectangular top, four legs, optional apron and stretchers (holes); "lower_shelf":
    four legs joined by a shelf below the top (holes); "pedestal": round or rectangular top on a
    column with a disc or cross foot; "round_legs": round top on 3-4 splayed legs, optional ring
    stretcher (a hole); "trestle": long top on two end frames joined by a stretcher (a hole)."""
    b = CSGBuilder()
    tw, tt = _u(rng, 0.85, 1.0), _u(rng, 0.055, 0.08)
    td = tw * _u(rng, 0.5, 0.9)
    th = _u(rng, 0.45, 0.75)
    round_top = style == "round_legs" or (style == "pedestal" and _chance(rng, 0.7))
    if round_top:
        r = tw / 2 * _u(rng, 0.85, 1.0)
        b.cylinder((0, th - tt / 2, 0), r, tt / 2)
    else:
        b.box((0, th - tt / 2, 0), (tw / 2, tt / 2, td / 2), rounding=0.01)
    if style == "pedestal":
        pr = _u(rng, 0.05, 0.09)
        b.cylinder((0, th / 2, 0), pr, th / 2)
        if _chance(rng, 0.5):
            b.cylinder((0, 0.03, 0), _u(rng, 0.2, 0.3), 0.03)
        else:  # a cross of four feet
            fl = _u(rng, 0.22, 0.32)
            a = _u(rng, 0.0, math.pi / 2) if round_top else math.pi / 4
            for k in range(2):
                b.box((0, 0.035, 0), (fl, 0.035, 0.035), rotation(_Y, a + k * math.pi / 2))
        return b.shape()
    if style == "round_legs":
        n = int(rng.integers(3, 5))
        lt = _u(rng, 0.028, 0.038)
        r_top, r_bot = r * _u(rng, 0.5, 0.65), r * _u(rng, 0.6, 0.8)
        a0 = _u(rng, 0.0, math.pi)
        for k in range(n):
            a = a0 + 2 * math.pi * k / n
            c, s = math.cos(a), math.sin(a)
            b.rod((r_bot * c, 0.0, r_bot * s), (r_top * c, th - tt + 0.005, r_top * s), lt)
        if _chance(rng, 0.5):  # ring stretcher through the legs
            y = _u(rng, 0.15, 0.3) * th
            rr = r_bot + (r_top - r_bot) * y / (th - tt)
            b.torus((0, y, 0), rr, 0.0275)
        return b.shape()
    if style == "trestle":
        px = tw / 2 - _u(rng, 0.08, 0.14)
        pt = _u(rng, 0.055, 0.075)
        fz = td / 2 * _u(rng, 0.7, 0.9)
        for x in (-px, px):
            b.box((x, (th - tt) / 2, 0), (pt / 2, (th - tt) / 2, _u(rng, 0.05, 0.08)))  # post
            b.box((x, 0.035, 0), (pt / 2 + 0.005, 0.035, fz), rounding=0.01)  # foot
            b.box((x, th - tt - 0.03, 0), (pt / 2, 0.03, fz))  # cleat under the top
        y = _u(rng, 0.3, 0.6) * (th - tt)
        b.box((0, y, 0), (px, 0.035, 0.03))
        return b.shape()
    # legs, lower_shelf
    lt = _u(rng, 0.055, 0.08)
    inset = _u(rng, 0.0, 0.06)
    lx, lz = tw / 2 - lt / 2 - inset, td / 2 - lt / 2 - inset
    _legs(b, (-lx, lx), (-lz, lz), th - tt, lt, _chance(rng, 0.5))
    if _chance(rng, 0.4):  # apron under the top
        ah = _u(rng, 0.06, 0.1)
        y0 = th - tt - ah
        b.box_between((-lx, y0, -lz - 0.0275), (lx, th - tt, -lz + 0.0275))
        b.box_between((-lx, y0, lz - 0.0275), (lx, th - tt, lz + 0.0275))
    if style == "lower_shelf":
        y = _u(rng, 0.08, 0.25)
        b.box((0, y, 0), (lx + lt / 2, 0.03, lz + lt / 2))
    elif _chance(rng, 0.5):  # stretchers
        y = _u(rng, 0.1, 0.25)
        for z in (-lz, lz):
            b.box_between((-lx, y - 0.0275, z - 0.0275), (lx, y + 0.0275, z + 0.0275))
        if _chance(rng, 0.5):
            b.box_between((-0.0275, y - 0.0275, -lz), (0.0275, y + 0.0275, lz))
    return b.shape()


def _hull(b: CSGBuilder, length: float, beam: float, depth: float, bow: float, v_rise: float,
          stern_taper: float) -> None:
    """A hull on y in [0, depth] along z: a box cut to a pointed bow over ``bow`` of its length,
    its forefoot raked, optionally a V bottom and a narrowed stern. The cuts stay below the deck
    (y = depth), so they miss masts and sails built before the hull. ``v_rise``: the height of the
    V bottom's chines as a fraction of the depth (0: flat bottom)."""
    front = -length / 2
    b.box((0, depth / 2, 0), (beam / 2, depth / 2, length / 2))
    hy = depth / 2 + 0.005
    for s in (-1, 1):
        _cut_beyond(b, (s * beam / 2, depth / 2, front + bow), (0, depth / 2, front), _Y, (s, 0, -0.3), hy,
                    margin=0.05)
    _cut_beyond(b, (0, 0, front + bow * 1.2), (0, depth * 0.7, front), _X, (0, -1, -1), beam / 2 + 0.01,
                margin=0.05)
    if v_rise > 0:
        for s in (-1, 1):
            _cut_beyond(b, (s * beam / 2, depth * v_rise, 0), (0, 0, 0), _Z, (s, -1, 0), length / 2 + 0.01, margin=0.0)
    if stern_taper > 0:
        for s in (-1, 1):
            _cut_beyond(b, (s * beam / 2, depth / 2, length / 2 - stern_taper),
                        (s * beam * 0.35, depth / 2, length / 2), _Y, (s, 0, 1), hy, margin=0.02)


def make_vessel(rng: np.random.Generator, style: str) -> CSGShape:
    """Along z, bow to -z. "ship": deckhouse, bridge, funnel and mast; "sailboat": narrow hull
    with a keel, a mast and one or two triangular sails; "speedboat": wide V hull with a cockpit
    and a windscreen; "rowboat": an open hull with thwarts across it (holes), no superstructure;
    "tanker": long flat deck, bridge and funnel at the stern."""
    b = CSGBuilder()
    length = _u(rng, 0.95, 1.0)
    front = -length / 2
    if style == "sailboat":
        beam, depth = _u(rng, 0.2, 0.26), _u(rng, 0.08, 0.11)
        mast_h = _u(rng, 0.5, 0.8)
        zm = front + length * _u(rng, 0.35, 0.45)
        top = depth + mast_h
        foot = depth + 0.08
        if _chance(rng, 0.7):  # jib from the masthead to the bow
            jz = front + 0.08
            b.box_between((-0.0275, depth + 0.02, jz), (0.0275, top * 0.85, zm))
            _cut_beyond(b, (0, top * 0.85, zm), (0, depth + 0.02, jz), _X, (0, 1, -1), 0.05)
        boom = _u(rng, 0.35, 0.5)
        b.box((0, (foot + top) / 2, zm + boom / 2), (0.0275, (top - foot) / 2, boom / 2))
        _cut_beyond(b, (0, top, zm), (0, foot, zm + boom), _X, (0, 1, 1), 0.05)
        b.cylinder((0, (depth + top) / 2, zm), 0.03, (top - depth) / 2)
        b.box((0, foot - 0.03, zm + boom / 2), (0.03, 0.03, boom / 2 + 0.02))  # boom
        _hull(b, length, beam, depth, length * _u(rng, 0.3, 0.4), 0.4, length * 0.15)
        b.box((0, depth + 0.03, zm + 0.12), (beam * 0.3, 0.04, 0.1), rounding=0.02)  # cabin roof
        b.box((0, -0.06, zm + 0.05), (0.03, 0.08, 0.1))  # keel
        return b.shape()
    if style == "speedboat":
        beam, depth = _u(rng, 0.3, 0.38), _u(rng, 0.13, 0.16)
        v_rise = 0.3
        _hull(b, length, beam, depth, length * _u(rng, 0.3, 0.4), v_rise, 0.0)
        cz0, cz1 = _u(rng, -0.1, 0.0), length / 2 - _u(rng, 0.08, 0.15)
        floor = depth * v_rise * 0.75 + 0.06  # over the V at the cockpit's sides
        b.box_between((-beam / 2 + 0.055, floor, cz0), (beam / 2 - 0.055, depth + 0.1, cz1), op="subtract")  # cockpit
        ws = rotation(_X, -_u(rng, 0.6, 0.9))
        b.box(np.array([0.0, depth + 0.04, cz0 - 0.02]), (beam / 2 - 0.04, 0.05, 0.0275), ws, rounding=0.01)
        if _chance(rng, 0.6):  # outboard motor on the transom
            b.box((0, depth + 0.02, length / 2 + 0.04), (0.05, 0.06, 0.05), rounding=0.02)
            b.box((0, depth * 0.2, length / 2 + 0.04), (0.0275, depth * 0.6, 0.03))
        return b.shape()
    if style == "rowboat":
        beam, depth = _u(rng, 0.3, 0.4), _u(rng, 0.12, 0.16)
        bow = length * _u(rng, 0.25, 0.35)
        _hull(b, length, beam, depth, bow, 0.0, length * _u(rng, 0.06, 0.1))
        wall = _u(rng, 0.055, 0.065)
        stern = length / 2 - length * 0.1 - wall
        b.box_between((-beam / 2 + wall, wall, front + bow + 0.01), (beam / 2 - wall, depth + 0.1, stern),
                      op="subtract")
        n = int(rng.integers(2, 4))
        for k in range(n):
            z = front + bow + (stern - front - bow) * (k + 0.7) / (n + 0.4)
            b.box((0, depth - 0.04, z), (beam / 2 - wall / 2, 0.0275, 0.045))
        return b.shape()
    # ship, tanker
    beam, depth = _u(rng, 0.16, 0.24), _u(rng, 0.09, 0.13)
    _hull(b, length, beam, depth, length * _u(rng, 0.15, 0.25), 0.0, length * _u(rng, 0.0, 0.06))
    if style == "tanker":
        zb = length / 2 - _u(rng, 0.12, 0.16)
        bh = _u(rng, 0.12, 0.18)
        b.box((0, depth + bh / 2, zb), (beam * 0.42, bh / 2, _u(rng, 0.05, 0.07)))
        b.box((0, depth + bh - 0.0275, zb - 0.02), (beam * 0.55, 0.0275, 0.04))  # bridge wings
        b.box((0, depth + bh * 0.6, zb + 0.09), (0.035, bh * 0.6, 0.035), rotation(_X, 0.15))  # funnel
        if _chance(rng, 0.5):  # containers
            n = int(rng.integers(3, 6))
            span = zb - 0.1 - (front + length * 0.2)
            for k in range(n):
                z = front + length * 0.2 + span * (k + 0.5) / n
                b.box((0, depth + 0.04, z), (beam * 0.42, 0.04, span / n * 0.42))
        else:  # a pipe deck: a catwalk down the middle and a forecastle
            b.box((0, depth + 0.03, 0.0), (0.035, 0.03, length * 0.3))
            b.box((0, depth + 0.03, front + 0.12), (beam * 0.3, 0.03, 0.05))
        return b.shape()
    zh = _u(rng, -0.05, 0.15)
    hl = _u(rng, 0.12, 0.18)
    dh = _u(rng, 0.06, 0.1)
    b.box((0, depth + dh / 2, zh), (beam * 0.38, dh / 2, hl), rounding=0.01)  # deckhouse
    bh = _u(rng, 0.06, 0.08)
    zbr = zh - hl * 0.5
    b.box((0, depth + dh + bh / 2, zbr), (beam * 0.33, bh / 2, _u(rng, 0.045, 0.065)), rounding=0.01)  # bridge
    if _chance(rng, 0.6):
        b.box((0, depth + dh + bh - 0.0275, zbr), (beam * 0.5, 0.0275, 0.035))  # bridge wings
    fh = _u(rng, 0.08, 0.13)
    b.cylinder((0, depth + dh + fh / 2, zh + hl * 0.45), _u(rng, 0.035, 0.045), fh / 2, rotation(_X, 0.2))  # funnel
    mh = _u(rng, 0.12, 0.22)
    b.cylinder((0, depth + dh + bh + mh / 2, zbr + 0.03), 0.0275, mh / 2)  # mast
    b.box((0, depth + dh + bh + mh * 0.7, zbr + 0.03), (_u(rng, 0.06, 0.09), 0.0275, 0.0275))  # yard
    if _chance(rng, 0.4):  # a gun turret on the foredeck
        tz = front + length * 0.25
        b.cylinder((0, depth + 0.03, tz), 0.05, 0.03)
        b.cylinder((0, depth + 0.035, tz - 0.09), 0.0275, 0.07, ALONG_Z)
    return b.shape()


def make_mug(rng: np.random.Generator, style: str) -> CSGShape:
    """A cup with a bottom and a torus handle (genus 1), "straight" or "tapered" towards the foot."""
    b = CSGBuilder()
    r, h = _u(rng, 0.25, 0.35), _u(rng, 0.5, 0.8)
    wall, bottom = _u(rng, 0.055, 0.07), _u(rng, 0.055, 0.08)
    taper = _u(rng, 0.04, 0.09) if style == "tapered" else 0.0
    b.cone((0, h / 2, 0), h / 2, r - taper, r)
    hr, hm = _u(rng, 0.12, 0.2) * h / 0.65, _u(rng, 0.035, 0.05)
    hr = min(hr, h / 2 - hm - 0.02)
    b.torus((r - 0.02 + hr * 0.55, h * _u(rng, 0.45, 0.55), 0), hr, hm, rotation(_X, math.pi / 2))
    # the cavity, cut last so the handle never enters the cup
    b.cone((0, bottom + (h - bottom) / 2 + 0.05, 0), (h - bottom) / 2 + 0.05,
           r - taper - wall, r - wall + 0.05 * taper / h, op="subtract")
    return b.shape()


def make_shelf(rng: np.random.Generator, style: str) -> CSGShape:
    """A bookcase: a box with a grid of compartments open at the front, with a "closed_back" or an
    "open_back" (the compartments go through: holes)."""
    b = CSGBuilder()
    w, h, d = _u(rng, 0.45, 0.9), _u(rng, 0.7, 1.0), _u(rng, 0.25, 0.4)
    t = _u(rng, 0.055, 0.065)
    b.box((0, h / 2, 0), (w / 2, h / 2, d / 2))
    rows, cols = int(rng.integers(2, 5)), int(rng.integers(1, 3))
    cw = (w - (cols + 1) * t) / cols
    chh = (h - (rows + 1) * t) / rows
    z1 = d / 2 + 0.1 if style == "open_back" else d / 2 - t
    for i in range(rows):
        for j in range(cols):
            x0 = -w / 2 + t + j * (cw + t)
            y0 = t + i * (chh + t)
            b.box_between((x0, y0, -d / 2 - 0.1), (x0 + cw, y0 + chh, z1), op="subtract")
    return b.shape()


# ---------------------------------------------------------------------------------------------
# The registry


@dataclass(frozen=True)
class ProceduralCategory:
    """A procedural category.

    The raw shapes of ``make`` keep these conventions, which ``make_shape`` keeps when it
    normalises them. They are y up, and objects that stand stand on y = 0 before normalisation.
    The front faces -z, towards NMR view 0 (whose eye is on the -z axis): chair and sofa seats open
    to -z with their backs at +z, screens, speaker drivers and cabinet doors face -z, and phones
    stand upright with the screen to -z. Long objects lie along z with their front to -z: the
    airplane's nose, the car's bonnet, the rifle's muzzle and the vessel's bow. Raw shapes are built
    at about unit size with every part at least ``MIN_PART`` thick and a longest side of at most
    ``MAX_RAW_SIZE``, so that after normalisation the thinnest part is at least
    ``MIN_PART / MAX_RAW_SIZE`` = 0.05 thick, 1.5 voxels of the 32^3 benchmark grid: thin enough for
    holes and legs, thick enough for the benchmark's voxels. Shapes have holes (genus > 0) where
    the real category has them: chair backs and arms, table stretchers and shelves, bench slats,
    lamp arms, display stands, rifle trigger guards and scopes, boat thwarts. Each row of a CSG
    program costs time in every render and voxelisation, so a shape holds a few tens of primitives
    at most; hollow parts (shades, beds, recesses) are built before the parts that must not be cut,
    since a subtraction removes material from everything added before it.

    Attributes:
        category_id: 8 digits; ShapeNet's synset id for the NMR categories, 9000000x for extras.
        name: e.g. "chair".
        styles: the structurally different variants ``make`` knows.
        make: ``(rng, style) -> CSGShape``, the raw (un-normalised) shape; ``make_shape`` normalises.
    """

    category_id: str
    name: str
    styles: tuple[str, ...]
    make: Callable[[np.random.Generator, str], CSGShape]


NMR_PROCEDURAL_CATEGORIES: tuple[ProceduralCategory, ...] = (
    ProceduralCategory("02691156", "airplane", ("airliner", "fighter", "propeller", "bizjet"), make_airplane),
    ProceduralCategory("02828884", "bench", ("park", "panel", "backless", "rail_back"), make_bench),
    ProceduralCategory("02933112", "cabinet", ("doors", "open_shelves", "drawers", "sideboard"), make_cabinet),
    ProceduralCategory("02958343", "car", ("sedan", "wagon", "pickup", "suv", "sports"), make_car),
    ProceduralCategory("03001627", "chair", ("four_legs", "slatted", "armchair", "swivel"), make_chair),
    ProceduralCategory("03211117", "display", ("monitor", "tv", "wall", "crt"), make_display),
    ProceduralCategory("03636649", "lamp", ("desk", "floor", "hanging", "table"), make_lamp),
    ProceduralCategory("03691459", "speaker", ("bookshelf", "tower", "cylinder", "subwoofer"), make_speaker),
    ProceduralCategory("04090263", "rifle", ("hunting", "assault", "sniper", "shotgun"), make_rifle),
    ProceduralCategory("04256520", "sofa", ("straight", "sectional", "armless", "loveseat"), make_sofa),
    ProceduralCategory("04379243", "table", ("legs", "lower_shelf", "pedestal", "round_legs", "trestle"), make_table),
    ProceduralCategory("04401088", "phone", ("slab", "flip", "desk", "candybar"), make_phone),
    ProceduralCategory("04530566", "vessel", ("ship", "sailboat", "speedboat", "rowboat", "tanker"), make_vessel),
)
EXTRA_CATEGORIES: tuple[ProceduralCategory, ...] = (
    ProceduralCategory("90000006", "mug", ("straight", "tapered"), make_mug),
    ProceduralCategory("90000008", "shelf", ("closed_back", "open_back"), make_shelf),
)
ALL_CATEGORIES: tuple[ProceduralCategory, ...] = NMR_PROCEDURAL_CATEGORIES + EXTRA_CATEGORIES
_BY_KEY = {**{c.name: c for c in ALL_CATEGORIES}, **{c.category_id: c for c in ALL_CATEGORIES}}


def procedural_category(key: str) -> ProceduralCategory:
    """A category by name ("chair") or id ("03001627").

    Raises:
        ValueError: for an unknown key, listing the valid names.
    """
    try:
        return _BY_KEY[str(key)]
    except KeyError:
        raise ValueError(f"unknown procedural category {key!r}; expected one of "
                         f"{[c.name for c in ALL_CATEGORIES]} or their ids") from None


def _draw(category: str, seed: Seed) -> tuple[ProceduralCategory, np.random.Generator, str]:
    """The category, the object's generator and its style, drawn first from that generator."""
    cat = procedural_category(category)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    return cat, rng, cat.styles[int(rng.integers(len(cat.styles)))]


def style_of(category: str, seed: Seed) -> str:
    """The style ``make_shape(category, seed)`` uses."""
    return _draw(category, seed)[2]


def make_shape(category: str, seed: Seed, style: str | None = None) -> CSGShape:
    """One normalised shape (centred on its bounding box, longest side 1) of a category.

    Args:
        category: a name or id (``procedural_category``).
        seed: an int or a sequence of ints (``np.random.SeedSequence``).
        style: one of the category's styles, or None for the one drawn from the seed
            (``style_of``). The style is drawn either way, so that ``make_shape(c, s,
            style_of(c, s))`` is ``make_shape(c, s)``.
    Returns:
        the CSGShape in the world frame (y up, front to -z).
    """
    cat, rng, drawn = _draw(category, seed)
    if style is None:
        style = drawn
    elif style not in cat.styles:
        raise ValueError(f"style must be one of {cat.name}'s styles {list(cat.styles)}, got {style!r}")
    return cat.make(rng, style).normalized()


__all__ = [
    "ALL_CATEGORIES", "EXTRA_CATEGORIES", "MAX_RAW_SIZE", "MIN_PART", "NMR_PROCEDURAL_CATEGORIES",
    "ProceduralCategory", "make_shape", "procedural_category", "style_of",
]
