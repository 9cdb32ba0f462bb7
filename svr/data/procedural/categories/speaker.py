"""The procedural speaker: an enclosure with drivers (conical dishes 0.2-0.9 of their radius deep,
1-4 of drawn sizes and places) in its front baffle (-z). Box enclosures ("bookshelf": height/width
0.9-2, depth/width 0.3-1.5, often on a stand 0.5-1.3 times its height; "tower": height/width
2.3-5, maybe a hybrid whose upper 40-70% is a thin panel 0.055-0.14 thick, maybe split in two over a
neck; "subwoofer": about a cube, its one big driver firing front, side or down into a hollow
underneath; "soundbar": a bar (height/width 0.12-0.33), a centre channel (0.28-0.55) or a boombox
(0.4-0.8, a grip on two posts); "pa": a horn-topped cabinet on a tripod or the floor, maybe split)
take a profile (square, a back tapered or a baffle sloped by up to 40 degrees, a curved back, or for
"pa" sides angled in), a rounding of 0-0.25, a baffle recessed 8-65% of the depth inside walls
0.055-0.16 thick, an open back hollowed 30-100% of what is left, a port, a grille or a tweeter ball
on top, and a base (none, plinth, foot strips, spikes, stand, tripod). "round" speakers are upright
drums (height/diameter 0.4-2.5, tapering either way, a coned top, a flat one with a top-firing
driver or a well 0.1-0.9 radii deep, maybe a carrying loop or a hollow underneath on three feet),
lying cylinders or pills (length/diameter 1.5-4) with radiators at both ends (tubes: deep in the
open ends), or orbs on a stem of 0.04-0.6 diameters with a dish or a deep mouth.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape
from svr.data.procedural.categories.blocks import uniform, chance, bar, frame, ALONG_X, ALONG_Z, X, Y

STYLES = ("bookshelf", "tower", "subwoofer", "soundbar", "round", "pa")
PROFILES = ("square", "taper", "slope", "curved", "trapezoid")
BASES = ("none", "plinth", "strips", "spikes", "stand", "tripod")
ROUND_FORMS = ("drum", "lying", "orb")
BAR_FORMS = ("bar", "centre", "boombox")  # soundbar: a long bar, a centre channel, a boombox with a handle


@dataclass(frozen=True)
class SpeakerParams:
    style: str
    width: float            # the enclosure (x); round: the diameter
    height: float           # y; lying cylinder: its length along x
    depth: float            # z
    rounding: float
    profile: str            # box enclosures: see PROFILES
    slant: float            # radians: the sloped baffle's or tapered back's angle
    drivers: tuple[tuple[float, float, float], ...]  # (x, y, radius) on the baffle, y from its bottom
    cone_depth: float       # the dishes' depth relative to their radius
    caps: bool              # dust caps on drivers over 0.1 in radius
    port: str               # "none", "round", "slot"
    port_y: float           # the port's height on the baffle
    grille: bool            # a cloth panel over the baffle, hiding the drivers
    firing: str             # subwoofer: the driver in the "front", a "side" or the "bottom" (on feet)
    base: str
    base_height: float
    base_width: float       # stand: column width; plinth/strips: overhang
    form: str               # round: see ROUND_FORMS; soundbar: see BAR_FORMS; else "box"
    panel_height: float     # tower: a thin panel radiator standing on the box; 0: none
    panel_thick: float
    pod: float              # a tweeter pod on top (bookshelf, tower): its radius; 0: none
    top: float              # round drum: the top's rise (0 flat, > 0 dome or cone)
    taper: float            # round drum: top radius / bottom radius; lying: 1 a cylinder, 0 a pill
    stalk: float            # round: the foot's height (orb: a stem) relative to the diameter
    foot: float             # round: the foot's radius relative to the body's
    handle: bool            # round drum: a carrying loop on the top; boombox: a grip on two posts
    recess: float           # box: the baffle set back this deep inside a surround; 0: flush
    wall: float             # box: the surround's and an open back's wall thickness
    back_open: float        # box: an open back (amp-style) hollowed this deep; 0: closed
    top_well: float         # round: the depth of the top-firing well (drum) or the driver bowl (orb), per radius
    gap: tuple[float, float, float]  # tower: (height share, gap height, neck width share): the box split in
                                     # two over a neck; (0, 0, 0): whole
    bottom_well: float      # round drum: a down-firing hollow underneath on three feet, its depth per height; 0: none


# ---------------------------------------------------------------------------------------------
# sampling


def _drivers_column(rng: np.random.Generator, w: float, h: float, n_max: int) -> tuple:
    """Woofers stacked in a column on the baffle, a tweeter above or between them."""
    r = min(w * uniform(rng, 0.28, 0.42), h * 0.3)
    tw = max(min(r * uniform(rng, 0.3, 0.55), 0.07), 0.04)
    n = int(rng.integers(1, n_max + 1))
    out = []
    y = h - uniform(rng, 0.06, 0.2) * h - tw
    x_off = w * uniform(rng, -0.15, 0.15) if chance(rng, 0.3) else 0.0
    out.append((x_off, y, tw))
    y -= tw + r + uniform(rng, 0.02, 0.08)
    for _ in range(n):
        if y - r < 0.04:
            break
        out.append((0.0, y, r))
        y -= 2 * r + uniform(rng, 0.02, 0.08)
    if len(out) == 1:
        out.append((0.0, max(r + 0.04, y), r))
    if chance(rng, 0.25):  # upside down: the tweeter at the bottom
        out = [(x, h - y, r) for x, y, r in out]
    return tuple(out)


def sample(rng: np.random.Generator, style: str) -> SpeakerParams:
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    bar_form = str(rng.choice(BAR_FORMS, p=(0.4, 0.3, 0.3))) if style == "soundbar" else "box"
    h_w, d_w = {"bookshelf": (uniform(rng, 0.9, 2.0), uniform(rng, 0.3, 1.5)),
                "tower": (uniform(rng, 2.3, 5.0), uniform(rng, 0.6, 2.4)),
                "subwoofer": (uniform(rng, 0.6, 1.4), uniform(rng, 0.5, 1.5)),
                "soundbar": {"bar": (uniform(rng, 0.12, 0.33), uniform(rng, 0.12, 0.4)),
                             "centre": (uniform(rng, 0.28, 0.55), uniform(rng, 0.25, 0.7)),
                             "boombox": (uniform(rng, 0.4, 0.8), uniform(rng, 0.18, 0.45))}.get(bar_form, (0, 0)),
                "round": (1.0, 1.0), "pa": (uniform(rng, 1.2, 2.0), uniform(rng, 0.7, 1.3))}[style]
    base = {"bookshelf": str(rng.choice(BASES, p=(0.25, 0.1, 0.15, 0.05, 0.45, 0.0))),
            "tower": str(rng.choice(BASES, p=(0.2, 0.35, 0.2, 0.25, 0.0, 0.0))),
            "subwoofer": str(rng.choice(BASES, p=(0.3, 0.2, 0.2, 0.3, 0.0, 0.0))),
            "soundbar": str(rng.choice(BASES, p=(0.6, 0.0, 0.4, 0.0, 0.0, 0.0))),
            "round": "none", "pa": str(rng.choice(BASES, p=(0.3, 0.0, 0.2, 0.0, 0.0, 0.5)))}[style]
    firing = str(rng.choice(["front", "side", "bottom"], p=(0.4, 0.25, 0.35))) if style == "subwoofer" else "front"
    if firing == "bottom" and base in ("none", "plinth"):
        base = "spikes"
    stand = uniform(rng, 0.5, 1.3) if base in ("stand", "tripod") else 0.0  # stand height / enclosure height
    base_frac = {"none": 0.0, "plinth": uniform(rng, 0.02, 0.06), "strips": uniform(rng, 0.02, 0.05),
                 "spikes": uniform(rng, 0.04, 0.12) * (1.6 if firing == "bottom" else 1.0)}.get(base, 0.0)
    pod = uniform(rng, 0.3, 0.5) if style in ("bookshelf", "tower") and chance(rng, 0.25) else 0.0
    tall = h_w * (1 + stand + base_frac) + 1.8 * pod
    s = 1.0 / max(1.0, tall, d_w)  # the longest side 1
    w, h, d = s, h_w * s, d_w * s
    base_height = max(stand * h, base_frac * h, 0.055) if base != "none" else 0.0
    form = str(rng.choice(ROUND_FORMS, p=(0.5, 0.25, 0.25))) if style == "round" else bar_form
    if style == "round":  # height (drum) or length (lying) against the diameter
        ratio = uniform(rng, 0.4, 2.5) if form == "drum" else uniform(rng, 1.5, 4.0)
        w = d = uniform(rng, 0.6, 0.95) if form == "orb" else min(0.9, 0.85 / ratio)
        h = w if form == "orb" else w * ratio
    panel_h = h * uniform(rng, 0.4, 0.7) if style == "tower" and pod == 0 and chance(rng, 0.35) else 0.0
    h -= panel_h  # a hybrid: a thin panel over a bass box
    profile = "square" if style == "round" else str(rng.choice(PROFILES, p=(0.25, 0.2, 0.3, 0.25, 0.0)))
    if style == "pa":
        profile = str(rng.choice(["trapezoid", "slope", "square"], p=(0.5, 0.3, 0.2)))
    slant = uniform(rng, 0.1, 0.9)
    rounding = min(uniform(rng, 0.0, 0.06) if chance(rng, 0.7) else uniform(rng, 0.1, 0.25), 0.4 * min(w, h, d))
    if style == "soundbar":
        rounding = min(uniform(rng, 0.01, 0.5), 0.49) * min(h, d)
    # drivers on the baffle (y from the enclosure's bottom)
    if style == "subwoofer":
        drivers = ((0.0, h / 2 + uniform(rng, -0.05, 0.05) * h, min(w, h) * uniform(rng, 0.3, 0.42)),)
    elif style == "soundbar":
        n = int(rng.integers(1, 4)) if form == "bar" else 1
        r = h * uniform(rng, 0.25, 0.42) if form != "boombox" else min(h * uniform(rng, 0.3, 0.4), w * 0.2)
        span = w * uniform(rng, 0.2, 0.42)
        xs = np.linspace(-span, span, 2 * n) if n > 1 else np.array([-span, span])
        drivers = tuple((float(x), h / 2, r) for x in xs)
    elif style == "round":
        r = w * uniform(rng, 0.25, 0.4)
        drivers = ((0.0, h * uniform(rng, 0.35, 0.65), r),)
        if form == "drum" and h > 2.2 * w and chance(rng, 0.7):
            drivers = ((0.0, h * 0.3, r), (0.0, h * 0.7, r))
    else:
        drivers = _drivers_column(rng, w, h, {"bookshelf": 1, "pa": 2}.get(style, 4))
        if panel_h > 0:
            drivers = ((0.0, h / 2, min(0.38 * w, 0.35 * h)),)
    port = str(rng.choice(["none", "round", "slot"], p=(0.5, 0.3, 0.2))) if style != "round" else "none"
    wall = min(uniform(rng, 0.055, 0.16), max(0.055, 0.25 * min(w, h + panel_h)))
    recess = back_open = 0.0
    if style != "round" and chance(rng, {"soundbar": 0.5}.get(style, 0.75)):
        recess = d * uniform(rng, 0.08, 0.65)
    if style != "round" and profile in ("square", "slope", "taper") and chance(rng, 0.5):
        back_open = (d - recess - 0.07) * uniform(rng, 0.3, 1.0)
    return SpeakerParams(
        style=style, width=w, height=h, depth=d, rounding=rounding, profile=profile, slant=slant,
        drivers=drivers, cone_depth=uniform(rng, 0.2, 0.9), caps=chance(rng, 0.5), port=port,
        port_y=uniform(rng, 0.06, 0.2), grille=style in ("bookshelf", "tower", "soundbar") and chance(rng, 0.25),
        firing=firing, base=base,
        pod=pod * w, panel_height=panel_h, panel_thick=uniform(rng, 0.055, 0.14), base_height=base_height,
        base_width=uniform(rng, 0.07, 0.2) if base == "stand" else uniform(rng, 0.0, 0.06),
        form=form, top=uniform(rng, 0.0, 0.4) if chance(rng, 0.35) else 0.0,
        taper=(uniform(rng, 0.55, 1.6) if chance(rng, 0.6) else 1.0) if form == "drum" else float(chance(rng, 0.6)),
        stalk=uniform(rng, 0.04, 0.6) if form == "orb" else uniform(rng, 0.0, 0.2),
        foot=uniform(rng, 0.35, 0.95), handle=(form == "drum" and chance(rng, 0.3)) or (form == "boombox" and chance(rng, 0.8)),
        recess=recess, wall=wall, back_open=max(back_open, 0.0), top_well=uniform(rng, 0.1, 0.9),
        bottom_well=uniform(rng, 0.1, 0.6) if form == "drum" and chance(rng, 0.4) else 0.0,
        gap=(uniform(rng, 0.3, 0.7), uniform(rng, 0.055, 0.14), uniform(rng, 0.25, 0.6))
        if style in ("tower", "pa") and chance(rng, 0.5) else (0.0, 0.0, 0.0))


# ---------------------------------------------------------------------------------------------
# construction


def _dish(b: CSGBuilder, centre, normal, radius: float, depth: float) -> None:
    """A driver: a conical dish cut into a face whose outward normal is ``normal``."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    half = depth / 2 + 0.005
    rot = frame(-n, X if abs(n[0]) < 0.9 else Y)
    # local +y points into the body: the wide end (bottom, -y) at the face
    b.cone(np.asarray(centre) - n * (half - 0.01), half, radius, 0.45 * radius, rot, op="subtract")


