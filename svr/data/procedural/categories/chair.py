"""The procedural chair: a seat (box, rounded or round; 0.36-0.78 wide, 0.34-0.66 deep, 0.055-0.15
thick, at 0.22-0.56, a bar stool's at 0.55-0.8, optionally a cushion) on a base, with a back at +z
(0.12-0.62 high, 55-100% of the seat's width, tilted 0-0.38 rad) and optional arms. Styles:
"four_legs": straight, tapered, round or splayed legs (0.055-0.10 thick), optional stretchers, a
solid, framed, pierced or curved back; "slatted": the same legs under a back of posts with 1-6
vertical slats or spindles or 1-4 ladder rails; "armchair": legs, a sled or a solid block under
any back with open or panel arms (0.12-0.3 above the seat); "swivel": a column over a 4-5 spoke
star (casters optional) or a disk, a back on a stem, optional arms; "cantilever": a tube frame
running down from the seat's front and back along the floor; "barstool": a tall seat on legs with
a foot ring, or on a column, with no back or a low one. Everything thin is at least MIN_PART.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import pick, MIN_PART, UPRIGHT_LEGS, X, Y, bar, chance, leg, uniform

STYLES = ("four_legs", "slatted", "armchair", "swivel", "cantilever", "barstool")
SEATS = ("box", "rounded", "round")
LEGS = ("straight", "tapered", "round", "splayed")
BASES = ("legs", "sled", "block", "star", "disk", "cantilever")
BACKS = ("none", "solid", "framed", "pierced", "shell", "slats", "spindles", "ladder")
ARMS = ("none", "open", "panel")
STRETCHERS = ("none", "h", "box", "ring")
HALF = MIN_PART / 2
Z_HINT = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class ChairParams:
    style: str
    seat: str            # SEATS
    seat_w: float
    seat_d: float
    seat_t: float
    seat_h: float        # top of the base, bottom of the seat
    seat_round: float    # edge rounding of a box seat
    cushion_t: float     # 0: none
    base: str            # BASES
    leg: str             # LEGS
    leg_t: float
    leg_inset: float
    splay: float         # outward run of splayed legs at the floor
    stretcher: str       # STRETCHERS
    stretcher_y: float
    spokes: int          # star base
    foot_r: float        # star or disk radius
    casters: bool
    column_r: float
    back: str            # BACKS
    back_h: float
    back_w: float        # fraction of the seat's width
    back_t: float
    back_tilt: float
    back_gap: float      # swivel: gap between seat and back
    back_round: float
    n_back: int          # slats, spindles or rails
    slat_fill: float     # how much of its pitch a slat or rail fills
    post_w: float
    rail_h: float
    shell_r: float       # radius of a curved back, in seat widths
    arms: str            # ARMS
    arm_h: float
    arm_t: float
    arm_len: float       # fraction of the seat's depth


def sample(rng: np.random.Generator, style: str) -> ChairParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    seat = pick(rng, SEATS, (0.5, 0.35, 0.15) if style != "barstool" else (0.25, 0.25, 0.5))
    sw, sd = uniform(rng, 0.36, 0.78), uniform(rng, 0.34, 0.66)
    if style == "barstool":
        sw, sd = uniform(rng, 0.3, 0.5), uniform(rng, 0.3, 0.5)
    if seat == "round":
        sd = sw = (sw + sd) / 2
    elif seat == "rounded":
        sd = max(sd, sw)
    st = uniform(rng, MIN_PART, 0.15)
    sh = uniform(rng, 0.55, 0.8) if style == "barstool" else uniform(rng, 0.22, 0.56)
    if style == "armchair":
        sh = uniform(rng, 0.16, 0.46)
    cushion = uniform(rng, MIN_PART, 0.11) if chance(rng, 0.55 if style == "armchair" else 0.2) else 0.0
    base = {"four_legs": "legs", "slatted": "legs", "cantilever": "cantilever",
            "armchair": pick(rng, ("legs", "sled", "block"), (0.55, 0.2, 0.25)),
            "swivel": pick(rng, ("star", "disk"), (0.75, 0.25)),
            "barstool": pick(rng, ("legs", "disk"), (0.65, 0.35))}[style]
    leg = pick(rng, LEGS)
    leg_t = uniform(rng, MIN_PART, 0.1)
    stretcher = pick(rng, STRETCHERS, (0.5, 0.25, 0.15, 0.1) if style != "barstool" else (0.1, 0.2, 0.2, 0.5))
    # the back
    if style == "four_legs":
        back = pick(rng, ("solid", "framed", "pierced", "shell"), (0.4, 0.2, 0.2, 0.2))
    elif style == "slatted":
        back = pick(rng, ("slats", "spindles", "ladder"))
    elif style == "barstool":
        back = pick(rng, ("none", "solid", "framed", "ladder"), (0.5, 0.2, 0.15, 0.15))
    elif style == "armchair":
        back = pick(rng, ("solid", "shell", "slats", "ladder"), (0.45, 0.25, 0.15, 0.15))
    elif style == "swivel":
        back = pick(rng, ("solid", "framed", "pierced"), (0.6, 0.2, 0.2))
    else:
        back = pick(rng, ("solid", "framed", "slats", "ladder"), (0.5, 0.2, 0.15, 0.15))
    back_h = uniform(rng, 0.12, 0.3) if style == "barstool" else uniform(rng, 0.18, 0.62)
    n_back = {"slats": int(rng.integers(1, 7)), "spindles": int(rng.integers(2, 7)),
              "ladder": int(rng.integers(1, 5))}.get(back, 0)
    arms = {"armchair": pick(rng, ("open", "panel"), (0.55, 0.45)),
            "swivel": pick(rng, ("none", "open"), (0.45, 0.55)),
            "four_legs": pick(rng, ("none", "open"), (0.85, 0.15)),
            "cantilever": pick(rng, ("none", "open"), (0.75, 0.25))}.get(style, "none")
    p = dict(style=style, seat=seat, seat_w=sw, seat_d=sd, seat_t=st, seat_h=sh,
             seat_round=uniform(rng, 0.0, 0.06), cushion_t=cushion, base=base, leg=leg, leg_t=leg_t,
             leg_inset=uniform(rng, 0.0, 0.06), splay=uniform(rng, 0.03, 0.12), stretcher=stretcher,
             stretcher_y=uniform(rng, 0.15, 0.5), spokes=int(rng.integers(4, 6)), foot_r=uniform(rng, 0.18, 0.36),
             casters=chance(rng, 0.6), column_r=uniform(rng, 0.03, 0.06), back=back, back_h=back_h,
             back_w=uniform(rng, 0.55, 1.0), back_t=uniform(rng, MIN_PART, 0.13),
             back_tilt=uniform(rng, 0.0, 0.38), back_gap=uniform(rng, 0.02, 0.12), back_round=uniform(rng, 0.0, 0.06),
             n_back=n_back, slat_fill=uniform(rng, 0.25, 0.8),
             post_w=uniform(rng, MIN_PART, 0.09), rail_h=uniform(rng, MIN_PART, 0.16),
             shell_r=uniform(rng, 0.52, 1.2), arms=arms, arm_h=uniform(rng, 0.12, 0.3),
             arm_t=uniform(rng, MIN_PART, 0.12), arm_len=uniform(rng, 0.6, 1.05))
    # the longest side at most 1.05: shrink the sizes (not the thicknesses) of a big chair; each
    # extent is (the part that scales, the part that does not)
    c, sn = math.cos(p["back_tilt"]), math.sin(p["back_tilt"])
    extents = [(sh + back_h * c, st + cushion + 0.02 + (p["back_gap"] if style == "swivel" else 0.0)),
               (sd + back_h * sn, p["back_t"] + MIN_PART), (sw, 2 * p["arm_t"]), (2 * p["foot_r"], 0.08)]
    f = min([1.0] + [(1.05 - fixed) / scaled for scaled, fixed in extents])
    for k in ("seat_w", "seat_d", "seat_h", "back_h", "foot_r", "arm_h"):
        p[k] *= f
    return ChairParams(**p)


# ----------------------------------------------------------------------------------- building


def _leg_feet(p: ChairParams) -> list[tuple[float, float]]:
    """(x, z) of the four legs' tops: near the seat's corners, inside a round seat's rim."""
    t, sw, sd = p.leg_t, p.seat_w, p.seat_d
    r = (sw / 2 - t / 2 - p.leg_inset) / math.sqrt(2)  # on a disk of the seat's width
    lx, lz = sw / 2 - t / 2 - p.leg_inset, sd / 2 - t / 2 - p.leg_inset
    if p.seat == "round":
        return [(-r, -r), (r, -r), (-r, r), (r, r)]
    if p.seat == "rounded":  # the front pair under the half disk
        zc = -sd / 2 + sw / 2
        return [(-r, zc - r), (r, zc - r), (-lx, lz), (lx, lz)]
    return [(-lx, -lz), (lx, -lz), (-lx, lz), (lx, lz)]


