"""The procedural airplane, fuselage along z with the nose to -z and the longer of fuselage and span 1
long. Five styles: "airliner" (span/length 0.75-1.15, low swept wing 0.3-0.65 rad, taper 0.2-0.5,
one or two engines under each wing or two at the rear, conventional or T tail, optional hump and
gear), "bizjet" (span/length 0.7-1.1, engines on the rear fuselage, T or cruciform tail), "fighter"
(span/length 0.45-0.85, pointed nose 15-30% of the length, delta or cropped trapezoid wing far
back, one upright or two canted fins, optional tailplanes and intakes, one or two nozzles, canopy),
"propeller" (span/length 1.05-1.5, straight tapered wing high or low, a nose propeller or two on
the wings, conventional, T or H tail, optional struts and gear) and "glider" (span/length 1.6-2.4,
slim high or mid wing, long tail boom, T, conventional or V tail, canopy). Every style draws the
fuselage radius (4.5-10% of the length), the wing's root chord, taper, sweep (leading edge),
dihedral (-0.08-0.12 rad), thickness and position along and across the fuselage, the fin's height,
chord and rake and the tailplane's span, chord and sweep from continuous ranges.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import MIN_PART, uniform, chance, cut_beyond, tail_cone, X, Y, Z, ALONG_X, ALONG_Z

STYLES = ("airliner", "fighter", "propeller", "bizjet", "glider")
TAILS = ("conventional", "t", "cruciform", "twin", "h", "v")
ENGINES = ("wing", "rear", "nose_prop", "wing_props", "nozzle", "none")
FIN_HALF = 0.0275  # a fin on the symmetry axis stays within the two middle voxel columns (AXIS_ROD)


@dataclass(frozen=True)
class AirplaneParams:
    style: str
    length: float       # fuselage, nose to tail (raw)
    span: float
    radius: float       # fuselage radius
    nose_len: float     # pointed nose cone (0: a round nose)
    tail_len: float     # the tail cone
    tail_end: float     # the tail cone's end radius
    hump: float         # length of a hump over the front fuselage (0: none)
    wing_z: float       # root leading edge, from the nose
    wing_y: float       # -1 low ... 1 high (wing top or bottom flush with the fuselage)
    root_chord: float
    tip_chord: float
    sweep: float        # leading-edge sweep (rad)
    dihedral: float
    wing_thick: float
    tail: str           # TAILS
    fin_h: float
    fin_c: float
    fin_rake: float     # the fin's lean back (rad)
    fin_cant: float     # twin and V fins: tilt from vertical (rad)
    stab_span: float
    stab_chord: float
    stab_sweep: float
    stab_level: float   # cruciform: the tailplane's height on the fin (fraction)
    engines: str        # ENGINES
    engine_at: tuple[float, ...]  # wing engines: fractions of the half span; rear: fraction of the length
    engine_r: float
    engine_len: float
    blade: float        # propeller blade half length
    blade_roll: float
    canopy: float       # canopy length (0: none)
    intakes: bool
    struts: bool
    gear: float         # gear leg length (0: no gear)


def _trapezoid_limit(half: float, root: float, tip: float, sweep: float) -> float:
    """The largest leading-edge sweep that keeps the trailing edge's sweep under 0.7 rad, so that a
    wing half's trailing-edge cut stays clear of the other half."""
    return min(sweep, math.atan(math.tan(0.7) + (root - tip) / half))


