"""The procedural table, in six styles: "legs" (four legs: square, round, tapered or splayed, with an
optional apron, drawer and H, box or X stretchers), "lower_shelf" (the same with one or two shelves
below the top), "pedestal" (one or two columns, cylindrical, tapered, flared or waisted, on a disc,
cone, plinth or three to five feet), "splayed" (three to five legs leaning outwards under a round,
oval or octagonal top, optional ring or shelf), "trestle" (a long top on two end frames: post and
foot, solid panels, X frames or closed sled loops, with zero to two stretchers) and "desk" (one or two
drawer pedestals, legs or a panel at the other end, an optional modesty panel). Drawn from wide
ranges: the top's outline (rectangular, chamfered, rounded, round, oval), depth / width 0.35-1,
height / width 0.25-1.2 (coffee to bar tables), top thickness 0.055-0.12, leg thickness 0.055-0.13
and inset, apron height and sides, stretcher height, shelf heights and thicknesses.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import bar, uniform, chance, X, Y, Z

STYLES = ("legs", "lower_shelf", "pedestal", "splayed", "trestle", "desk")
TOPS = ("rect", "chamfer", "rounded", "round", "oval")
LEGS = ("square", "round", "tapered", "splayed")
STRETCHERS = ("none", "H", "box", "X", "side")
COLUMNS = ("cylinder", "taper", "flare", "waist")
PEDESTAL_BASES = ("disc", "cone", "plinth", "feet")
ENDS = ("trestle", "panel", "x_frame", "sled")
T = 0.055  # the thinnest part (blocks.MIN_PART)


@dataclass(frozen=True)
class TableParams:
    """One table. Lengths are raw units (the longest side about 1); x is the width, z the depth."""

    style: str
    top: str               # TOPS
    width: float
    depth: float
    height: float          # floor to the top's upper face
    top_thick: float
    corner: float          # chamfer / rounding of the outline, a fraction of the half diagonal
    edge: float            # rounding of the top's edges
    leg: str               # LEGS (legs, lower_shelf, desk)
    leg_thick: float
    inset: float           # legs in from the top's edge
    splay: float           # how far a foot leans out
    legs_n: int            # splayed style: 3-5
    apron: float           # apron height, 0 for none
    apron_sides: int       # 2 (long sides) or 4
    drawer: bool           # a drawer front in the apron (legs style)
    stretcher: str         # STRETCHERS; "ring" / "shelf" for the splayed style
    stretcher_y: float     # fraction of the leg height
    bar_thick: float       # stretchers, aprons, shelves' rails
    shelves: int           # lower_shelf: 1-2; splayed: 0-1
    shelf_y: float         # fraction of the leg height of the lowest shelf
    shelf_thick: float
    column: str            # COLUMNS (pedestal)
    columns: int           # 1 or 2 (pedestal)
    column_r: float
    base: str              # PEDESTAL_BASES, ENDS, or the desk's other end ("legs" / "panel")
    base_size: float       # radius / half length of a pedestal's base; a trestle end's foot depth
    base_thick: float
    feet_n: int            # pedestal feet: 3-5
    angle: float           # a rotation of the feet / legs about y
    end_inset: float       # trestle ends / desk pedestal in from the top's short edges
    drawers: int           # desk: drawers per pedestal
    pedestals: int         # desk: 1 or 2
    side: int              # desk: the pedestal's side, -1 or 1
    ped_width: float       # desk: pedestal width
    modesty: float         # desk / trestle: the back panel's height fraction, 0 for none
    cutout: float          # panel ends: the arch cut out of the panel, a fraction of its height


def _top_shape(rng: np.random.Generator, style: str) -> str:
    if style == "splayed":
        return ("round", "oval", "chamfer")[int(rng.choice(3, p=[0.55, 0.25, 0.2]))]
    if style == "pedestal":
        return ("round", "rect", "chamfer", "rounded", "oval")[int(rng.choice(5, p=[0.4, 0.15, 0.15, 0.15, 0.15]))]
    if style == "trestle":
        return ("rect", "rect", "rounded", "chamfer")[int(rng.integers(4))]
    if style == "desk":
        return "rect"
    return ("rect", "chamfer", "rounded", "round", "oval")[int(rng.choice(5, p=[0.45, 0.15, 0.2, 0.08, 0.12]))]


def sample(rng: np.random.Generator, style: str) -> TableParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    top = _top_shape(rng, style)
    # proportions: depth/width and height/width ratios, the longest side scaled to 1 below
    lo_d = {"trestle": 0.35, "desk": 0.4}.get(style, 0.45)
    hi_d = {"trestle": 0.7, "desk": 0.75}.get(style, 1.0)
    d_ratio = 1.0 if top == "round" else uniform(rng, lo_d, hi_d)
    if top == "oval":
        d_ratio = uniform(rng, 0.45, 0.8)
    h_lo, h_hi = {"legs": (0.25, 1.2), "lower_shelf": (0.3, 1.2), "pedestal": (0.45, 1.15),
                  "splayed": (0.4, 1.2), "trestle": (0.3, 0.85), "desk": (0.5, 0.95)}[style]
    h_ratio = math.exp(uniform(rng, math.log(h_lo), math.log(h_hi)))
    s = 1.0 / max(1.0, h_ratio)
    width, depth, height = s, s * d_ratio, s * h_ratio
    top_thick = uniform(rng, T, 0.12) if chance(rng, 0.4) else uniform(rng, T, 0.08)
    leg = ("square", "round", "tapered", "splayed")[int(rng.choice(4, p=[0.35, 0.2, 0.25, 0.2]))]
    leg_thick = uniform(rng, T, 0.13) if leg != "tapered" else uniform(rng, 0.07, 0.13)
    apron = uniform(rng, 0.05, 0.16) if chance(rng, 0.5) else 0.0
    stretcher = str(rng.choice(STRETCHERS, p=[0.35, 0.2, 0.2, 0.1, 0.15]))
    if style == "splayed":
        stretcher = ("none", "ring", "shelf", "cross")[int(rng.choice(4, p=[0.4, 0.25, 0.2, 0.15]))]
    shelves = int(rng.choice([1, 2], p=[0.7, 0.3])) if style == "lower_shelf" else 0
    base = {"pedestal": str(rng.choice(PEDESTAL_BASES)), "trestle": str(rng.choice(ENDS)),
            "desk": ("legs", "panel")[int(rng.integers(2))]}.get(style, "none")
    columns = 2 if style == "pedestal" and d_ratio < 0.7 and top != "round" and chance(rng, 0.6) else 1
    return TableParams(
        style=style, top=top, width=width, depth=depth, height=height, top_thick=top_thick,
        corner=uniform(rng, 0.12, 0.4), edge=uniform(rng, 0.0, 0.025), leg=leg, leg_thick=leg_thick,
        inset=uniform(rng, 0.0, 0.12), splay=uniform(rng, 0.03, 0.12), legs_n=int(rng.integers(3, 6)),
        apron=apron, apron_sides=int(rng.choice([2, 4], p=[0.3, 0.7])), drawer=chance(rng, 0.3),
        stretcher=stretcher, stretcher_y=uniform(rng, 0.1, 0.5), bar_thick=uniform(rng, T, 0.075),
        shelves=shelves, shelf_y=uniform(rng, 0.08, 0.35), shelf_thick=uniform(rng, T, 0.09),
        column=str(rng.choice(COLUMNS)), columns=columns, column_r=uniform(rng, 0.05, 0.11),
        base=base, base_size=uniform(rng, 0.5, 1.0), base_thick=uniform(rng, T, 0.09),
        feet_n=int(rng.integers(3, 6)), angle=uniform(rng, 0.0, 2 * math.pi),
        end_inset=uniform(rng, 0.02, 0.18), drawers=int(rng.integers(1, 5)), pedestals=int(rng.choice([1, 2], p=[0.7, 0.3])),
        side=int(rng.choice([-1, 1])), ped_width=uniform(rng, 0.22, 0.4), modesty=uniform(rng, 0.25, 0.6) if chance(rng, 0.5) else 0.0,
        cutout=uniform(rng, 0.3, 0.7) if chance(rng, 0.5) else 0.0,
    )


# ------------------------------------------------------------------------------------ parts


def _inside_top(p: TableParams, x: float, z: float) -> bool:
    """Whether (x, z) lies under the top's outline."""
    hw, hd = p.width / 2, p.depth / 2
    x, z = abs(x), abs(z)
    if x > hw or z > hd:
        return False
    if p.top == "round":
        return math.hypot(x, z) <= hw
    if p.top == "oval":
        return x <= hw - hd or math.hypot(x - (hw - hd), z) <= hd
    if p.top == "chamfer":
        return x + z <= hw + hd - 2 * p.corner * min(hw, hd)
    if p.top == "rounded":
        return math.hypot(x, z) <= math.hypot(hw, hd) * (1 - 0.35 * p.corner)
    return True