def _legs(b: CSGBuilder, p: ChairParams) -> list[tuple[float, float]]:
    """Four legs under the seat; returns their (x, z) at the height of the stretchers."""
    t, sh = p.leg_t, p.seat_h
    y = p.stretcher_y * sh
    at_y = []
    hh = sh / 2 + 0.005  # into the seat
    for x, z in _leg_feet(p):
        if p.leg in UPRIGHT_LEGS:
            leg(b, p.leg, x, z, 2 * hh, t)
        else:  # splayed: the foot pushed outwards
            s = p.splay / math.hypot(x, z)
            b.rod((x, sh + 0.01, z), (x * (1 + s), t / 2, z * (1 + s)), max(HALF, t / 2))
            f = 1 + s * (1 - y / sh)
            x, z = x * f, z * f
        at_y.append((x, z))
    return at_y


def _stretchers(b: CSGBuilder, p: ChairParams, feet: list[tuple[float, float]]) -> None:
    y, h = p.stretcher_y * p.seat_h, HALF + 0.004
    radii = [math.hypot(x, z) for x, z in feet]
    if p.stretcher == "ring" and max(radii) - min(radii) < 1e-6:
        b.torus((0, y, 0), radii[0], h, None)
        return
    (x0, z0), (x1, z1), (x2, z2), (x3, z3) = feet  # front left, front right, back left, back right
    bar(b, (x0, y, z0), (x2, y, z2), 2 * h, 2 * h, Y)
    bar(b, (x1, y, z1), (x3, y, z3), 2 * h, 2 * h, Y)
    if p.stretcher == "h":
        bar(b, ((x0 + x2) / 2, y, (z0 + z2) / 2), ((x1 + x3) / 2, y, (z1 + z3) / 2), 2 * h, 2 * h, Y)
    elif p.stretcher in ("box", "ring"):
        bar(b, (x0, y, z0), (x1, y, z1), 2 * h, 2 * h, Y)
        bar(b, (x2, y, z2), (x3, y, z3), 2 * h, 2 * h, Y)


