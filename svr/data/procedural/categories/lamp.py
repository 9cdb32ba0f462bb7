"""The procedural lamp, in four styles: "desk" (a disc, square or dome base, a gooseneck or an arm of
two or three segments, single rods or parallel pairs with a hole between them, turned sideways by up
to 35 degrees, and a cone, dome, drum or flat bar head tilted towards the front), "floor" (a pole on a
disc, square, dome, cross or tripod base, straight or arching over the front, with a drum, cone,
dome, globe or uplighter bowl shade and an optional reading arm), "hanging" (a canopy and a cord over
a cone, dome, drum, globe or bare bulb, two to four pendants under a bar, or a chandelier of three to
six arms with candles, cups, globes or small shades) and "table" (a ball, column, vase, gourd, block,
tripod or candlestick body under a drum, cone, empire or mushroom dome shade). Drawn from wide ranges:
height / width, shade height 0.1-0.4 and radii 0.1-0.3, wall 0.058-0.075, base size, arm lengths
0.22-0.7 and angles, head tilt 0-0.8 rad, cord length, rod thickness.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import AXIS_ROD, X, Y, bar, chance, frame, hollow_cone, uniform

STYLES = ("desk", "floor", "hanging", "table")
SHADES = ("cone", "drum", "dome", "globe", "bowl", "bulb", "bar", "empire", "chandelier")
BASES = ("disc", "square", "dome", "cross", "tripod")
BODIES = ("ball", "column", "vase", "gourd", "block", "tripod", "candlestick")
LIGHTS = ("candle", "cup", "globe", "shade")
T = 0.055  # the thinnest part (blocks.MIN_PART)
R = T / 2  # the thinnest rod's radius


@dataclass(frozen=True)
class LampParams:
    """One lamp. Lengths are raw units, the height about 1 (less for wide lamps)."""

    style: str
    height: float            # floor to top; hanging lamps: the drop from the ceiling
    shade: str               # SHADES
    shade_h: float
    shade_rb: float          # bottom radius
    shade_rt: float          # top radius
    wall: float
    base: str                # BASES (desk, floor) or BODIES (table)
    base_r: float            # base / body radius
    base_h: float            # base / body height
    rod: float               # rod radius; poles on the axis draw within AXIS_ROD of the longest side
    axis_rod: float          # 0..1 within AXIS_ROD
    segments: tuple[tuple[float, float], ...]  # desk: (length, angle from vertical, + leans to the front); floor arc
    paired: tuple[bool, ...]  # desk: which segments are parallel pairs
    yaw: float               # desk: the arm turned about y
    tilt: float              # desk: the head's tilt from straight down, towards the front
    arms: int                # chandelier arms / hanging pendants / floor reading arm (0 or 1)
    reach: float             # chandelier arm reach; floor arc reach; pendant bar half length
    rise: float              # chandelier: arm rise
    light: str               # LIGHTS (chandelier)
    light_size: float
    canopy: float            # hanging / chandelier canopy radius
    body: str                # chandelier body: "ball", "cone", "ring"
    neck: float              # 0..1: the gap from a table lamp's body to its shade, where poles meet shades
    harp: bool               # table lamp: two spokes to the shade (a harp), else three
    angle: float             # rotation about y of arms and feet


def _shade_kind(rng: np.random.Generator, style: str) -> str:
    options = {"desk": (("cone", "dome", "drum", "bar"), (0.4, 0.3, 0.15, 0.15)),
               "floor": (("drum", "cone", "dome", "globe", "bowl"), (0.3, 0.25, 0.15, 0.1, 0.2)),
               "hanging": (("cone", "dome", "drum", "globe", "bulb"), (0.3, 0.3, 0.2, 0.12, 0.08)),
               "table": (("drum", "cone", "empire", "dome"), (0.35, 0.2, 0.3, 0.15))}[style]
    return str(rng.choice(options[0], p=options[1]))


def sample(rng: np.random.Generator, style: str) -> LampParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    shade = _shade_kind(rng, style)
    shade_h = uniform(rng, 0.1, 0.4)
    shade_rb = uniform(rng, 0.1, 0.3)
    shade_rt = shade_rb * uniform(rng, 0.35, 1.0)
    base = str(rng.choice(BASES, p=(0.35, 0.2, 0.15, 0.15, 0.15)))
    base_r, base_h = uniform(rng, 0.1, 0.25), uniform(rng, T, 0.12)
    height = uniform(rng, 0.85, 1.0)
    segments: tuple[tuple[float, float], ...] = ()
    paired: tuple[bool, ...] = ()
    arms, reach, rise = 0, uniform(rng, 0.2, 0.45), uniform(rng, -0.1, 0.2)
    if style == "desk":
        n = int(rng.choice([1, 2, 3], p=[0.15, 0.6, 0.25]))
        if n == 1:  # a gooseneck leaning forwards
            segments = ((uniform(rng, 0.45, 0.7), uniform(rng, 0.1, 0.6)),)
        else:  # an arm: leaning back or forwards, then forwards, then down to the head
            angles = (uniform(rng, -0.5, 0.35), uniform(rng, 0.9, 2.1), uniform(rng, 1.6, 2.7))
            segments = tuple((uniform(rng, 0.22, 0.45), angles[k]) for k in range(n))
        paired = tuple(chance(rng, 0.5) for _ in range(n))
        shade_h, shade_rb = uniform(rng, 0.06, 0.16), uniform(rng, 0.08, 0.17)
        shade_rt = shade_rb * uniform(rng, 0.35, 0.9)
        base = ("disc", "square", "dome")[int(rng.integers(3))]
        base_r = uniform(rng, 0.09, 0.17)
    elif style == "floor":
        arms = int(chance(rng, 0.25))
        base = str(rng.choice(BASES, p=(0.35, 0.15, 0.15, 0.15, 0.2)))
        if chance(rng, 0.3):  # an arc: the pole bows over towards the front
            segments = ((uniform(rng, 0.4, 0.7), 0.0),)
            shade = ("dome", "cone")[int(rng.integers(2))]
        shade_h, shade_rb = uniform(rng, 0.1, 0.3), uniform(rng, 0.1, 0.24)
        if shade == "bowl":
            shade_rt = shade_rb * uniform(rng, 1.0, 1.3)  # the mouth
            shade_rb, shade_h = shade_rt * uniform(rng, 0.5, 0.75), uniform(rng, 0.12, 0.2)
    elif style == "hanging":
        height = uniform(rng, 0.45, 1.0)
        shade_h, shade_rb = uniform(rng, 0.08, 0.3), uniform(rng, 0.12, 0.3)
        if chance(rng, 0.3):  # a chandelier
            shade, height, arms = "chandelier", uniform(rng, 0.4, 0.9), int(rng.integers(3, 7))
            reach = uniform(rng, 0.22, 0.45)
        else:  # one shade, or two to four under a bar
            arms = int(rng.choice([1, 2, 3, 4], p=[0.75, 0.1, 0.1, 0.05]))
    else:  # table
        base = str(rng.choice(BODIES))
        base_r, base_h = uniform(rng, 0.06, 0.17), uniform(rng, 0.15, 0.45)
        shade_h, shade_rb = uniform(rng, 0.14, 0.32), uniform(rng, 0.14, 0.3)
        if shade == "empire":
            shade_rt = shade_rb * uniform(rng, 0.45, 0.75)
        elif shade == "drum":
            shade_rt = shade_rb * uniform(rng, 0.9, 1.0)
    return LampParams(
        style=style, height=height, shade=shade, shade_h=shade_h, shade_rb=shade_rb, shade_rt=shade_rt,
        wall=uniform(rng, 0.058, 0.075), base=base, base_r=base_r, base_h=base_h, rod=uniform(rng, R, 0.045),
        axis_rod=uniform(rng, 0.0, 1.0), segments=segments, paired=paired, yaw=uniform(rng, -0.6, 0.6),
        tilt=uniform(rng, 0.0, 0.8), arms=arms, reach=reach, rise=rise,
        light=str(rng.choice(LIGHTS)), light_size=uniform(rng, 0.0, 1.0), canopy=uniform(rng, 0.06, 0.12),
        body=("ball", "cone", "ring")[int(rng.integers(3))], neck=uniform(rng, 0.0, 1.0), harp=chance(rng, 0.6),
        angle=uniform(rng, 0.0, 2 * math.pi),
    )


# ------------------------------------------------------------------------------------ parts


def _axis_radius(p: LampParams, longest: float) -> float:
    """A rod on the lamp's axis: thinner than a voxel of the normalised grid (blocks.AXIS_ROD)."""
    return (AXIS_ROD[0] + p.axis_rod * (AXIS_ROD[1] - AXIS_ROD[0])) * longest


