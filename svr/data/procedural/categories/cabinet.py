"""The procedural cabinet: a carcass with its front to -z whose front is a stack of tiers, each a row
of cells (doors of one or two leaves, a door standing open by 20-110 degrees, drawers, a drawer pulled
out 15-70% of the depth as an open box, or open compartments reaching 30-100% of the way to a back
panel or, with an open back, through it), on a plinth, legs (square, round or tapered), bun feet,
side gables or nothing, under an optional overhanging top and cornice. Styles: "doors" (cupboards and
wardrobes, height/width 0.7-2.4, maybe a drawer row or an open niche), "open_shelves" (bookcases and
cubbies, height/width 0.3-3, 1-6 shelf rows of 1-4 compartments, maybe doors below), "drawers"
(chests and filing cabinets, 2-6 drawer rows of 1-3), "sideboard" (height/width 0.3-0.65, doors,
drawers and open bays side by side), "hutch" (a lower cabinet and a shallower upper unit on its
counter: a stepped profile) and "nightstand" (small, drawers over an open niche). Depth/width
0.2-1.2, panels 0.055-0.13 thick, the front set back up to 45% of the depth in two thirds of them, bases
0-40% of the height, overhangs 0-0.06; every draw is in ``sample``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, chance, frame, Y

STYLES = ("doors", "open_shelves", "drawers", "sideboard", "hutch", "nightstand")
CELL_KINDS = ("door", "doors", "drawer", "open", "ajar", "pulled")
# "doors": a pair of leaves in one cell; "ajar": a door swung open; "pulled": a drawer pulled out
BASES = ("plinth", "legs", "feet", "gables", "none")
LEG_SHAPES = ("square", "round", "tapered")
HANDLES = ("knob", "bar", "none")
# the chance that a closed cell of a style is an open compartment instead
P_OPEN = {"doors": 0.45, "drawers": 0.35, "sideboard": 0.5, "hutch": 0.5, "nightstand": 0.45}
P_AJAR = 0.45  # the chance that a door cell left closed stands open
P_PULLED = 0.45  # the chance that a drawer left closed is pulled out


@dataclass(frozen=True)
class Tier:
    """One row of a unit's front: its share of the unit's inner height and its cells (kind, share of
    the width) from left to right."""

    height: float
    cells: tuple[tuple[str, float], ...]
    depth: float = 1.0  # open cells reach this share of the way from the front to the back panel


@dataclass(frozen=True)
class Section:
    """One of a unit's side-by-side sections: its share of the width and its tiers, bottom to top."""

    width: float
    tiers: tuple[Tier, ...]


@dataclass(frozen=True)
class CabinetParams:
    style: str
    width: float            # the carcass (x), raw units
    depth: float            # the lower unit (z)
    body_height: float      # the lower unit's carcass (y), above the base
    sections: tuple[Section, ...]  # the lower unit's front, left to right
    panel: float            # carcass, shelf and divider thickness
    back: float             # back panel behind open cells; 0: open back (through-holes)
    front_recess: float     # the front set back inside the carcass's edges; 0: flush
    shelf_inset: float      # open cells' shelves and dividers set back from the front
    margin: float           # door and drawer fronts: recess inset from the cell (gap or frame)
    handle: str
    handle_size: float      # knob radius or bar length
    handle_height: float    # doors: the handle's height within the door, 0 (bottom) to 1 (top)
    base: str
    base_height: float
    leg_thick: float
    leg_shape: str
    leg_inset: float
    undershelf: float       # legs: a shelf between them at this fraction of their height; 0: none
    plinth_inset: float     # plinth set back from the front and sides
    top_thick: float        # 0: no separate top
    top_overhang: float
    upper_height: float     # hutch: the upper unit on the counter; 0: none
    upper_depth: float
    upper_width: float
    upper_sections: tuple[Section, ...]
    cornice: float          # a slab on the very top, overhanging by this; 0: none
    door_angle: float       # "ajar" cells: the leaf's swing out of the front, radians
    pull: float             # "pulled" cells: the drawer's box out of the front, share of the carcass depth
    drawer_wall: float      # "pulled" cells: the drawer box's walls