def _box_body(b: CSGBuilder, p: SpeakerParams, y0: float) -> tuple:
    """The enclosure, its profile, a recessed baffle and an open back; returns (a point on the baffle
    at its bottom, the baffle's normal, its up direction, the recess, the baffle's thickness)."""
    w, h, d = p.width, p.height, p.depth
    zf, zb = -d / 2, d / 2
    b.box((0, y0 + h / 2, 0), (w / 2, h / 2, d / 2), rounding=p.rounding)
    normal, up = np.array([0.0, 0.0, -1.0]), np.array([0.0, 1.0, 0.0])
    origin = np.array([0.0, y0, zf])
    big = 1.0
    if p.profile == "slope":  # the baffle leans back: cut the front along a plane through its bottom edge
        a = min(p.slant, math.atan(0.75 * d / h))
        up = np.array([0.0, math.cos(a), math.sin(a)])
        normal = np.array([0.0, math.sin(a), -math.cos(a)])
        centre = origin + up * h / 2 + normal * big / 2
        b.box(centre, (w, h, big / 2), frame(up, X), op="subtract")
    elif p.profile == "taper":  # the back slopes in towards the top
        a = min(p.slant, math.atan(0.6 * d / h))
        upb = np.array([0.0, math.cos(a), -math.sin(a)])
        nb = np.array([0.0, math.sin(a), math.cos(a)])
        centre = np.array([0.0, y0, zb]) + upb * h / 2 + nb * big / 2
        b.box(centre, (w, h, big / 2), frame(upb, X), op="subtract")
    elif p.profile == "trapezoid":  # the sides angle in towards the back
        a = min(p.slant * 0.5, math.atan(0.3 * w / d))
        for sx in (-1, 1):
            side = np.array([sx * math.cos(a), 0.0, math.sin(a)])
            centre = np.array([sx * w / 2, y0 + h / 2, zf]) + side * big / 2 + np.array([-sx * math.sin(a), 0, math.cos(a)]) * d / 2
            b.box(centre, (big / 2, h, d), frame((0, 1, 0), side), op="subtract")
    elif p.profile == "curved":  # a rounded back: the body cut to a cylinder through the front corners
        depth_c = d * 0.98
        r = ((w / 2) ** 2 + depth_c ** 2) / (2 * depth_c)
        b.cylinder((0, y0 + h / 2, zb - r), r, h, op="intersect")
    a = min(p.slant, math.atan(0.75 * d / h)) if p.profile == "slope" else 0.0
    rest = d - h * math.tan(a)  # the body's depth behind the baffle at its top
    rec = min(p.recess, rest * math.cos(a) - 0.09) if min(w, h) > 2 * p.wall + 0.06 else 0.0
    if rec > 0.03:  # the baffle set back inside a surround of the walls' thickness
        length = h / math.cos(a)
        lo, hi = p.wall, length - p.wall / math.cos(a)
        centre = origin + up * (lo + hi) / 2 + normal * (0.05 - rec) / 2
        b.box(centre, (w / 2 - p.wall, (hi - lo) / 2, (rec + 0.05) / 2), frame(up, X), op="subtract")
        origin = origin - normal * rec
    else:
        rec = 0.0
    hollow = min(p.back_open, rest - rec / math.cos(a) - 0.07) if min(w, h) > 2 * p.wall + 0.06 else 0.0
    if hollow > 0.05:  # an open back: the box hollowed to its walls from behind
        b.box_between((-w / 2 + p.wall, y0 + p.wall, zb - hollow), (w / 2 - p.wall, y0 + h - p.wall, zb + 0.05),
                      op="subtract")
    if p.gap[1] > 0 and h > 0.4:  # split in two over a neck: the slot through the depth beside it
        yg, gh, neck = y0 + p.gap[0] * h, p.gap[1], max(p.gap[2] * w, 0.08)
        for sx in (-1, 1):
            b.box_between((sx * neck / 2, yg - gh / 2, zf - 0.05), (sx * (w / 2 + 0.05), yg + gh / 2, zb + 0.05),
                          op="subtract")
    return origin, normal, up, rec, (rest - rec / math.cos(a) - hollow if hollow > 0.05 else 1.0)