def _base(b: CSGBuilder, p: ChairParams) -> None:
    sh, sw, sd = p.seat_h, p.seat_w, p.seat_d
    if p.base == "legs":
        b.part("legs")
        feet = _legs(b, p)
        if p.stretcher != "none":
            b.part("stretchers")
            _stretchers(b, p, feet)
    elif p.base == "sled":  # two side frames: a floor runner and two uprights each
        b.part("legs")
        t = p.leg_t
        x = sw / 2 - t / 2 - p.leg_inset
        for s in (-1, 1):
            b.box_between((s * x - t / 2, 0, -sd / 2 - 0.02), (s * x + t / 2, t, sd / 2 + 0.02), rounding=0.02)
            for z in (-sd / 2 + t, sd / 2 - t):
                b.box_between((s * x - t / 2, t, z - t / 2), (s * x + t / 2, sh + 0.01, z + t / 2))
    elif p.base == "block":  # a solid plinth under the seat, set back a little
        b.part("base")
        m = p.leg_inset
        b.box_between((-sw / 2 + m, 0, -sd / 2 + m), (sw / 2 - m, sh + 0.01, sd / 2 - m), rounding=0.02)
    elif p.base == "cantilever":  # per side: seat rail, front upright, floor runner
        b.part("frame")
        t = max(HALF, p.leg_t / 2)
        x = sw / 2 - t - p.leg_inset / 2
        zf, zb = -sd / 2 + p.leg_inset, sd / 2 - 0.02
        lean = p.splay * 1.5
        for s in (-1, 1):
            b.capsule((s * x, sh - t + 0.005, zb), (s * x, sh - t + 0.005, zf), t)
            b.capsule((s * x, sh - t, zf), (s * x, t, zf - lean), t)
            b.capsule((s * x, t, zf - lean), (s * x, t, zb + 0.05), t)
    else:  # star or disk foot, a column
        b.part("base")
        y_hub = 0.06 + 0.1 * p.foot_r
        if p.base == "star":
            y_end = 0.065 if p.casters else 0.03
            for k in range(p.spokes):
                a = 2 * math.pi * (k + 0.5) / p.spokes + (math.pi / 2 if p.spokes == 4 else 0)
                end = (p.foot_r * math.cos(a), y_end, p.foot_r * math.sin(a))
                bar(b, (0, y_hub, 0), end, MIN_PART, 0.06, Y)
            if p.casters:
                b.part("casters")
                for k in range(p.spokes):
                    a = 2 * math.pi * (k + 0.5) / p.spokes + (math.pi / 2 if p.spokes == 4 else 0)
                    b.sphere((p.foot_r * math.cos(a), 0.035, p.foot_r * math.sin(a)), 0.035)
            b.part("base")
            b.cylinder((0, y_hub, 0), p.column_r + 0.015, 0.04)
        else:
            b.cone((0, 0.03, 0), 0.03, p.foot_r, 0.8 * p.foot_r)
            y_hub = 0.05
        b.cylinder((0, (y_hub + sh) / 2, 0), p.column_r, (sh - y_hub) / 2 + 0.01)
        if p.style == "barstool" and p.stretcher != "none":  # a foot ring on spokes
            b.part("stretchers")
            y = p.stretcher_y * sh + 0.1
            r = max(0.11, 0.5 * p.foot_r + 0.05)
            b.torus((0, y, 0), r, HALF + 0.004)
            bar(b, (-r, y, 0), (r, y, 0), MIN_PART, MIN_PART, Z_HINT)