def _shade(b: CSGBuilder, kind: str, mouth, down, h: float, rb: float, rt: float, wall: float,
           closed_top: bool = False, along=(0.0, 0.0, -1.0)) -> None:
    """A shade whose open mouth (radius rb) is centred at ``mouth`` and faces ``down``; h tall.
    Built before the parts it must not cut: its cavity is a subtraction."""
    down = np.asarray(down, dtype=np.float64)
    down = down / np.linalg.norm(down)
    mouth = np.asarray(mouth, dtype=np.float64)
    rot = frame(-down, X if abs(down[0]) < 0.9 else Y)
    if kind in ("cone", "drum", "empire"):
        hollow_cone(b, mouth - down * h / 2, rot, h / 2, rb, rt, wall, open_top=not closed_top)
    elif kind == "bowl":  # an uplighter's bowl: the mouth faces up, the far end closed
        hollow_cone(b, mouth - down * h / 2, rot, h / 2, rb, rt, wall, open_top=False)
    elif kind == "dome":  # a spherical cap of radius rb, h deep: its cut is a box over the mouth
        r = rb
        depth = min(h, r)
        c = mouth + down * (r - depth)  # the sphere's centre: the mouth is a chord plane
        b.sphere(c, r)
        b.sphere(c, r - wall, op="subtract")
        b.box(mouth + down * (r + 0.02), (r + 0.05, r + 0.02, r + 0.05), rot, op="subtract")
    elif kind == "globe":
        b.sphere(mouth - down * rb, rb)
    elif kind == "bulb":
        b.sphere(mouth - down * rb, rb)
        b.rod(mouth - down * rb * 1.5, mouth - down * (2 * rb + 0.04), max(R, 0.45 * rb))
    else:  # bar: a flat LED head, long along ``along``
        t = T + 0.01
        b.box(mouth - down * t / 2, (max(t / 2, 0.4 * rb), t / 2, 1.4 * rb), frame(-down, np.cross(-down, along)))