def build(p: SpeakerParams) -> CSGShape:
    b = CSGBuilder()
    y0 = p.base_height
    w, h, d = p.width, p.height, p.depth
    b.part("body")
    if p.style == "round":
        return _round(b, p)
    origin, normal, up, rec, baffle = _box_body(b, p, y0)
    inner = w / 2 - p.wall - 0.01 if rec > 0 else w  # drivers fit inside a surround
    if p.firing != "front":
        rr = p.drivers[0][2]
        b.part("drivers")
        if p.firing == "side":
            _dish(b, (w / 2, y0 + h / 2, 0.0), (1, 0, 0), min(rr, 0.42 * d), min(p.cone_depth * rr, 0.6 * w))
        elif p.profile in ("square", "slope", "taper") and p.wall * 2 + 0.1 < min(w, d):
            # hollow underneath to its walls, the driver firing into the hollow
            b.box_between((-w / 2 + p.wall, y0 - 0.05, -d / 2 + p.wall + rec),
                          (w / 2 - p.wall, y0 + p.top_well * (h - p.wall - 0.06), d / 2 - p.wall), op="subtract")
        else:
            _dish(b, (0.0, y0, 0.0), (0, -1, 0), min(rr, 0.42 * d), min(p.cone_depth * rr, 0.6 * h))
    elif p.grille:
        b.part("grille")
        g = p.wall + 0.01 if rec > 0 else 0.04
        c = origin + up * h / 2 + normal * 0.0
        b.box(c, (w / 2 - g, h / 2 - g, 0.0275), frame(up, X), rounding=0.01)
    else:
        b.part("drivers")
        for x, y, r in p.drivers:
            r = min(r, inner)
            _dish(b, origin + up * y + np.array([x, 0, 0]), normal, r, min(p.cone_depth * r, 0.6 * d, baffle - 0.03))
        if p.port != "none":
            pc = origin + up * (p.port_y * h)
            if p.port == "round":
                b.cylinder(pc, 0.04, 0.12, frame(-normal, X), op="subtract")
            else:
                b.box(pc, (w * 0.3, 0.0275, 0.12), frame(up, X), op="subtract")
        if p.caps:
            for x, y, r in p.drivers:
                r = min(r, inner)
                if r > 0.1:
                    dd = min(p.cone_depth * r, 0.6 * d, baffle - 0.03)
                    b.sphere(origin + up * y + np.array([x, 0, 0]) - normal * (dd * 0.7), 0.3 * r)
    if p.panel_height > 0:  # a thin panel in a frame on the box, leaning back a little
        b.part("panel")
        a = 0.15 * p.slant
        up = np.array([0.0, math.cos(a), math.sin(a)])
        c = np.array([0.0, y0 + h - 0.02, 0.0]) + up * (p.panel_height / 2 + 0.02)
        b.box(c, (w / 2 * 0.95, p.panel_height / 2 + 0.02, p.panel_thick / 2), frame(up, X), rounding=0.015)
    z0, z1 = -d / 2, d / 2  # the top that the profile leaves
    if p.profile == "slope":
        z0 += h * math.tan(min(p.slant, math.atan(0.75 * d / h)))
    elif p.profile == "taper":
        z1 -= h * math.tan(min(p.slant, math.atan(0.6 * d / h)))
    zc = (z0 + z1) / 2
    if p.form == "boombox" and p.handle:  # a grip on two posts over the top
        b.part("handle")
        hx, gh, top = w / 2 * p.foot * 0.9, 0.08 + 0.6 * p.stalk, y0 + h
        for sx in (-1, 1):
            b.box_between((sx * hx - 0.0275, top - 0.02, zc - 0.0275), (sx * hx + 0.0275, top + gh, zc + 0.0275))
        b.box_between((-hx - 0.0275, top + gh - 0.01, zc - 0.035), (hx + 0.0275, top + gh + 0.055, zc + 0.035), rounding=0.01)
    if p.pod > 0:  # a ball on the top, its tweeter to the front
        b.part("pod")
        yc = y0 + h + p.pod * 0.8
        b.sphere((0, yc, zc), p.pod)
        _dish(b, (0, yc, zc - p.pod + 0.01), (0, 0, -1), 0.5 * p.pod, 0.3 * p.pod)
    if p.base != "none":
        b.part("base")
        o = p.base_width
        bh = y0 + 0.01
        if p.base == "plinth":
            b.box((0, bh / 2, 0), (w / 2 + o, bh / 2, d / 2 + o), rounding=0.01)
        elif p.base == "strips":
            zs = max(d / 2 - 0.06, 0.0)
            for s in (-1, 1):
                b.box((0, bh / 2, s * zs), (w / 2 - 0.04, bh / 2, 0.04))
        elif p.base == "spikes":  # cones at the corners, points down
            for sx in (-1, 1):
                for sz in (-1, 1):
                    k = 0.5 if p.profile == "curved" else 1.0
                    ins = max(0.05, p.rounding + 0.03)
                    b.cone((sx * k * (w / 2 - ins), bh / 2, sz * k * (d / 2 - ins)), bh / 2, 0.015, 0.04)
        elif p.base == "tripod":  # a pole in a socket under the box, on three legs
            b.cylinder((0, y0 / 2 + 0.02, 0), 0.0285, y0 / 2 + 0.02)
            for k in range(3):
                ang = 2 * math.pi * k / 3 + math.pi / 2
                foot = np.array([math.cos(ang), 0, math.sin(ang)]) * min(0.45 * y0 + 0.1, 0.5)
                bar(b, (0, y0 * 0.4, 0), foot + np.array([0, 0.0275, 0]), 0.055, 0.055)
        else:  # stand: a top plate, a column, a foot plate
            cw = max(p.base_width, 0.055)
            b.box((0, y0 - 0.0275, 0), (w / 2 * 0.9, 0.0275, d / 2 * 0.9))
            b.box((0, y0 / 2, 0), (cw / 2, y0 / 2, cw / 2))
            b.box((0, 0.0275, 0), (w / 2, 0.0275, d / 2), rounding=0.01)
    return b.shape()