def _under_top(p: TableParams, x: float, z: float, margin: float) -> tuple[float, float]:
    """(x, z) moved towards the centre until a square of half side ``margin`` around it lies
    under the top's outline."""
    for _ in range(60):
        if _inside_top(p, abs(x) + margin, abs(z) + margin):
            break
        x, z = 0.96 * x, 0.96 * z
    return x, z


def _top(b: CSGBuilder, p: TableParams) -> None:
    """The top: its upper face at y = height. Built first: the chamfer / rounding intersection
    clips only what is built before it (the top and an apron)."""
    hw, hd, tt = p.width / 2, p.depth / 2, p.top_thick
    yc = p.height - tt / 2
    b.part("top")
    if p.top == "round":
        b.cylinder((0, yc, 0), hw, tt / 2)
    elif p.top == "oval":  # a stadium: a box between two half discs
        r = hd
        b.box((0, yc, 0), (hw - r, tt / 2, r))
        for x in (-(hw - r), hw - r):
            b.cylinder((x, yc, 0), r, tt / 2)
    else:
        b.box((0, yc, 0), (hw, tt / 2, hd), rounding=p.edge)
        # the outline's corners: an intersection reaching down to the floor, so that it trims an
        # apron built before the top as well
        y_mid, y_half = p.height / 2, p.height / 2 + 0.01
        if p.top == "chamfer":  # a square turned 45 degrees: an octagon
            half = (hw + hd - 2 * p.corner * min(hw, hd)) / math.sqrt(2)
            b.box((0, y_mid, 0), (half, y_half, half), rotation(Y, math.pi / 4), op="intersect")
        elif p.top == "rounded":  # a disc: corners rounded with a large radius
            b.cylinder((0, y_mid, 0), math.hypot(hw, hd) * (1 - 0.35 * p.corner), y_half, op="intersect")