def _base(b: CSGBuilder, p: LampParams, x: float, z: float, r: float, h: float) -> float:
    """A base on the floor under (x, z); returns the height of its top."""
    b.part("base")
    if p.base == "disc":
        b.cylinder((x, h / 2, z), r, h / 2)
        return h
    if p.base == "square":
        b.box((x, h / 2, z), (r * 0.9, h / 2, r * 0.9), rotation(Y, p.angle), rounding=0.01)
        return h
    if p.base == "dome":  # a low cone on a plinth (a bare cone would end in a knife-thin rim)
        hp, hh = T + 0.005, max(h, 0.4 * r)
        b.cylinder((x, hp / 2, z), r, hp / 2)
        b.cone((x, hp + hh / 2 - 0.005, z), hh / 2, r * 0.9, max(R + 0.01, 0.3 * r))
        return hp + hh - 0.01
    # feet: a cross of four or a tripod of three, sloping up to a hub
    n = 4 if p.base == "cross" else 3
    hub = h + 0.05
    for k in range(n):
        a = p.angle + 2 * math.pi * k / n
        foot = (x + 1.3 * r * math.cos(a), R, z + 1.3 * r * math.sin(a))
        b.capsule(foot, (x, hub, z), R + 0.005)
    return hub


def _longest(p: LampParams) -> float:
    """The lamp's longest side, for rods on its axis."""
    return max(p.height, 2 * max(p.shade_rb, p.shade_rt, p.base_r * 1.3))