def sample(rng: np.random.Generator, style: str) -> AirplaneParams:
    u = lambda lo, hi: uniform(rng, lo, hi)  # noqa: E731
    ratio = {"airliner": (0.7, 1.25), "bizjet": (0.6, 1.15), "fighter": (0.4, 0.95), "propeller": (0.95, 1.6),
             "glider": (1.6, 2.4)}[style]
    r = u(*ratio)
    length, span = (1.0, r) if r <= 1.0 else (1.0 / r, 1.0)
    L = length
    nose_len, hump, canopy, intakes, struts, gear, blade, roll = 0.0, 0.0, 0.0, False, False, 0.0, 0.0, 0.0
    stab_level, fin_cant = 0.0, 0.0
    engine_at: tuple[float, ...] = ()
    er, el = 0.0, 0.0
    if style in ("airliner", "bizjet"):
        air = style == "airliner"
        fr = L * (u(0.04, 0.085) if air else u(0.045, 0.095))
        tail_len, tail_end = L * (u(0.12, 0.32) if air else u(0.18, 0.34)), u(0.3, 0.6)
        hump = L * u(0.2, 0.35) if air and chance(rng, 0.2) else 0.0
        wing_z = L * (u(0.25, 0.5) if air else u(0.3, 0.55))
        wing_y = u(0.5, 0.95) if air and chance(rng, 0.15) else u(-0.95, -0.2)
        root = L * (u(0.12, 0.3) if air else u(0.1, 0.22))
        taper = u(0.2, 0.5) if air else u(0.3, 0.6)
        sweep = u(0.2, 0.7) if air else u(0.1, 0.55)
        dihedral = u(-0.02, 0.18) if wing_y < 0 else u(-0.12, 0.0)
        if air:
            tail = "t" if chance(rng, 0.3) else "conventional"
        else:
            tail = "t" if chance(rng, 0.65) else "cruciform"
            stab_level = u(0.35, 0.7)
        fin_h, fin_c, fin_rake = L * u(0.09, 0.22), L * u(0.09, 0.2), u(0.4, 0.85)
        stab_span, stab_chord, stab_sweep = L * u(0.22, 0.4), L * u(0.06, 0.1), u(0.25, 0.6)
        if air and chance(rng, 0.85):
            engines = "wing"
            engine_at = (u(0.25, 0.42),) if chance(rng, 0.6) else (u(0.22, 0.35), u(0.5, 0.7))
            er, el = L * u(0.03, 0.055), L * u(0.08, 0.15)
        else:
            engines = "rear"
            engine_at = (u(0.62, 0.78),)
            er, el = L * u(0.03, 0.05), L * u(0.08, 0.14)
        gear = L * u(0.07, 0.14) if chance(rng, 0.4) else 0.0
    elif style == "fighter":
        fr = L * u(0.045, 0.07)
        nose_len = L * u(0.12, 0.35)
        tail_len, tail_end = L * u(0.05, 0.12), u(0.65, 0.9)
        delta = chance(rng, 0.5)
        root = L * (u(0.35, 0.55) if delta else u(0.2, 0.32))
        taper = u(0.0, 0.2) if delta else u(0.2, 0.45)
        sweep = u(0.75, 1.05) if delta else u(0.35, 0.7)
        wing_z = L * u(0.8, 1.0)  # where the wing ends: placed below, once its sweep is known
        wing_y = u(-0.4, 0.4)
        dihedral = u(-0.12, 0.06)
        tail = "twin" if chance(rng, 0.45) else "conventional"
        fin_cant = u(0.1, 0.45)
        fin_h, fin_c, fin_rake = L * u(0.12, 0.2), L * u(0.12, 0.2), u(0.4, 0.75)
        stab_span = L * u(0.28, 0.45) if not delta or chance(rng, 0.2) else 0.0
        stab_chord, stab_sweep = L * u(0.07, 0.11), u(0.3, 0.7)
        engines = "nozzle"
        engine_at = (0.0,) if chance(rng, 0.6) else (1.0,)  # one nozzle or two side by side
        er, el = fr * u(0.7, 0.9), L * u(0.04, 0.08)
        canopy = L * u(0.12, 0.22)
        intakes = chance(rng, 0.7)
        gear = L * u(0.07, 0.1) if chance(rng, 0.15) else 0.0
    elif style == "propeller":
        fr = L * u(0.055, 0.11)
        tail_len, tail_end = L * u(0.3, 0.45), u(0.25, 0.45)
        wing_y = u(0.6, 0.9) if chance(rng, 0.55) else u(-0.9, -0.6)
        wing_z = L * u(0.15, 0.4)
        root = L * u(0.1, 0.25)
        taper = u(0.5, 1.0)
        sweep = u(-0.05, 0.12)
        dihedral = u(0.0, 0.15) if wing_y < 0 else u(-0.05, 0.06)
        tail = str(rng.choice(["conventional", "t", "h"], p=[0.7, 0.15, 0.15]))
        fin_h, fin_c, fin_rake = L * u(0.12, 0.2), L * u(0.12, 0.2), u(0.2, 0.6)
        if tail == "h":
            fin_h, fin_c = fin_h * 0.7, fin_c * 0.7
        stab_span, stab_chord, stab_sweep = L * u(0.28, 0.45), L * u(0.07, 0.12), u(0.0, 0.25)
        if chance(rng, 0.7):
            engines, engine_at = "nose_prop", ()
        else:
            engines, engine_at = "wing_props", (u(0.25, 0.4),)
            er, el = L * u(0.04, 0.06), L * u(0.15, 0.25)
        blade, roll = L * u(0.12, 0.22), u(0.0, math.pi)
        struts = wing_y > 0 and chance(rng, 0.6)
        canopy = L * u(0.12, 0.2) if chance(rng, 0.6) else 0.0
        gear = L * u(0.08, 0.14) if chance(rng, 0.6) else 0.0
    elif style == "glider":
        fr = max(L * u(0.075, 0.1), 0.042)
        tail_len, tail_end = L * u(0.45, 0.6), u(0.45, 0.65)
        wing_y = u(0.3, 0.9)
        wing_z = L * u(0.25, 0.35)
        root = span * u(0.07, 0.12)
        taper = u(0.35, 0.7)
        sweep = u(-0.02, 0.08)
        dihedral = u(0.0, 0.16)
        tail = str(rng.choice(["t", "conventional", "v"], p=[0.6, 0.25, 0.15]))
        fin_cant = u(0.6, 0.9)
        fin_h, fin_c, fin_rake = L * u(0.18, 0.28), L * u(0.12, 0.2), u(0.25, 0.6)
        stab_span, stab_chord, stab_sweep = L * u(0.3, 0.45), L * u(0.07, 0.11), u(0.0, 0.2)
        engines = "none"
        canopy = L * u(0.15, 0.25)
    else:
        raise ValueError(f"unknown airplane style {style!r}; expected one of {STYLES}")
    tip = max(root * taper, 0.06)
    sweep = _trapezoid_limit(span / 2, root, tip, sweep)
    if style == "fighter":
        wing_z -= max(root, span / 2 * math.tan(sweep) + tip)
    return AirplaneParams(
        style=style, length=length, span=span, radius=max(fr, 0.042), nose_len=nose_len, tail_len=tail_len,
        tail_end=max(tail_end * fr, 0.03), hump=hump, wing_z=wing_z, wing_y=wing_y, root_chord=root,
        tip_chord=tip, sweep=sweep, dihedral=dihedral, wing_thick=u(MIN_PART, 0.09), tail=tail,
        fin_h=fin_h, fin_c=max(fin_c, 0.07), fin_rake=fin_rake, fin_cant=fin_cant, stab_span=stab_span,
        stab_chord=max(stab_chord, MIN_PART + 0.005), stab_sweep=stab_sweep, stab_level=stab_level,
        engines=engines, engine_at=engine_at, engine_r=max(er, 0.03), engine_len=max(el, 0.07), blade=blade,
        blade_roll=roll, canopy=canopy, intakes=intakes, struts=struts, gear=gear)