def _leg_positions(p: TableParams) -> list[tuple[float, float]]:
    """Four leg centres inside the top's outline."""
    hw, hd, t = p.width / 2, p.depth / 2, p.leg_thick
    lx, lz = _under_top(p, hw - t / 2 - p.inset * hw, hd - t / 2 - p.inset * hd, t / 2 + 0.01)
    return [(x, z) for x in (-lx, lx) for z in (-lz, lz)]


def _leg(b: CSGBuilder, p: TableParams, x: float, z: float, top: float, kind: str | None = None) -> None:
    """One leg from the floor up into the underside (at y = top) at (x, z)."""
    t = p.leg_thick
    kind = kind or p.leg
    if kind == "square":
        b.box((x, top / 2, z), (t / 2, top / 2 + 0.005, t / 2))
    elif kind == "round":
        b.cylinder((x, top / 2, z), t / 2, top / 2 + 0.005)
    elif kind == "tapered":
        b.cone((x, top / 2, z), top / 2 + 0.005, max(T / 2, 0.45 * t), t / 2)
    else:  # splayed: leaning out from the centre
        r = math.hypot(x, z) or 1.0
        foot = (x + p.splay * x / r, 0.0, z + p.splay * z / r)
        bar(b, (foot[0], t / 4, foot[2]), (x, top + 0.005, z), t, t, Z if abs(x) < abs(z) else X)


def _apron(b: CSGBuilder, p: TableParams, legs: list[tuple[float, float]], under: float) -> None:
    """A rectangular apron joining the legs' tops, one box per side (its outer face flush with the
    legs' outer faces)."""
    lx, lz = abs(legs[-1][0]), abs(legs[-1][1])
    t, at, y0 = p.leg_thick, max(T, 0.6 * p.bar_thick), under - p.apron
    o = t / 2 - at / 2
    b.part("apron")
    for z in (-(lz + o), lz + o):
        b.box_between((-lx, y0, z - at / 2), (lx, under + 0.005, z + at / 2))
    if p.apron_sides == 4:
        for x in (-(lx + o), lx + o):
            b.box_between((x - at / 2, y0, -lz), (x + at / 2, under + 0.005, lz))