# ------------------------------------------------------------------------------------ styles


def _desk(b: CSGBuilder, p: LampParams) -> None:
    yaw = rotation(Y, p.yaw)
    base_top = p.base_h + 0.02
    p0 = np.array([0.0, base_top, 0.0])
    pts = [p0]
    for length, angle in p.segments:  # the angle from straight up, towards the front
        pts.append(pts[-1] + length * np.array([0.0, math.cos(angle), -math.sin(angle)]))
    pts = [yaw @ q for q in pts]
    # the head: pointing down and forwards, tilted
    fwd = yaw @ np.array([0.0, 0.0, -1.0])
    down = np.array([0.0, -math.cos(p.tilt), 0.0]) + fwd * math.sin(p.tilt)
    head = pts[-1]
    lift = head[1] - (p.shade_h + p.rod + 0.03)
    if lift < 0:  # keep the head above the floor
        pts = [q + np.array([0.0, -lift, 0.0]) * (k / (len(pts) - 1)) for k, q in enumerate(pts)]
        head = pts[-1]
    b.part("shade")
    depth = T + 0.01 if p.shade == "bar" else p.shade_h
    _shade(b, p.shade, head + down * (depth + p.rod), down, p.shade_h, p.shade_rb, p.shade_rt, p.wall,
           closed_top=True, along=fwd)
    b.part("arm")
    side = yaw @ np.array([1.0, 0.0, 0.0])
    for k, (a, c) in enumerate(zip(pts[:-1], pts[1:])):
        if p.paired[k]:  # two parallel rods in the arm's plane, with a hole between them
            u = c - a
            n = np.cross(side, u / np.linalg.norm(u))
            off = 0.045 + 0.02 * p.light_size
            for s in (-1, 1):
                b.rod(a + s * n * off, c + s * n * off, R)
            for q in (a, c):
                bar(b, q - n * (off + R), q + n * (off + R), T + 0.005, T + 0.005, side)
        else:
            b.rod(a, c, p.rod)
        b.sphere(c, p.rod + 0.012)  # the joint
    _base(b, p, 0.0, 0.0, p.base_r, p.base_h)