# ---------------------------------------------------------------------------------------------- build


class _Wing:
    """A trapezoidal wing half: root leading edge at ``origin`` on the symmetry plane, ``side`` -1
    or 1, raised by the dihedral. ``at(f, c)``: the world point at the fraction f of the half span
    and chord fraction c (0 leading edge, 1 trailing edge) on the mid plane."""

    def __init__(self, p: AirplaneParams, origin: np.ndarray, side: int):
        self.p, self.origin, self.side = p, origin, side
        self.rot = rotation(Z, side * p.dihedral)
        self.half = p.span / 2

    def local(self, lx: float, lz: float) -> np.ndarray:
        return self.origin + self.rot @ np.array([self.side * lx, 0.0, lz])

    def at(self, f: float, c: float) -> np.ndarray:
        p = self.p
        lx = f * self.half
        le = lx * math.tan(p.sweep)
        chord = p.root_chord + (p.tip_chord - p.root_chord) * f
        return self.local(lx, le + c * chord)

    def build(self, b: CSGBuilder) -> None:
        p, h = self.p, self.half
        le_tip = h * math.tan(p.sweep)
        z0, z1 = min(0.0, le_tip), max(p.root_chord, le_tip + p.tip_chord)
        b.box(self.local(h / 2, (z0 + z1) / 2), (h / 2, p.wing_thick / 2, (z1 - z0) / 2), self.rot)
        normal = self.rot @ np.array(Y)
        depth = z1 - z0 + 0.05
        if le_tip - z0 > 0.005:
            cut_beyond(b, self.at(0, 0), self.at(1, 0), normal, (0, 0, -1), p.wing_thick / 2 + 0.01, depth, 0.005)
        if abs(z1 - (le_tip + p.tip_chord)) > 0.005 or abs(z1 - p.root_chord) > 0.005:
            cut_beyond(b, self.at(0, 1), self.at(1, 1), normal, (0, 0, 1), p.wing_thick / 2 + 0.01, depth, 0.005)