# ---------------------------------------------------------------------------------------------
# sampling


def _shares(rng: np.random.Generator, n: int, jitter: float) -> tuple[float, ...]:
    """n shares summing to 1, each within a factor (1 +- jitter) of the even share."""
    s = np.array([1.0 + uniform(rng, -jitter, jitter) for _ in range(n)])
    return tuple(float(x) for x in s / s.sum())


def _tier(rng: np.random.Generator, kinds, height: float, jitter: float = 0.25) -> Tier:
    depth = 1.0 if chance(rng, 0.35) else uniform(rng, 0.3, 1.0)
    return Tier(height, tuple(zip(kinds, _shares(rng, len(kinds), jitter))), depth)


def _stack(rng: np.random.Generator, tiers: list[tuple[list[str], float]], height: float, width: float,
           panel: float) -> tuple[Tier, ...]:
    """Tiers from (cell kinds, relative height) pairs, heights normalised to shares; tiers and cells
    that would leave a cell under 0.07 high or 0.1 wide are dropped."""
    tiers = list(tiers)
    while len(tiers) > 1 and (len(tiers) + 1) * panel + len(tiers) * 0.07 > height:
        tiers.pop(len(tiers) // 2)
    tiers = [(kinds[:max(1, int((width - panel) // (panel + 0.1)))], h) for kinds, h in tiers]
    total = sum(h for _, h in tiers)
    return tuple(_tier(rng, kinds, h / total) for kinds, h in tiers)


def _shelves(rng: np.random.Generator, height: float, width: float, kind: str = "open") -> list:
    """Open compartments: rows and columns from drawn spacings."""
    rows = int(np.clip(round(height / uniform(rng, 0.16, 0.42)), 1, 6))
    cols = int(np.clip(round(width / uniform(rng, 0.22, 0.6)), 1, 4))
    while rows * cols > 12:
        cols -= 1
    return [([kind] * cols, uniform(rng, 0.7, 1.3)) for _ in range(rows)]


def _closed(rng: np.random.Generator, width: float) -> list[str]:
    """A row of door cells across a width (wide cells get a pair of leaves)."""
    n = int(np.clip(round(width / uniform(rng, 0.3, 0.65)), 1, 4))
    if n == 1 and width > 0.45 and chance(rng, 0.6):
        return ["doors"]
    return ["door"] * n


def _drawer_rows(rng: np.random.Generator, width: float, most: int = 6) -> list:
    """A chest's drawers: 2..most rows, the top ones maybe split into 2-3 side by side."""
    n = int(rng.integers(2, most + 1))
    cols = int(rng.choice([1, 2, 3] if width > 0.6 else [1, 2]))
    split = int(rng.integers(0, n + 1)) if cols > 1 else 0
    return [(["drawer"] * (cols if k >= n - split else 1), uniform(rng, 0.8, 1.3)) for k in range(n)]


def _open_some(rng: np.random.Generator, rows: list, p: float) -> list:
    """Each closed cell becomes an open compartment with probability p, a door left so maybe ajar."""
    def one(kind: str) -> str:
        if chance(rng, p):
            return "open"
        if kind == "drawer" and chance(rng, P_PULLED):
            return "pulled"
        return "ajar" if kind == "door" and chance(rng, P_AJAR) else kind
    return [([one(kind) for kind in kinds], h) for kinds, h in rows]


def _bay(rng: np.random.Generator, kind: str, height: float, width: float) -> list:
    """The rows of one side-by-side section of a unit: "doors", "drawers", "shelves"."""
    if kind == "doors":
        return [(_closed(rng, width), 1.0)]
    if kind == "drawers":
        return _drawer_rows(rng, width, 4)
    return _shelves(rng, height, width)


def _unit(rng: np.random.Generator, bays: list, height: float, width: float, panel: float,
          p_open: float) -> tuple[Section, ...]:
    """Sections from (share of the width, rows) pairs: shares normalised, some cells opened."""
    total = sum(share for share, _ in bays)
    out = []
    for share, rows in bays:
        w = share / total * width
        rows = _open_some(rng, rows, p_open) if p_open > 0 else rows
        out.append(Section(share / total, _stack(rng, rows, height, w, panel)))
    return tuple(out)


def sample(rng: np.random.Generator, style: str) -> CabinetParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    # proportions: height and depth relative to the width; the longest side is scaled to 1 below
    h_w, d_w = {
        "doors": (uniform(rng, 0.7, 2.4), uniform(rng, 0.28, 0.8)),
        "open_shelves": (float(np.exp(uniform(rng, np.log(0.3), np.log(3.0)))), uniform(rng, 0.2, 0.6)),
        "drawers": (uniform(rng, 0.45, 2.2), uniform(rng, 0.4, 1.1)),
        "sideboard": (uniform(rng, 0.3, 0.65), uniform(rng, 0.22, 0.5)),
        "hutch": (uniform(rng, 1.0, 2.2), uniform(rng, 0.3, 0.65)),
        "nightstand": (uniform(rng, 0.6, 1.6), uniform(rng, 0.5, 1.2)),
    }[style]
    base = str(rng.choice(BASES, p={
        "doors": (0.3, 0.35, 0.15, 0.1, 0.1), "open_shelves": (0.25, 0.15, 0.05, 0.3, 0.25),
        "drawers": (0.25, 0.4, 0.2, 0.05, 0.1), "sideboard": (0.2, 0.55, 0.1, 0.1, 0.05),
        "hutch": (0.5, 0.2, 0.15, 0.1, 0.05), "nightstand": (0.15, 0.6, 0.1, 0.1, 0.05)}[style]))
    base_frac = {"plinth": uniform(rng, 0.03, 0.12), "legs": uniform(rng, 0.08, 0.4),
                 "feet": uniform(rng, 0.04, 0.1), "gables": uniform(rng, 0.03, 0.15), "none": 0.0}[base]
    if style == "hutch":
        base_frac *= 0.5
    top = chance(rng, {"open_shelves": 0.2, "hutch": 1.0}.get(style, 0.55))
    s = 1.0 / max(1.0, h_w, d_w)  # raw scale: the longest side is 1
    width, height, depth = s, h_w * s, d_w * s
    base_height = max(base_frac * height, 0.055) if base != "none" else 0.0
    panel = min(uniform(rng, 0.055, 0.13), max(0.055, 0.12 * min(width, height)))
    top_thick = uniform(rng, 0.055, 0.09) if top else 0.0
    overhang = uniform(rng, 0.0, 0.06) if top else 0.0
    cornice = uniform(rng, 0.02, 0.06) if style in ("doors", "hutch") and chance(rng, 0.3) else 0.0
    width -= 2 * overhang  # so the top's overhang stays inside the unit width
    depth -= overhang
    body = height - base_height - top_thick - (0.06 if cornice else 0.0)
    upper_h = upper_d = upper_w = 0.0
    upper: tuple[Section, ...] = ()
    if style == "hutch":
        upper_h = body * uniform(rng, 0.45, 0.65)
        body -= upper_h
        upper_d = depth * uniform(rng, 0.35, 0.7)
        upper_w = width * uniform(rng, 0.8, 1.0)
        kinds = ["shelves"] if chance(rng, 0.6) else ["shelves", "doors"] if chance(rng, 0.5) else ["doors"]
        if len(kinds) == 2 and chance(rng, 0.5):
            kinds = kinds + kinds[:1]
        upper = _unit(rng, [(uniform(rng, 0.6, 1.4), _bay(rng, k, upper_h, upper_w / len(kinds))) for k in kinds],
                      upper_h, upper_w, panel, 0.3)
    p_open = P_OPEN.get(style, 0.0)
    if style == "doors":
        rows = [(_closed(rng, width), 1.0)]
        if chance(rng, 0.4):
            drawers = ["drawer"] * int(rng.integers(1, 4))
            rows.insert(0 if chance(rng, 0.5) else 1, (drawers, uniform(rng, 0.12, 0.25)))
        if chance(rng, 0.25):
            rows.append((["open"], uniform(rng, 0.15, 0.35)))
        bays = [(1.0, rows)]
        if width > 0.45 and chance(rng, 0.35):  # a column of shelves or drawers beside the doors
            side = (uniform(rng, 0.3, 0.8), _bay(rng, str(rng.choice(["shelves", "drawers"])), body, 0.3 * width))
            bays.insert(int(rng.integers(0, 2)), side)
    elif style == "open_shelves":
        rows = _shelves(rng, body, width)
        if len(rows) > 1 and chance(rng, 0.3):  # closed doors at the bottom
            rows[0] = (_closed(rng, width), rows[0][1] * uniform(rng, 1.0, 2.0))
        bays = [(1.0, rows)]
        if width > 0.5 and chance(rng, 0.3):  # a second bay of other shelves or of doors
            side = (uniform(rng, 0.3, 0.9), _bay(rng, str(rng.choice(["shelves", "doors"])), body, 0.4 * width))
            bays.insert(int(rng.integers(0, 2)), side)
    elif style == "drawers":
        bays = [(1.0, _drawer_rows(rng, width))]
        if width > 0.5 and chance(rng, 0.3):  # a door or a second stack of drawers beside them
            side = (uniform(rng, 0.4, 1.0), _bay(rng, str(rng.choice(["doors", "drawers"])), body, 0.4 * width))
            bays.insert(int(rng.integers(0, 2)), side)
    elif style == "sideboard":
        n = int(rng.integers(1, 4)) if width > 0.5 else 1
        kinds = [str(rng.choice(["doors", "doors", "drawers", "shelves"])) for _ in range(n)]
        if n == 3 and chance(rng, 0.6):
            kinds[2] = kinds[0]  # symmetric
        bays = [(uniform(rng, 0.6, 1.4), _bay(rng, k, body, width / n)) for k in kinds]
        if n == 1 and chance(rng, 0.5):
            bays = [(1.0, [(_closed(rng, width), 1.0), (["drawer"] * int(rng.integers(2, 4)), uniform(rng, 0.2, 0.4))])]
    elif style == "hutch":
        n = int(rng.integers(1, 4)) if width > 0.5 else 1
        bays = [(uniform(rng, 0.6, 1.4), _bay(rng, str(rng.choice(["doors", "doors", "drawers"])), body, width / n))
                for _ in range(n)]
    else:  # nightstand
        rows = [(["drawer"], 1.0) for _ in range(int(rng.integers(1, 3)))]
        if chance(rng, 0.65):
            rows.insert(0 if chance(rng, 0.8) else len(rows), (["open"], uniform(rng, 0.8, 1.8)))
        bays = [(1.0, rows)]
    sections = _unit(rng, bays, body, width, panel, p_open)
    back = 0.0 if chance(rng, {"open_shelves": 0.45, "sideboard": 0.3}.get(style, 0.15)) else \
        uniform(rng, 0.055, max(0.07, 0.6 * depth))
    room = depth - back - 0.12  # a recessed front leaves open cells some depth
    front_recess = uniform(rng, 0.02, max(0.03, min(0.45 * depth, room))) if room > 0.05 and chance(rng, 0.65) else 0.0
    return CabinetParams(
        style=style, width=width, depth=depth, body_height=body, sections=sections, panel=panel,
        back=back, front_recess=front_recess,
        shelf_inset=uniform(rng, 0.0, 0.05) if chance(rng, 0.4) else 0.0,
        margin=uniform(rng, 0.012, 0.05), handle=str(rng.choice(HANDLES, p=(0.4, 0.45, 0.15))),
        handle_size=uniform(rng, 0.028, 0.04), handle_height=uniform(rng, 0.3, 0.8),
        base=base, base_height=base_height, leg_thick=uniform(rng, 0.055, 0.1),
        leg_shape=str(rng.choice(LEG_SHAPES)), undershelf=uniform(rng, 0.15, 0.5) if chance(rng, 0.35) else 0.0, leg_inset=uniform(rng, 0.0, 0.06),
        plinth_inset=uniform(rng, 0.0, 0.14), top_thick=top_thick, top_overhang=overhang,
        upper_height=upper_h, upper_depth=upper_d, upper_width=upper_w, upper_sections=upper,
        cornice=cornice, door_angle=uniform(rng, 0.35, 1.9),
        pull=uniform(rng, 0.15, 0.7), drawer_wall=uniform(rng, 0.055, 0.09))


# ---------------------------------------------------------------------------------------------
# construction


def _front(b: CSGBuilder, p: CabinetParams, tiers, x0: float, x1: float, y0: float, y1: float,
           z0: float, z1: float, handles: list) -> None:
    """Cuts a unit's front (the carcass box x0..x1, y0..y1, z0 (front)..z1): open cells as cavities,
    with shelves and dividers added back; closed cells as recessed fronts. Handles are collected to
    add after every cut."""
    t = p.panel
    zb = z1 + 0.05 if p.back == 0 else z1 - p.back
    iy0, iy1 = y0 + t, y1 - t
    inner = iy1 - iy0 - t * (len(tiers) - 1)
    ya = iy0
    spans = []  # (y from, y to, tier)
    for tier in tiers:
        spans.append((ya, ya + tier.height * inner, tier))
        ya += tier.height * inner + t
    # runs of tiers that are all open become one cavity with shelves and dividers added back
    k = 0
    while k < len(spans):
        if all(kind == "open" for kind, _ in spans[k][2].cells):
            j = k
            while j + 1 < len(spans) and all(kind == "open" for kind, _ in spans[j + 1][2].cells):
                j += 1
            b.part("body")
            b.box_between((x0 + t, spans[k][0], z0 - 0.05), (x1 - t, spans[j][1], zb), op="subtract")
            for m in range(k, j + 1):  # shallower tiers: their back filled in again
                zend = min(zb + 0.01, z1)
                zfill = min(z0 + spans[m][2].depth * (zb - z0), zend - 0.06)
                if spans[m][2].depth < 0.99 and zfill > z0 + 0.05:
                    b.box_between((x0 + t / 2, spans[m][0] - 0.01, zfill), (x1 - t / 2, spans[m][1] + 0.01, zend))
            b.part("shelves")
            zs0 = z0 + p.shelf_inset
            for m in range(k, j):
                b.box_between((x0 + t / 2, spans[m][1], zs0), (x1 - t / 2, spans[m + 1][0], z1 - 0.01))
            for m in range(k, j + 1):
                xa = x0 + t
                w = x1 - x0 - 2 * t - t * (len(spans[m][2].cells) - 1)
                for _, share in spans[m][2].cells[:-1]:
                    xa += share * w
                    b.box_between((xa, spans[m][0] - t / 2, zs0), (xa + t, spans[m][1] + t / 2, z1 - 0.01))
                    xa += t
            k = j + 1
            continue
        ya0, ya1, tier = spans[k]
        w = x1 - x0 - 2 * t - t * (len(tier.cells) - 1)
        xa = x0 + t
        for kind, share in tier.cells:
            xb = xa + share * w
            if kind in ("open", "ajar", "pulled"):
                b.part("body")
                zc = z0 + tier.depth * (zb - z0) if kind == "open" else zb if kind == "ajar" else z1 - 0.055
                zc = zb if kind == "open" and z1 - zc < 0.06 else zc  # no sliver of a back
                b.box_between((xa, ya0, z0 - 0.05), (xb, ya1, zc), op="subtract")
                if kind != "open":  # the leaf or the drawer's box, added after every cut
                    handles.append((kind, xa, xb, ya0, ya1, z1))
            else:
                _closed_cell(b, p, kind, xa - t / 2, xb + t / 2, ya0 - t / 2, ya1 + t / 2, z0, handles)
            xa = xb + t
        k += 1


def _unit_front(b: CSGBuilder, p: CabinetParams, sections, x0: float, x1: float, y0: float, y1: float,
                z0: float, z1: float, handles: list) -> None:
    """The sections side by side, sharing a panel between neighbours."""
    t = p.panel
    w = x1 - x0 + t * (len(sections) - 1)
    xa = x0
    for sec in sections:
        _front(b, p, sec.tiers, xa, xa + sec.width * w, y0, y1, z0, z1, handles)
        xa += sec.width * w - t


def _closed_cell(b: CSGBuilder, p: CabinetParams, kind: str, xa: float, xb: float, ya: float, yb: float,
                 z0: float, handles: list) -> None:
    """Recessed door or drawer fronts in the cell (including half the dividers around it)."""
    m = p.margin
    leaves = [(xa, xb)] if kind != "doors" else [(xa, (xa + xb) / 2), ((xa + xb) / 2, xb)]
    b.part("doors" if kind != "drawer" else "drawers")
    for n, (la, lb) in enumerate(leaves):
        b.box(((la + lb) / 2, (ya + yb) / 2, z0), ((lb - la) / 2 - m, (yb - ya) / 2 - m, 0.015), op="subtract")
        if p.handle == "none":
            continue
        if kind == "drawer":
            handles.append(("drawer", (la + lb) / 2, ya + (yb - ya) * 0.55, min(lb - la - 2 * m - 0.02, 0.3)))
        else:
            # on the leaf's free edge: the right edge of a left leaf, the left edge of a right leaf
            right = (kind == "doors" and n == 0) or (kind == "door" and (la + lb) / 2 < 0)
            x = lb - m - 0.045 if right else la + m + 0.045
            handles.append(("door", x, ya + (yb - ya) * p.handle_height, min(yb - ya - 2 * m - 0.02, 0.25)))


def _handles(b: CSGBuilder, p: CabinetParams, handles: list, z0: float) -> None:
    t = p.panel
    for _, xa, xb, ya, yb, zb in [h for h in handles if h[0] == "pulled"]:  # a drawer's open box, pulled out
        b.part("drawers")
        m, dw = p.margin, p.drawer_wall
        if xb - xa < 2 * dw + 0.06 or yb - ya < dw + 0.06:  # too small to hollow: a plain pulled box
            dw = 0.0
        zd0 = z0 - p.pull * (zb - z0)
        zd1 = min(zd0 + 0.85 * (zb - z0), zb - 0.06)
        x0, x1, yt = xa + 0.01, xb - 0.01, yb - min(m, 0.3 * (yb - ya))  # resting on the cell's floor
        b.box_between((x0, ya - 0.01, zd0), (x1, yt, zd1))
        if dw > 0:
            b.box_between((x0 + dw, ya - 0.01 + dw, zd0 + dw), (x1 - dw, yt + 0.005, zd1 - dw), op="subtract")
        if p.handle != "none":
            b.part("handles")
            b.box(((xa + xb) / 2, ya + 0.55 * (yb - ya), zd0 - 0.01), (max(0.3 * (xb - xa), 0.05), 0.0275, 0.04), rounding=0.01)
    for _, xa, xb, ya, yb, _ in [h for h in handles if h[0] == "ajar"]:  # doors swung open about a side
        b.part("doors")
        s = 1.0 if (xa + xb) / 2 < 0 else -1.0  # hinged on the side nearer the carcass's edge
        xh = xa - t / 2 if s > 0 else xb + t / 2
        a = p.door_angle
        along = np.array([s * np.cos(a), 0.0, -np.sin(a)])
        out = np.array([-s * np.sin(a), 0.0, -np.cos(a)])
        lw = xb - xa + t
        c = np.array([xh, (ya + yb) / 2, z0]) + along * (lw / 2 - 0.03) + out * t / 2
        b.box(c, ((lw + 0.06) / 2, (yb - ya + t) / 2 - p.margin, t / 2), frame(Y, along))
    handles = [h for h in handles if h[0] not in ("ajar", "pulled")]
    b.part("handles")
    r = p.handle_size
    for kind, x, y, room in handles:
        if p.handle == "knob":
            b.sphere((x, y, z0 - 0.01), r)
        elif kind == "drawer":
            b.box((x, y, z0 - 0.01), (max(0.6 * room, 0.1) / 2, 0.0275, 0.04), rounding=0.01)
        else:
            b.box((x, y, z0 - 0.01), (0.0275, max(0.6 * room, 0.1) / 2, 0.04), rounding=0.01)


def build(p: CabinetParams) -> CSGShape:
    b = CSGBuilder()
    w, d = p.width, p.depth
    y0 = p.base_height
    y1 = y0 + p.body_height
    zf, zb = -d / 2, d / 2
    b.part("body")
    b.box_between((-w / 2, y0, zf), (w / 2, y1, zb))
    yu0 = y1 + p.top_thick
    if p.upper_height > 0:
        b.box_between((-p.upper_width / 2, yu0 - 0.01, zb - p.upper_depth), (p.upper_width / 2, yu0 + p.upper_height, zb))
    handles: list = []
    if p.front_recess > 0:
        t = p.panel
        b.box_between((-w / 2 + t, y0 + t, zf - 0.05), (w / 2 - t, y1 - t, zf + p.front_recess), op="subtract")
    _unit_front(b, p, p.sections, -w / 2, w / 2, y0, y1, zf + p.front_recess, zb, handles)
    _handles(b, p, handles, zf + p.front_recess)
    if p.upper_height > 0:
        handles = []
        zu = zb - p.upper_depth
        _unit_front(b, p, p.upper_sections, -p.upper_width / 2, p.upper_width / 2, yu0, yu0 + p.upper_height, zu, zb, handles)
        _handles(b, p, handles, zu)
    if p.top_thick > 0:
        o = p.top_overhang
        b.part("top")
        b.box_between((-w / 2 - o, y1 - 0.005, zf - o), (w / 2 + o, y1 + p.top_thick, zb), rounding=0.01)
    if p.cornice > 0:
        ytop = yu0 + p.upper_height if p.upper_height > 0 else y1 + p.top_thick
        cw = p.upper_width if p.upper_height > 0 else w
        cz = zb - p.upper_depth if p.upper_height > 0 else zf
        b.part("top")
        b.box_between((-cw / 2 - p.cornice, ytop - 0.005, cz - p.cornice), (cw / 2 + p.cornice, ytop + 0.06, zb), rounding=0.01)
    if p.base != "none":
        b.part("base")
        h = y0 + 0.01
        if p.base == "plinth":
            i = p.plinth_inset
            b.box_between((-w / 2 + i, 0, zf + i), (w / 2 - i, h, zb - 0.01))
        elif p.base == "gables":  # the side panels run down to the floor, a kick board between
            for s in (-1, 1):
                b.box_between((s * w / 2, 0, zf), (s * (w / 2 - p.panel), h, zb))
            b.box_between((-w / 2 + 0.02, h - min(h, 0.07), zf + p.plinth_inset), (w / 2 - 0.02, h, zf + p.plinth_inset + 0.055))
        else:  # legs or bun feet at the corners
            lt = p.leg_thick if p.base == "legs" else max(p.leg_thick, 0.07)
            xi, zi = w / 2 - lt / 2 - p.leg_inset, d / 2 - lt / 2 - p.leg_inset
            for x in (-xi, xi):
                for z in (-zi, zi):
                    if p.base == "feet":
                        b.cylinder((x, h / 2, z), lt / 2 + 0.01, h / 2)
                    elif p.leg_shape == "square":
                        b.box((x, h / 2, z), (lt / 2, h / 2, lt / 2))
                    elif p.leg_shape == "round":
                        b.cylinder((x, h / 2, z), lt / 2, h / 2)
                    else:
                        b.cone((x, h / 2, z), h / 2, max(0.6 * lt, 0.055) / 2, lt / 2)
            if p.base == "legs" and p.undershelf > 0 and h > 0.2:
                ys = max(p.undershelf * h, 0.03)
                b.box_between((-xi, ys, -zi), (xi, ys + 0.055, zi))
    return b.shape()
