"""The procedural airplane (see ``make_airplane`` for its styles)."""
from __future__ import annotations

import math

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, frame, cut_beyond, tail_cone, X, Y, Z, ALONG_X, ALONG_Z


def make_airplane(rng: np.random.Generator, style: str) -> CSGShape:
    """Fuselage along z with the nose to -z. "airliner": swept wings with 2 or 4 engines under
    them; "fighter": delta wing cut from a plate, pointed nose, canopy, one or two fins;
    "propeller": straight high or low wing, propeller at the nose, optional struts (holes) and
    landing gear; "bizjet": swept wings, engines on the rear fuselage and a T-tail."""
    b = CSGBuilder()
    th = uniform(rng, 0.055, 0.065)  # wing thickness
    if style == "fighter":
        length, fr = uniform(rng, 0.95, 1.0), uniform(rng, 0.055, 0.07)
        span = uniform(rng, 0.55, 0.75)
        z_apex, z_trail = uniform(rng, -0.2, -0.05), uniform(rng, 0.3, 0.4)
        wy = uniform(rng, -0.02, 0.0)
        # the delta: a plate whose leading edges are cut away; built first so the cuts hit only it
        b.box((0, wy, (z_apex + z_trail) / 2), (span / 2, th / 2, (z_trail - z_apex) / 2))
        tip = uniform(rng, 0.0, 0.08)  # chord left at the tip (cropped delta)
        for s in (-1, 1):
            cut_beyond(b, (0, wy, z_apex), (s * span / 2, wy, z_trail - tip), Y, (s, 0, -1), th)
        b.capsule((0, 0, -length / 2 + 0.25), (0, 0, length / 2 - fr), fr)
        b.cone((0, 0, -length / 2 + 0.13), 0.13, 0.02, fr, ALONG_Z)  # pointed nose
        b.capsule((0, fr * 0.75, -length / 2 + 0.25), (0, fr * 0.75, -length / 2 + 0.42), uniform(rng, 0.035, 0.045))
        for s in (-1, 1):  # intakes
            b.box((s * (fr + 0.02), -0.01, 0.0), (0.035, 0.04, 0.14), rounding=0.01)
        fin_h, fin_c = uniform(rng, 0.13, 0.2), uniform(rng, 0.14, 0.2)
        fz = length / 2 - fin_c / 2 - 0.02
        sweep = rotation(X, uniform(rng, 0.35, 0.6))
        if chance(rng, 0.5):
            b.box((0, fr + fin_h / 2 - 0.03, fz), (0.03, fin_h / 2, fin_c / 2), sweep)
        else:
            cant = uniform(rng, 0.2, 0.4)
            for s in (-1, 1):
                rot = rotation(Z, -s * cant) @ sweep
                b.box((s * fr * 0.8, fr + fin_h / 2 - 0.04, fz), (0.03, fin_h / 2, fin_c / 2), rot)
        if chance(rng, 0.5):  # tailplanes
            sspan = uniform(rng, 0.14, 0.2)
            for s in (-1, 1):
                b.box((s * (fr + sspan / 2 - 0.02), wy, length / 2 - 0.08), (sspan / 2, th / 2, 0.06))
        b.cylinder((0, 0, length / 2 - 0.02), fr * 0.85, 0.03, ALONG_Z)
        return b.shape()

    if style == "propeller":
        length, fr = uniform(rng, 0.7, 0.85), uniform(rng, 0.06, 0.08)
        span, chord = uniform(rng, 0.9, 1.0), uniform(rng, 0.13, 0.18)
        nose = -length / 2
        tail = length / 2
        b.capsule((0, 0, nose + fr), (0, 0, 0.05), fr)
        tail_cone(b, 0.05, tail, fr, 0.03)
        high = chance(rng, 0.6)
        wy = fr + th / 2 - 0.01 if high else -fr + th / 2 + 0.01
        wz = nose + uniform(rng, 0.2, 0.28)
        b.box((0, wy, wz), (span / 2, th / 2, chord / 2), rounding=0.015)
        if high:
            b.box((0, fr * 0.55, wz - chord * 0.3), (fr * 0.8, fr * 0.6, chord * 0.45), rounding=0.02)  # cabin
            if chance(rng, 0.6):  # wing struts from the fuselage's belly: two triangles (holes)
                for s in (-1, 1):
                    b.rod((s * fr * 0.6, -fr * 0.5, wz), (s * span * 0.28, wy - th / 2, wz), 0.028)
        b.cone((0, 0, nose - 0.03), 0.04, 0.055, 0.01, frame((0, 0, -1), X))  # spinner
        blade = uniform(rng, 0.17, 0.24)
        roll = uniform(rng, 0.0, math.pi)
        b.box((0, 0, nose - 0.02), (0.035, blade, 0.028), rotation(Z, roll))
        fin_h, fin_c = uniform(rng, 0.13, 0.18), uniform(rng, 0.12, 0.16)
        b.box((0, 0.03 + fin_h / 2, tail - fin_c / 2), (0.028, fin_h / 2, fin_c / 2), rotation(X, 0.35))
        b.box((0, 0.04, tail - 0.06), (uniform(rng, 0.16, 0.22), th / 2, 0.055))
        if chance(rng, 0.6):  # fixed landing gear
            gy = -fr - uniform(rng, 0.06, 0.1)
            for s in (-1, 1):
                b.rod((s * 0.02, -fr * 0.5, wz), (s * 0.12, gy, wz), 0.026)
                b.cylinder((s * 0.12, gy, wz), 0.045, 0.028, ALONG_X)
        return b.shape()

    # airliner / bizjet: capsule fuselage with a raised tail cone, swept wings
    if style == "airliner":
        length, fr = uniform(rng, 0.9, 1.0), uniform(rng, 0.055, 0.075)
        span, chord = uniform(rng, 0.85, 1.0), uniform(rng, 0.14, 0.2)
        sweep, dihedral = uniform(rng, 0.35, 0.6), uniform(rng, 0.04, 0.1)
    else:
        length, fr = uniform(rng, 0.85, 1.0), uniform(rng, 0.055, 0.065)
        span, chord = uniform(rng, 0.7, 0.85), uniform(rng, 0.12, 0.16)
        sweep, dihedral = uniform(rng, 0.3, 0.5), uniform(rng, 0.02, 0.07)
    tl = uniform(rng, 0.18, 0.25)
    b.capsule((0, 0, -length / 2 + fr), (0, 0, length / 2 - tl), fr)
    tail_cone(b, length / 2 - tl, length / 2, fr, 0.03)
    wz, wy = uniform(rng, -0.1, 0.0), -fr * 0.45
    for side in (-1, 1):
        rot = rotation(Y, -side * sweep) @ rotation(Z, side * dihedral)
        centre = np.array([0.0, wy, wz]) + rot @ np.array([side * span / 4, 0, 0])
        b.box(centre, (span / 4, th / 2, chord / 2), rot, rounding=0.015)
    fin_h, fin_c = uniform(rng, 0.13, 0.19), uniform(rng, 0.12, 0.17)
    fin_sweep = rotation(X, uniform(rng, 0.45, 0.7))
    root = np.array([0.0, fr - 0.02, length / 2 - fin_c / 2 - 0.03])  # on the tail's level top line
    b.box(root + fin_sweep @ np.array([0.0, fin_h / 2, 0.0]), (0.028, fin_h / 2, fin_c / 2), fin_sweep)
    sspan = uniform(rng, 0.22, 0.32)
    if style == "airliner":  # on the tail cone's axis
        sz = length / 2 - 0.08
        sy = (fr - 0.03) * (sz - length / 2 + tl) / tl
    else:  # T-tail: the stabiliser sits on the swept fin's tip
        _, sy, sz = root + fin_sweep @ np.array([0.0, fin_h - 0.03, 0.0])
    for side in (-1, 1):
        rot = rotation(Y, -side * sweep * 0.8)
        b.box(np.array([0.0, sy, sz]) + rot @ np.array([side * sspan / 4, 0, 0]), (sspan / 4, 0.0275, 0.05), rot)
    if style == "airliner":
        er, el = uniform(rng, 0.035, 0.05), uniform(rng, 0.07, 0.1)
        xs = (0.3,) if chance(rng, 0.65) else (0.25, 0.55)
        for side in (-1, 1):
            for f in xs:
                x = side * span / 2 * f
                z = wz + math.tan(sweep) * abs(x)
                y = wy + math.tan(dihedral) * abs(x)
                pylon = (0.0275, max(er * 0.6, 0.0275), chord * 0.3)
                b.box((x, y - th / 2 - er * 0.5, z - chord * 0.2), pylon)
                b.cylinder((x, y - th / 2 - er * 0.9, z - chord * 0.45), er, el, ALONG_Z)
    else:
        er, el = uniform(rng, 0.035, 0.045), uniform(rng, 0.07, 0.09)
        ez = length / 2 - tl - uniform(rng, 0.02, 0.08)
        for side in (-1, 1):
            b.box((side * (fr + 0.02), fr * 0.3, ez), (0.04, 0.0275, 0.05))  # pylon
            b.cylinder((side * (fr + er + 0.02), fr * 0.4, ez), er, el, ALONG_Z)
    return b.shape()


STYLES = ('airliner', 'fighter', 'propeller', 'bizjet')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_airplane(*params)