def _tail_axis_y(p: AirplaneParams, z: float) -> tuple[float, float]:
    """The fuselage's axis height and radius at z (the tail cone's axis rises to keep its top level)."""
    ts = p.length / 2 - p.tail_len
    if z <= ts:
        return 0.0, p.radius
    f = min((z - ts) / p.tail_len, 1.0)
    r = p.radius + (p.tail_end - p.radius) * f
    return p.radius - r, r


def build(p: AirplaneParams) -> CSGShape:
    b = CSGBuilder()
    L, fr = p.length, p.radius
    nose, tail = -L / 2, L / 2
    # wings first: their trailing and leading edges are cut from plates, and the cuts must miss the rest
    b.part("wings")
    wy = p.wing_y * (fr - p.wing_thick / 2 - 0.005)
    wings = [_Wing(p, np.array([0.0, wy, nose + p.wing_z]), s) for s in (-1, 1)]
    for w in wings:
        w.build(b)
    if p.struts:  # from the belly's sides to the wing's underside (holes between strut, wing and body)
        for w in wings:
            b.rod((w.side * fr * 0.6, -fr * 0.6, nose + p.wing_z + p.root_chord * 0.4),
                  w.at(0.45, 0.4) - np.array([0, p.wing_thick / 2, 0]), 0.028)

    b.part("fuselage")
    ts = tail - p.tail_len
    if p.nose_len > 0:  # a pointed nose cone ahead of a cylinder
        b.cone((0, 0, nose + p.nose_len / 2), p.nose_len / 2, 0.2 * fr, fr, ALONG_Z)
        b.rod((0, 0, nose + p.nose_len - 0.005), (0, 0, ts + 0.01), fr)
    else:
        b.capsule((0, 0, nose + fr), (0, 0, ts), fr)
    tail_cone(b, ts - 0.3 * fr, tail, fr, p.tail_end)
    if p.hump > 0:
        b.capsule((0, fr * 0.4, nose + fr * 1.6), (0, fr * 0.4, nose + p.hump), fr * 0.8)
    if p.intakes:  # a box through the body, from behind the nose cone to over the wing root
        z0 = nose + p.nose_len + 0.02
        z1 = max(nose + p.wing_z + 0.3 * p.root_chord, z0 + 0.15)
        b.box((0, -fr * 0.15, (z0 + z1) / 2), (fr + 0.03, max(fr * 0.55, 0.03), (z1 - z0) / 2), rounding=0.015)

    b.part("tail")
    _tail(b, p)

    b.part("engines")
    _engines(b, p, wings)
    if p.canopy > 0:
        b.part("canopy")
        cz = nose + (p.nose_len + 0.02 if p.nose_len > 0 else fr * 1.2)
        cr = max(0.6 * fr, 0.03)
        b.capsule((0, fr * 0.75, cz + cr), (0, fr * 0.75, cz + p.canopy - cr), cr)
    if p.gear > 0:
        b.part("gear")
        bottom = -fr * 0.5
        gy = -fr - p.gear
        wr = max(p.gear * 0.35, 0.035)
        zm = nose + p.wing_z + p.root_chord * 0.6
        for w in wings:
            if p.wing_y < 0 and p.style != "fighter":  # legs under the wing
                top = w.at(0.22, 0.55)
                x = top[0]
            else:  # legs splayed from the belly
                top = np.array([w.side * fr * 0.5, bottom, zm])
                x = w.side * max(fr * 1.6, 0.09)
            b.rod(top, (x, gy + wr, top[2]), 0.0285)
            b.cylinder((x, gy + wr, top[2]), wr, 0.03, ALONG_X)
        if p.engines != "nose_prop" or p.style != "propeller":  # a nose wheel (tail draggers have none)
            zn = nose + max(p.nose_len, 0.05 * L) + 0.06
            b.rod((0, bottom, zn), (0, gy + wr, zn), 0.0285)
            b.cylinder((0, gy + wr, zn), wr, FIN_HALF, ALONG_X)
    return b.shape()