def _floor(b: CSGBuilder, p: LampParams) -> None:
    h = p.height
    longest = _longest(p)
    if p.segments:  # an arc lamp: the pole bows over the front, a shade hangs at its tip
        reach = p.segments[0][0] * h
        top = np.array([0.0, h, -reach * 0.35])
        tip = np.array([0.0, h - 0.12, -reach])
        mouth = tip + np.array([0.0, -0.03 - (min(p.shade_h, p.shade_rb) if p.shade == "dome" else p.shade_h), 0.0])
        b.part("shade")
        _shade(b, p.shade, mouth, (0, -1, 0), p.shade_h, p.shade_rb, p.shade_rt, p.wall, closed_top=True)
        rod = max(p.rod, 0.033)
        base_top = _base(b, p, 0.0, 0.0, p.base_r, p.base_h)
        b.part("pole")
        knee = np.array([0.0, h * (0.7 + 0.2 * p.neck), 0.0])
        b.rod((0.0, base_top - 0.01, 0.0), knee, rod)
        b.rod(knee, top, rod)
        b.rod(top, tip, rod)
        b.sphere(knee, rod + 0.01)
        b.sphere(top, rod + 0.01)
        b.rod(tip + np.array([0.0, 0.02, 0.0]), tip - np.array([0.0, 0.05, 0.0]), rod)
        return
    b.part("shade")
    if p.shade == "globe":
        r = min(p.shade_rb, 0.15)
        _shade(b, "globe", (0, h - 2 * r, 0), (0, -1, 0), 2 * r, r, r, p.wall)
        pole_top = h - r
    elif p.shade == "bowl":  # an uplighter: the wide mouth at the top
        _shade(b, "bowl", (0, h, 0), (0, 1, 0), p.shade_h, p.shade_rt, p.shade_rb, p.wall)
        pole_top = h - p.shade_h + p.wall
    else:
        ys0 = h - (min(p.shade_h, p.shade_rb) if p.shade == "dome" else p.shade_h)  # the shade's mouth
        _shade(b, p.shade, (0, ys0, 0), (0, -1, 0), p.shade_h, p.shade_rb, p.shade_rt, p.wall)
        pole_top = ys0 + p.shade_h * (0.35 + 0.4 * p.neck)
        if p.shade == "dome":
            pole_top = h - p.wall
        else:  # spokes from the pole to the shade's wall
            f = (pole_top + 0.03 - ys0) / p.shade_h
            r_at = p.shade_rb + (p.shade_rt - p.shade_rb) * f - p.wall / 2
            for k in range(2):
                a = p.angle + math.pi * k
                b.rod((0, pole_top - 0.02, 0), (r_at * math.cos(a), pole_top + 0.03, r_at * math.sin(a)), R)
    base_top = _base(b, p, 0.0, 0.0, p.base_r, p.base_h)
    lo, hi = b.shape().bounds  # conservative: the pole is at least as thick as AXIS_ROD asks
    longest = max(longest, float((hi - lo).max()), h)
    b.part("pole")
    b.cylinder((0, (base_top + pole_top) / 2 - 0.005, 0), _axis_radius(p, longest), (pole_top - base_top) / 2 + 0.01)
    if p.arms:  # a reading arm with a small cone on the side
        y = h * (0.45 + 0.2 * p.neck)
        a = p.angle
        d = np.array([math.cos(a), 0.0, math.sin(a)])
        tip = np.array([0.0, y + 0.1, 0.0]) + d * 0.22
        b.part("shade")
        b.cone(tip + d * 0.03 + np.array([0, -0.06, 0]), 0.05, 0.07, 0.035, frame((-d[0] * 0.5, 1, -d[2] * 0.5)))
        b.part("pole")
        b.rod((0.0, y, 0.0), tip, R + 0.003)