def _stretchers(b: CSGBuilder, p: TableParams, legs: list[tuple[float, float]], under: float) -> None:
    lx, lz = abs(legs[-1][0]), abs(legs[-1][1])
    t = p.bar_thick
    y = max(0.06, p.stretcher_y * under)
    if p.leg == "splayed":  # the legs' centres at height y
        r = math.hypot(lx, lz)
        f = 1 + p.splay / r * (1 - y / under)
        lx, lz = lx * f, lz * f
    b.part("stretchers")
    if p.stretcher in ("H", "side", "box"):
        for x in (-lx, lx):
            b.box_between((x - t / 2, y - t / 2, -lz), (x + t / 2, y + t / 2, lz))
    if p.stretcher == "H":
        b.box_between((-lx, y - t / 2 + 0.01, -t / 2), (lx, y + t / 2 + 0.01, t / 2))
    if p.stretcher == "box":
        for z in (-lz, lz):
            b.box_between((-lx, y - t / 2 + 0.012, z - t / 2), (lx, y + t / 2 + 0.012, z + t / 2))
    if p.stretcher == "X":
        for s in (-1, 1):
            bar(b, (-lx, y, -s * lz), (lx, y, s * lz), t, t, Y)


def _shelf(b: CSGBuilder, p: TableParams, legs: list[tuple[float, float]], y: float) -> None:
    lx, lz = abs(legs[-1][0]), abs(legs[-1][1])
    if p.leg == "splayed":
        r = math.hypot(lx, lz)
        f = 1 + p.splay / r * (1 - y / p.height)
        lx, lz = lx * f, lz * f
    o = p.leg_thick / 2
    b.part("shelf")
    b.box((0, y, 0), (lx + o, p.shelf_thick / 2, lz + o))


# ------------------------------------------------------------------------------------ styles


def _four_legs(b: CSGBuilder, p: TableParams) -> None:
    under = p.height - p.top_thick
    legs = _leg_positions(p)
    apron = p.apron > 0
    if apron:  # before the top, so the top's intersection trims the apron's corners too
        _apron(b, p, legs, under)
        if p.drawer and p.apron >= 0.08:  # a drawer front: a shallow recess in the front apron
            lz = abs(legs[-1][1])
            b.part("drawer")
            b.box((0, under - p.apron / 2, -(lz + p.leg_thick / 2)), (0.3 * abs(legs[-1][0]), p.apron * 0.32, 0.012),
                  op="subtract")
    _top(b, p)
    b.part("legs")
    for x, z in legs:
        _leg(b, p, x, z, under)
    if p.style == "lower_shelf":
        ys = [p.shelf_y * under + p.shelf_thick / 2]
        if p.shelves == 2:
            ys.append((ys[0] + under - (p.apron if apron else 0)) / 2)
        for y in ys:
            _shelf(b, p, legs, y)
    elif p.stretcher != "none":
        _stretchers(b, p, legs, under)


def _pedestal(b: CSGBuilder, p: TableParams) -> None:
    under = p.height - p.top_thick
    _top(b, p)
    hw = p.width / 2
    xs = [0.0] if p.columns == 1 else [-(hw * 0.5), hw * 0.5]
    r = p.column_r * (0.75 if p.columns == 2 else 1.0)
    bt = p.base_thick
    # the base reaches towards the top's edge: a fraction of the smaller half extent
    reach = max(2 * r + 0.05, p.base_size * 0.9 * min(p.depth / 2, hw / (2 if p.columns == 2 else 1)))
    for x in xs:
        b.part("column")
        y0, y1 = bt * 0.5, under + 0.005
        h = (y1 - y0) / 2
        if p.column == "cylinder":
            b.cylinder((x, y0 + h, 0), r, h)
        elif p.column == "taper":
            b.cone((x, y0 + h, 0), h, r * 1.4, max(0.04, r * 0.75))
        elif p.column == "flare":
            b.cone((x, y0 + h, 0), h, max(0.04, r * 0.7), r * 1.4)
        else:  # waisted: two cones meeting in the middle
            b.cone((x, y0 + h / 2, 0), h / 2, r * 1.4, max(0.04, r * 0.7))
            b.cone((x, y0 + 1.5 * h, 0), h / 2, max(0.04, r * 0.7), r * 1.4)
        b.part("base")
        if p.base == "disc":
            b.cylinder((x, bt / 2, 0), reach, bt / 2)
        elif p.base == "cone":
            hc = max(bt, (0.1 + 0.25 * p.base_size) * under)
            b.cone((x, hc / 2, 0), hc / 2, reach, r)
        elif p.base == "plinth":
            b.box((x, bt / 2, 0), (reach * 0.85, bt / 2, reach * 0.85), rotation(Y, p.angle) if p.columns == 1 else None)
        else:  # feet radiating from the column, sloping down to the floor
            n = p.feet_n if p.columns == 1 else 2
            a0 = p.angle if p.columns == 1 else 0.0
            for k in range(n):
                a = a0 + 2 * math.pi * k / n
                if p.columns == 2:
                    a = math.pi / 2 + math.pi * k
                d = np.array([math.cos(a), 0.0, math.sin(a)])
                foot = np.array([x, bt / 2, 0.0]) + reach * d
                bar(b, (x, bt * 1.5 + 0.03, 0), foot, bt, 0.06 + 0.03 * p.base_size, Y)
    if p.columns == 2 and p.stretcher != "none":
        b.part("stretchers")
        t = p.bar_thick
        y = max(bt + t, p.stretcher_y * under)
        b.box_between((-hw * 0.5, y - t / 2, -t / 2), (hw * 0.5, y + t / 2, t / 2))