def _tail(b: CSGBuilder, p: AirplaneParams) -> None:
    fr, tail = p.radius, p.length / 2
    rake = rotation(X, p.fin_rake)
    # the fin's root: its front corner on the fuselage's level top line, its back end where the tail
    # cone is still deep enough to hold the raked root's low back corner
    drop = p.fin_c * math.sin(p.fin_rake)
    z_back = tail - 0.01
    ts = tail - p.tail_len
    while z_back > ts and 2 * _tail_axis_y(p, z_back)[1] < drop + 0.01:
        z_back -= 0.01
    z_back = min(z_back, tail - p.fin_h * math.sin(p.fin_rake))  # the fin's top ends over the tail
    z_front = z_back - p.fin_c * math.cos(p.fin_rake)
    # the tailplane's root chord mid point; its swept tips end near the tail's end
    reach = p.stab_span / 2 * math.sin(p.stab_sweep) + p.stab_chord / 2
    stab_z = tail - reach + 0.02
    stab_y = _tail_axis_y(p, stab_z)[0]
    if p.tail in ("t", "cruciform"):  # on the fin: the fin moves forward as far as the tailplane needs
        level = 1.0 if p.tail == "t" else p.stab_level
        on_fin = z_front + p.fin_h * level * math.sin(p.fin_rake) + p.fin_c / 2 * math.cos(p.fin_rake)
        z_front -= max(0.0, on_fin - stab_z)
    fins = []
    if p.tail in ("conventional", "t", "cruciform"):
        fins = [(0.0, np.eye(3), FIN_HALF)]
    elif p.tail in ("twin", "v"):
        fins = [(s * fr * 0.55, rotation(Z, -s * p.fin_cant), 0.03) for s in (-1, 1)]
    for x, cant, half in fins:
        rot = cant @ rake
        corner = np.array([x, fr - 0.012 - (0.01 if x else 0.0), z_front])
        b.box(corner + rot @ np.array([0, p.fin_h / 2, p.fin_c / 2]), (half, p.fin_h / 2, p.fin_c / 2), rot)
        if p.tail == "t":
            stab_y, stab_z = (corner + rot @ np.array([0, p.fin_h - 0.028, p.fin_c / 2]))[1:]
        elif p.tail == "cruciform":
            stab_y, stab_z = (corner + rot @ np.array([0, p.fin_h * p.stab_level, p.fin_c / 2]))[1:]
    if p.tail == "v" or p.stab_span <= 0:
        return
    for s in (-1, 1):
        rot = rotation(Y, -s * p.stab_sweep)
        centre = np.array([0.0, stab_y, stab_z]) + rot @ np.array([s * p.stab_span / 4, 0, 0])
        b.box(centre, (p.stab_span / 4, 0.0285, p.stab_chord / 2), rot)
        if p.tail == "h":  # a fin on each tip
            tip = np.array([0.0, stab_y, stab_z]) + rot @ np.array([s * p.stab_span / 2 - s * 0.03, 0, 0])
            b.box(tip + np.array([0, 0.0, 0.01]), (0.03, p.fin_h * 0.6, p.fin_c / 2), rake)


def _engines(b: CSGBuilder, p: AirplaneParams, wings: list) -> None:
    fr, nose, tail = p.radius, -p.length / 2, p.length / 2
    er, el = p.engine_r, p.engine_len
    if p.engines == "wing":
        for w in wings:
            for f in p.engine_at:
                le = w.at(f, 0.0)
                down = w.rot @ np.array([0.0, -(p.wing_thick / 2 + er * 0.75), 0.0])
                b.cylinder(le + down + np.array([0, 0, el * 0.15]), er, el / 2, ALONG_Z)
    elif p.engines == "rear":
        ez = nose + p.engine_at[0] * p.length
        ay, r = _tail_axis_y(p, ez)
        b.box((0, ay + r * 0.3, ez), (r + er * 1.2, 0.0285, max(el * 0.3, 0.03)))  # the pylons, through the body
        for s in (-1, 1):
            b.cylinder((s * (r + er + 0.015), ay + r * 0.3, ez), er, el / 2, ALONG_Z)
    elif p.engines == "nozzle":
        ay, r = _tail_axis_y(p, tail)
        xs = (0.0,) if p.engine_at[0] == 0.0 else (-er * 0.9, er * 0.9)
        rr = er if len(xs) == 1 else max(er * 0.75, 0.03)
        for x in xs:
            b.cylinder((x, ay, tail - el / 2 + 0.02), rr, el / 2, ALONG_Z)
    elif p.engines == "nose_prop":
        b.cone((0, 0, nose - 0.025), 0.035, 0.012, max(0.7 * fr, 0.04), ALONG_Z)
        b.box((0, 0, nose - 0.02), (0.035, p.blade, 0.028), rotation(Z, p.blade_roll))
    elif p.engines == "wing_props":
        for w in wings:
            le = w.at(p.engine_at[0], 0.0)
            b.cylinder(le + np.array([0, 0, el * 0.3]), er, el / 2, ALONG_Z)
            b.box(le + np.array([0, 0, -el * 0.2 - 0.015]), (0.035, p.blade, 0.028),
                  rotation(Z, p.blade_roll + w.side * 0.5))