def _seat(b: CSGBuilder, p: ChairParams) -> float:
    """The seat (and its cushion); returns the height of its top."""
    b.part("seat")
    sw, sd, st, sh = p.seat_w, p.seat_d, p.seat_t, p.seat_h
    if p.seat == "round":
        b.cylinder((0, sh + st / 2, 0), sw / 2, st / 2)
    else:
        if p.seat == "rounded":  # a D in plan: a half disk in front of a box
            zc = -sd / 2 + sw / 2
            b.box_between((-sw / 2, sh, zc), (sw / 2, sh + st, sd / 2), rounding=min(p.seat_round, 0.02))
            b.cylinder((0, sh + st / 2, zc), sw / 2, st / 2)
        else:
            b.box((0, sh + st / 2, 0), (sw / 2, st / 2, sd / 2), rounding=p.seat_round)
    top = sh + st
    if p.cushion_t > 0:
        b.part("cushion")
        m = 0.02
        if p.seat == "round":
            b.cylinder((0, top + p.cushion_t / 2 - 0.01, 0), sw / 2 - m, p.cushion_t / 2 + 0.01)
        else:
            b.box((0, top + p.cushion_t / 2 - 0.01, -0.01), (sw / 2 - m, p.cushion_t / 2 + 0.01, sd / 2 - m - 0.01),
                  rounding=0.025)
        top += p.cushion_t
    return top