def _hanging(b: CSGBuilder, p: LampParams) -> None:
    if p.shade == "chandelier":
        _chandelier(b, p)
        return
    n = p.arms
    sh, rb, rt = p.shade_h, p.shade_rb, p.shade_rt
    if n > 1:  # pendants under a bar: smaller shades
        sh, rb, rt = sh * 0.7, max(0.08, rb * 0.6), max(0.05, rt * 0.6)
    xs = [0.0] if n == 1 else list(np.linspace(-1, 1, n) * min(max(p.reach, (n - 1) * rb * 1.15 / 2 + 0.02), 0.48 - rb))
    tops = []
    b.part("shade")
    for x in xs:
        if p.shade == "dome":
            depth = min(sh, rb)
            _shade(b, "dome", (x, 0.0, 0.0), (0, -1, 0), depth, rb, rb, p.wall)
            tops.append(depth)
        elif p.shade in ("globe", "bulb"):
            r = min(rb, 0.2) * (0.6 if p.shade == "bulb" else 1.0)
            b.sphere((x, r, 0), r)
            tops.append(2 * r)
        else:
            r_top = rb if p.shade == "drum" else rt
            _shade(b, "cone", (x, 0.0, 0.0), (0, -1, 0), sh, rb, r_top, p.wall, closed_top=True)
            tops.append(sh)
    top = max(tops)
    drop = max(p.height * max(1.0, 2 * max(xs[-1] + rb, rb)) - top, 0.15)
    ceiling = top + drop
    b.part("cord")
    if n == 1:
        longest = max(2 * rb, ceiling)
        b.cylinder((0, (tops[0] + ceiling) / 2 - 0.01, 0), _axis_radius(p, longest), (ceiling - tops[0]) / 2 + 0.02)
    else:  # a bar over the shades, hung from two cords
        yb = top + 0.04 + 0.25 * drop * p.neck
        b.box((0, yb, 0), (xs[-1] + 0.04, T / 2 + 0.005, T / 2 + 0.005))
        for x, t in zip(xs, tops):
            b.rod((x, t - 0.01, 0), (x, yb, 0), R)
        for x in (-0.7 * xs[-1], 0.7 * xs[-1]):
            b.rod((x, yb, 0), (x, ceiling, 0), R)
    b.part("canopy")
    c = p.canopy if n == 1 else max(p.canopy, 0.3 * xs[-1])
    if n == 1:
        c = min(c, 0.75 * rb + 0.02)
    hc = 0.035 + 0.02 * p.light_size
    if n == 1:
        b.cone((0, ceiling - hc, 0), hc, c * 0.7, c)
    else:
        b.box((0, ceiling - hc, 0), (xs[-1] * 0.8, hc, max(T / 2 + 0.005, c * 0.5)))


def _chandelier(b: CSGBuilder, p: LampParams) -> None:
    """Three to six arms from a central body, a light at each tip, hung from a stem."""
    n, reach = p.arms, p.reach
    size = 0.5 + 0.5 * p.light_size
    y_arm = 0.12
    tips = []
    for k in range(n):
        a = p.angle + 2 * math.pi * k / n
        tips.append(np.array([reach * math.cos(a), y_arm + p.rise * reach, reach * math.sin(a)]))
    b.part("arms")
    for tip in tips:
        b.rod((0.0, y_arm, 0.0), tip, R + 0.002)
    b.part("lights")
    for tip in tips:
        if p.light == "candle":
            hc = 0.08 + 0.1 * size
            b.cylinder(tip + np.array([0, hc / 2 - 0.01, 0]), R + 0.006 + 0.01 * size, hc / 2)
        elif p.light == "cup":  # a glass opening upwards
            b.cone(tip + np.array([0, 0.03 + 0.02 * size, 0]), 0.03 + 0.02 * size, 0.035, 0.05 + 0.04 * size)
        elif p.light == "globe":
            b.sphere(tip + np.array([0, 0.03, 0]), 0.04 + 0.035 * size)
        else:  # a small shade opening downwards
            b.cone(tip - np.array([0, 0.02 + 0.02 * size, 0]), 0.035 + 0.02 * size, 0.05 + 0.04 * size, 0.035)
    b.part("body")
    if p.body == "ball":
        b.sphere((0, y_arm, 0), 0.06 + 0.04 * size)
    elif p.body == "cone":
        b.cone((0, y_arm - 0.04, 0), 0.09, 0.03 + 0.02 * size, 0.07 + 0.03 * size)
    else:  # a ring through the arms
        b.torus((0, y_arm + p.rise * reach * 0.55, 0), reach * 0.55, R + 0.003)
    width = 2 * (reach + 0.1)
    lo_y = min(0.0, min(float(t[1]) for t in tips) - 0.1)
    ceiling = max(y_arm + 0.15, lo_y + min(p.height * width * 1.2, 1.0))
    b.part("cord")
    longest = max(width, ceiling - lo_y)
    b.cylinder((0, (y_arm + ceiling) / 2, 0), _axis_radius(p, longest), (ceiling - y_arm) / 2)
    b.part("canopy")
    b.cone((0, ceiling - 0.03, 0), 0.03, p.canopy * 0.7, p.canopy)