def _splayed(b: CSGBuilder, p: TableParams) -> None:
    under = p.height - p.top_thick
    _top(b, p)
    hw, hd = p.width / 2, p.depth / 2
    n = p.legs_n if p.top != "oval" else 4
    t = p.leg_thick
    k = 0.55 + 0.3 * p.inset / 0.12  # the legs' tops, a fraction of the outline's radius
    spread = 1 + p.splay * 2.5  # feet further out than the tops
    tops, feet = [], []
    for j in range(n):
        a = p.angle + 2 * math.pi * j / n
        c, s = math.cos(a), math.sin(a)
        tops.append(np.array([k * (hw - t) * c, under + 0.005, k * (hd - t) * s]))
        feet.append(np.array([min(k * spread, 0.95) * (hw - t / 2) * c, 0.0, min(k * spread, 0.95) * (hd - t / 2) * s]))
    b.part("legs")
    for a, f in zip(tops, feet):
        if p.leg in ("square", "splayed"):
            bar(b, f + np.array([0, t / 4, 0]), a, t, t, X)
        else:
            b.rod(f, a, t / 2)
    y = max(0.07, p.stretcher_y * 0.7 * under)
    f = y / under
    ring = [fe + (a - fe) * f for a, fe in zip(tops, feet)]  # the legs' centres at height y
    if p.stretcher == "ring" and p.top != "oval":
        b.part("stretchers")
        rr = float(np.mean([math.hypot(q[0], q[2]) for q in ring]))
        b.torus((0, y, 0), rr, max(T / 2, 0.45 * p.bar_thick))
    elif p.stretcher == "shelf":
        b.part("shelf")
        rr = float(max(math.hypot(q[0], q[2]) for q in ring))
        if p.top == "round":
            b.cylinder((0, y, 0), rr + t / 2, p.shelf_thick / 2)
        else:
            xs, zs = max(abs(q[0]) for q in ring), max(abs(q[2]) for q in ring)
            b.box((0, y, 0), (xs + t / 2, p.shelf_thick / 2, zs + t / 2))
    elif p.stretcher in ("cross", "ring"):
        b.part("stretchers")
        for j in range(n):
            a, c = ring[j], ring[(j + n // 2) % n] if n % 2 == 0 else np.array([0, y, 0])
            bar(b, a, c, p.bar_thick, p.bar_thick, Y)


def _trestle(b: CSGBuilder, p: TableParams) -> None:
    under = p.height - p.top_thick
    hw, hd = p.width / 2, p.depth / 2
    _top(b, p)
    t = p.leg_thick
    # the end frames: in from the short edges, their depth a fraction of the top's
    px, fz = _under_top(p, hw * (1 - p.end_inset) - t / 2, hd * (0.55 + 0.4 * p.base_size), t / 2 + 0.01)
    bt = p.base_thick
    b.part("ends")
    for x in (-px, px):
        if p.base == "trestle":  # a post on a foot, a cleat under the top
            b.box((x, under / 2, 0), (t / 2, under / 2, max(t / 2, 0.03 + 0.08 * p.corner)))
            b.box((x, bt / 2, 0), (t / 2 + 0.008, bt / 2, fz), rounding=0.01)
            b.box((x, under - bt / 2, 0), (t / 2, bt / 2, fz * 0.95))
        elif p.base == "panel":
            b.box((x, under / 2, 0), (t / 2, under / 2 + 0.005, fz))
        elif p.base == "x_frame":
            for s in (-1, 1):
                bar(b, (x, bt * 0.3, -s * (fz - bt / 2)), (x, under + 0.003, s * (fz - bt / 2)), bt, t, X)
        else:  # sled: a closed loop of two posts, a foot rail and a top rail
            for z in (-(fz - bt / 2), fz - bt / 2):
                b.box((x, under / 2, z), (t / 2, under / 2, bt / 2))
            b.box((x, bt / 2, 0), (t / 2, bt / 2, fz))
            b.box((x, under - bt / 2, 0), (t / 2, bt / 2, fz))
    if p.base == "panel" and p.cutout > 0:  # an arch cut out of each panel (before the stretcher)
        b.part("ends")
        for x in (-px, px):
            hc = p.cutout * under * 0.8
            b.box((x, hc / 2 - 0.01, 0), (t, hc / 2, fz - max(T, 0.3 * fz)), op="subtract")
    if p.stretcher != "none" or p.base in ("trestle", "x_frame"):
        b.part("stretchers")
        st = p.bar_thick
        y = max(bt + st, p.stretcher_y * under) if p.base != "x_frame" else under * 0.5
        if p.base == "x_frame":
            y = min(y, under * (0.5 - 0.1 * p.stretcher_y))
        zs = [0.0] if p.stretcher in ("none", "H", "X") or p.base in ("trestle", "x_frame") else [-(fz - st), fz - st]
        for z in zs:
            b.box_between((-px, y - st / 2, z - st / 2), (px, y + st / 2, z + st / 2))
    if p.modesty > 0 and p.base in ("panel", "sled"):
        b.part("panel")
        y0 = under * (1 - p.modesty)
        b.box_between((-px, y0, fz * 0.6 - T / 2), (px, under + 0.005, fz * 0.6 + T / 2))


def _desk(b: CSGBuilder, p: TableParams) -> None:
    under = p.height - p.top_thick
    hw, hd = p.width / 2, p.depth / 2
    pw = p.ped_width * p.width
    edge = hw - p.end_inset * 0.3 * hw
    pd = hd * 0.95
    sides = [p.side] if p.pedestals == 1 else [-1, 1]
    b.part("pedestal")
    for s in sides:
        xc = s * (edge - pw / 2)
        b.box((xc, under / 2, 0), (pw / 2, under / 2 + 0.005, pd))
    b.part("drawers")
    n = p.drawers
    gap = 0.03
    hdw = (under - 0.04 - gap * (n + 1)) / n
    for s in sides:
        xc = s * (edge - pw / 2)
        for k in range(n):
            y = 0.04 + gap + hdw / 2 + k * (hdw + gap)
            b.box((xc, y, -pd), (pw / 2 - 0.035, hdw / 2, 0.015), op="subtract")
    _top(b, p)
    if p.pedestals == 1:
        x = -p.side * (edge - p.leg_thick / 2)
        if p.base == "legs":
            b.part("legs")
            lz = hd - p.leg_thick / 2 - p.inset * hd * 0.5
            for z in (-lz, lz):
                _leg(b, p, x, z, under, "square" if p.leg == "splayed" else p.leg)
        else:
            b.part("panel")
            b.box((x, under / 2, 0), (p.leg_thick / 2, under / 2 + 0.005, pd))
    if p.modesty > 0:
        b.part("panel")
        x0 = -edge + (pw if -1 in sides else p.leg_thick)
        x1 = edge - (pw if 1 in sides else p.leg_thick)
        y0 = under * (1 - p.modesty)
        b.box_between((x0 - 0.01, y0, hd * 0.55 - T / 2), (x1 + 0.01, under + 0.005, hd * 0.55 + T / 2))


def build(p: TableParams) -> CSGShape:
    b = CSGBuilder()
    {"legs": _four_legs, "lower_shelf": _four_legs, "pedestal": _pedestal, "splayed": _splayed,
     "trestle": _trestle, "desk": _desk}[p.style](b, p)
    return b.shape()