def _round(b: CSGBuilder, p: SpeakerParams) -> CSGShape:
    w, h = p.width, p.height
    r = w / 2
    if p.form == "lying":  # a cylinder or a pill along x: radiators in both ends, on a foot strip
        length = h
        cy = r + 0.04 + p.stalk * w
        if p.taper > 0.5:
            b.cylinder((0, cy, 0), r, length / 2, ALONG_X)
        else:
            b.capsule((-length / 2 + r, cy, 0), (length / 2 - r, cy, 0), r)
        b.part("drivers")
        for s in (-1, 1):
            if p.taper > 0.5 and r > 0.14:  # a tube: radiators deep in both open ends
                deep = p.top_well * (length / 2 - 0.1)
                b.cylinder((s * (length / 2 - deep / 2 + 0.02), cy, 0), r - 0.065, deep / 2 + 0.02, ALONG_X, op="subtract")
            else:
                _dish(b, (s * length / 2, cy, 0), (s, 0, 0), 0.8 * r, p.cone_depth * r)
        x, y, dr = p.drivers[0]
        _dish(b, (0, cy + r * 0.25, -r * 0.97), (0, 0.25, -1), min(dr, 0.3 * length), 0.05)
        b.part("base")
        fh = (cy - r * 0.7) / 2
        b.box((0, fh, 0), (length * 0.35 * p.foot + 0.03, fh, max(r * 0.6 * p.foot, 0.04)), rounding=0.01)
        return b.shape()
    if p.form == "orb":  # a ball on a stem and a disc
        cy = r + 0.055 + p.stalk * w
        b.sphere((0, cy, 0), r)
        b.part("drivers")
        ro = min(p.drivers[0][2] * (1 + 0.5 * p.top_well), r - 0.08)
        zb = -r + p.top_well * (r + 0.9 * math.sqrt(max(r * r - (ro + 0.06) ** 2, 0.0)))
        if zb > -r + 0.06:  # a deep mouth in the front, its driver at the bottom
            b.cylinder((0, cy, (zb - r - 0.05) / 2), ro, (zb + r + 0.05) / 2, ALONG_Z, op="subtract")
        else:
            _dish(b, (0, cy, -r), (0, 0, -1), ro, p.cone_depth * r)
        b.part("base")
        b.cylinder((0, (cy - r * 0.8) / 2, 0), 0.03 + 0.06 * p.foot, (cy - r * 0.8) / 2)
        b.cylinder((0, 0.0275, 0), r * p.foot, 0.0275)
        return b.shape()
    y0 = 0.055 + p.stalk * w * 0.5
    rb, rt = (r, r * p.taper) if p.taper <= 1 else (r / p.taper, r)
    b.cone((0, y0 + h / 2, 0), h / 2, rb, rt)
    well = min(p.bottom_well * h, h - 0.25) if rb > 0.12 else 0.0
    if well > 0.05:  # hollow underneath, firing down, on three feet under its rim
        b.cone((0, y0 + well / 2 - 0.01, 0), well / 2 + 0.01, rb - 0.065, rb - 0.065 + (rt - rb) * well / h, op="subtract")
    b.part("drivers")
    if p.top > 0:
        b.part("body")
        b.cone((0, y0 + h + p.top * rt / 2, 0), max(p.top * rt / 2, 0.0275), rt, rt * (1 - p.top))
    elif p.handle or rt < 0.12:  # a flat top with a top-firing driver
        _dish(b, (0, y0 + h, 0), (0, 1, 0), 0.6 * rt, p.cone_depth * rt * 0.4)
    else:  # a well in the top, a driver at its bottom firing up
        well = min(p.top_well * rt, 0.5 * h)
        b.cylinder((0, y0 + h - well / 2 + 0.025, 0), rt - 0.06, well / 2 + 0.025, op="subtract")
    for x, y, dr in p.drivers:
        ry = rb + (rt - rb) * y / h  # the body's radius there
        _dish(b, (0, y0 + y, -ry), (0, 0, -1), min(dr, 0.4 * h, 0.8 * ry), p.cone_depth * dr)
    if p.handle:  # a carrying loop over the top
        b.part("handle")
        b.torus((0, y0 + h + (p.top * rt / 2 if p.top > 0 else 0.0), 0), 0.6 * rt, 0.0285, ALONG_Z)
    b.part("base")
    if well > 0.05:
        for k in range(3):
            ang = 2 * math.pi * k / 3 + math.pi / 2
            b.cylinder((math.cos(ang) * (rb - 0.035), y0 / 2, math.sin(ang) * (rb - 0.035)), 0.04, y0 / 2 + 0.01)
    else:
        b.cylinder((0, y0 / 2, 0), rb * p.foot, y0 / 2 + 0.01)
    return b.shape()