def _table(b: CSGBuilder, p: LampParams) -> None:
    r, hb = p.base_r, p.base_h
    # the body: its top at body_top
    body_top = {"ball": 0.03 + 2 * r, "gourd": 0.03 + 2 * r + 1.4 * r * 0.7}.get(p.base, hb)
    gap = 0.03 + p.neck * 0.2
    sh = p.shade_h
    ys0 = body_top + gap  # the shade's mouth
    scale = min(1.0, 0.6 * (ys0 + sh) / max(p.shade_rb, p.shade_rt))  # no wider than about its height
    rb, rt = p.shade_rb * scale, p.shade_rt * scale
    b.part("shade")
    if p.shade == "dome":  # a mushroom lamp: the stem runs up to the dome's crown
        depth = min(sh, rb)
        _shade(b, "dome", (0, ys0, 0), (0, -1, 0), depth, rb, rb, p.wall)
        hp = ys0 + depth - p.wall
        longest = max(ys0 + depth, 2 * max(rb, r))
    else:
        _shade(b, p.shade, (0, ys0, 0), (0, -1, 0), sh, rb, rt, p.wall)
        hp = ys0 + sh * (0.4 + 0.3 * p.neck)
        longest = max(ys0 + sh, 2 * max(rb, rt, r * 1.6))
        f = (hp + 0.04 - ys0) / sh
        r_at = rb + (rt - rb) * f - p.wall / 2
        n = 2 if p.harp else 3  # a harp's two spokes, or three
        for k in range(n):
            a = p.angle + 2 * math.pi * k / n
            b.rod((0, hp - 0.02, 0), (r_at * math.cos(a), hp + 0.04, r_at * math.sin(a)), R)
    b.part("stem")
    b.cylinder((0, (body_top + hp) / 2 - 0.01, 0), _axis_radius(p, longest), (hp - body_top) / 2 + 0.02)
    b.part("base")
    if p.base == "ball":
        b.cylinder((0, 0.02, 0), r * 0.7, 0.02 + 0.005)
        b.sphere((0, 0.03 + r, 0), r)
    elif p.base == "column":
        b.cylinder((0, 0.025, 0), r * 1.5, 0.025 + 0.005)
        b.cylinder((0, hb / 2, 0), max(r * 0.6, 0.045), hb / 2)
    elif p.base == "block":
        b.box((0, hb / 2, 0), (r, hb / 2, r * (0.6 + 0.4 * p.neck)), rotation(Y, p.angle))
    elif p.base == "candlestick":
        b.cylinder((0, 0.025, 0), r * 1.4, 0.025 + 0.005)
        b.cone((0, hb / 2, 0), hb / 2, 0.05, 0.04)
        b.cylinder((0, hb, 0), 0.06 + 0.03 * p.neck, 0.02 + 0.005)
    elif p.base == "gourd":
        b.sphere((0, 0.03 + r, 0), r)
        b.sphere((0, 0.03 + 2 * r + 0.4 * r * 0.7, 0), r * 0.7)
    elif p.base == "vase":  # a swelling body on a narrow foot: two cones
        hm = hb * (0.3 + 0.3 * p.neck)
        b.cone((0, hm / 2, 0), hm / 2, r * 0.55, r)
        b.cone((0, hm + (hb - hm) / 2, 0), (hb - hm) / 2, r, max(0.04, r * 0.35))
    else:  # tripod legs meeting under the stem
        for k in range(3):
            a = p.angle + 2 * math.pi * k / 3
            b.capsule((1.3 * r * math.cos(a), R, 1.3 * r * math.sin(a)), (0, hb, 0), R + 0.004)


def build(p: LampParams) -> CSGShape:
    b = CSGBuilder()
    {"desk": _desk, "floor": _floor, "hanging": _hanging, "table": _table}[p.style](b, p)
    return b.shape()