def _back(b: CSGBuilder, p: ChairParams, top: float) -> None:
    """The back, built upright in a frame whose origin is the middle of the seat's rear edge, then
    tilted backwards about x."""
    if p.back == "none":
        return
    b.part("back")
    sw, sd = p.seat_w, p.seat_d
    bw, bh, bt = p.back_w * sw, p.back_h, p.back_t
    y0 = p.seat_h + p.seat_t
    zb = sd / 2 - bt / 2
    if p.seat == "round":
        zb = sd / 2 * math.sqrt(max(0.0, 1 - (bw / sw) ** 2)) - bt / 2 + 0.02
    if p.style == "swivel":  # on a stem behind the seat, with a gap over the seat
        y0 = top + p.back_gap
        zb = sd / 2 + MIN_PART + bt / 2 - 0.01
    pivot = np.array([0.0, y0, zb])
    rot = rotation(X, p.back_tilt)  # top towards +z
    if p.style == "swivel":
        zs = sd / 2 + HALF
        b.box_between((-0.045, p.seat_h - 0.01, sd / 4), (0.045, p.seat_h + MIN_PART - 0.01, zs + HALF))
        b.box_between((-0.045, p.seat_h - 0.01, zs - HALF), (0.045, y0, zs + HALF))
        bar(b, (0, y0 - 0.01, zs), pivot + rot @ np.array([0.0, 0.5 * bh, -bt / 2 + 0.005]), 0.09, MIN_PART)

    def panel(lo, hi, rounding=0.0, op="union"):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        b.box(pivot + rot @ ((lo + hi) / 2), np.abs(hi - lo) / 2, rot, op=op, rounding=rounding)

    if p.back == "shell":  # a curved shell: a slice of a tube around the seat, vertical
        r = max(p.shell_r * sw / 2, bw / 2 + bt)
        zc = sd / 2 - r
        half_h = bh / 2
        yc = y0 - 0.02 + half_h
        b.cylinder((0, yc, zc), r, half_h + 0.01)
        b.cylinder((0, yc, zc), r - bt, half_h + 0.05, op="subtract")
        zcut = zc + math.sqrt(max(r * r - (bw / 2) ** 2, 0.0))
        b.box_between((-r - 0.1, yc - half_h - 0.1, zc - r - 0.1), (r + 0.1, yc + half_h + 0.1, zcut), op="subtract")
        return
    if p.back in ("solid", "pierced"):
        panel((-bw / 2, -0.02, -bt / 2), (bw / 2, bh, bt / 2), rounding=p.back_round)
        if p.back == "pierced":  # a window through the panel
            m = max(MIN_PART, 0.22 * bw)
            hy0, hy1 = max(MIN_PART, 0.3 * bh, p.cushion_t + 0.03), bh - max(MIN_PART, 0.18 * bh)
            if hy1 - hy0 > 0.05 and bw - 2 * m > 0.05:
                panel((-bw / 2 + m, hy0, -bt), (bw / 2 - m, hy1, bt), rounding=0.02, op="subtract")
        return
    # posts and a top rail, then what fills the frame
    pw, rh = p.post_w, min(p.rail_h, 0.45 * bh)
    t = max(MIN_PART, min(bt, 0.08))
    for s in (-1, 1):
        panel((s * bw / 2 - pw / 2, -0.02, -t / 2), (s * bw / 2 + pw / 2, bh, t / 2))
    panel((-bw / 2 - pw / 2, bh - rh, -t / 2), (bw / 2 + pw / 2, bh, t / 2), rounding=0.01)
    inner = bw - pw
    if p.back == "framed":
        panel((-bw / 2, -0.02, -t / 2), (bw / 2, MIN_PART, t / 2))  # a low rail: the frame is closed
        return
    n = p.n_back
    if p.back == "ladder":
        n = max(1, min(n, int((bh - rh) / (2 * MIN_PART)) - 1))
        pitch = (bh - rh) / (n + 1)
        h = max(MIN_PART, min(p.slat_fill * pitch, pitch - MIN_PART))
        for k in range(n):
            y = pitch * (k + 1)
            panel((-inner / 2, y - h / 2, -HALF), (inner / 2, y + h / 2, HALF))
        return
    # slats or spindles, as many as fit with a gap of at least one part's width
    n = max(1, min(n, int(inner / (2 * MIN_PART)) - 1))
    pitch = inner / (n + 1)
    w = max(MIN_PART, min(p.slat_fill * pitch, pitch - MIN_PART)) if p.back == "slats" else MIN_PART
    for k in range(n):
        x = -inner / 2 + inner * (k + 1) / (n + 1)
        if p.back == "slats":
            panel((x - w / 2, -0.02, -HALF), (x + w / 2, bh - rh + 0.01, HALF))
        else:
            c = pivot + rot @ np.array([x, (bh - rh) / 2, 0.0])
            b.cylinder(c, HALF + 0.002, (bh - rh) / 2 + 0.02, rot)


def _arms(b: CSGBuilder, p: ChairParams, top: float) -> None:
    if p.arms == "none":
        return
    b.part("arms")
    sw, sd = p.seat_w, p.seat_d
    at = p.arm_t
    y = top + p.arm_h
    z1 = sd / 2 - 0.02
    z0 = z1 - p.arm_len * sd
    for s in (-1, 1):
        x0, x1 = sorted((s * (sw / 2 - 0.03), s * (sw / 2 - 0.03 + at)))
        if p.arms == "panel":  # solid sides from the base up
            y_lo = 0.0 if p.base == "block" else p.seat_h
            b.box_between((x0, y_lo, z0), (x1, y, z1), rounding=min(0.03, at / 2 - 0.001))
        else:  # an armrest on a front post
            b.box_between((x0, y - MIN_PART, z0), (x1, y, z1 + 0.03), rounding=0.015)
            if p.seat == "round":  # where the seat is widest
                pz = 0.0
            elif p.seat == "rounded":
                pz = max(z0 + 0.05, -sd / 2 + sw / 2)
            else:
                pz = max(z0 + 0.05, -sd / 2 + HALF + 0.01)
            xp = s * (sw / 2 - 0.03 + HALF)
            b.box_between((xp - HALF, p.seat_h + 0.01, pz - HALF), (xp + HALF, y, pz + HALF))


def build(p: ChairParams) -> CSGShape:
    b = CSGBuilder()
    if p.back == "shell":  # its cuts come first, so that they cut nothing else
        _back(b, p, p.seat_h + p.seat_t + p.cushion_t)
    top = _seat(b, p)
    _base(b, p)
    if p.back != "shell":
        _back(b, p, top)
    _arms(b, p, top)
    return b.shape()
