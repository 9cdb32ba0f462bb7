"""The procedural phone: screen to -z, in six styles. "slab": a smartphone 0.28-0.8 of its height
wide and 0.06-0.26 thick (log-uniform), edge rounding up to half its thickness, a recessed screen
with drawn bezels, a camera bump (none, square, round or a full-width strip; 0.1-0.5 of the width,
standing out 0.0275-0.08), maybe a side button, in 40% a wallet case's cover (0.055-0.1 thick) open at 0.25-3.14 rad about
the left edge, and in 50% a battery pack (0.055-0.16 thick, 0.3-0.8
of the height, 0.5-0.95 of the width) on the back, and in 50% a back sloping in to lose 0.1-0.6
of the thickness at the top (slab and candybar); "candybar": a thicker phone (0.09-0.32) with a
screen over a keypad (0.25-0.5 of the face; a flush panel or a block standing out 0.045-0.1), maybe
an antenna and a battery pack; "slider": two slabs (0.06-0.17 and 0.055-0.16 thick), the screen half
slid up (or sideways) by 0-0.55 of its length off the keypad half; "flip": a keypad half and a
screen lid on a hinge cylinder, closed or open at any angle from 0.4 rad to flat; "handset": a
cordless handset 0.18-0.4 wide, its ear end (0.25-0.51 of the length, 0.06-0.2 thick) bent to the
front by 0-0.45 rad, maybe an antenna; "desk": a desk telephone, a base 0.5-1.0 wide, 0.35-1.0 deep
and 0.06-0.35 high whose top slopes down to the front, a keypad and maybe a display on the slope,
and a handset resting on two cradle blocks (a hole under it) along the left side or across the
back, maybe with a cord looping to the base, or a cordless one standing in a dock. The hand-held
styles stand tilted back by 0-0.3 rad, or lean by 0.05-0.5 rad in a dock (a block or a round foot,
in 50% with a back rest 0.25-0.7 of the phone's height) or by up to 0.7 rad on an easel strut
(0.055-0.11 thick).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, cut_beyond, X, Y, Z, ALONG_X, ALONG_Z

STYLES = ("slab", "candybar", "slider", "flip", "desk", "handset")
THICK = 0.06  # the thinnest slab, strut or key: a little over MIN_PART


@dataclass(frozen=True)
class PhoneParams:
    style: str
    height: float        # hand-held: the body's length (the keypad half's for slider and flip)
    width: float
    thick: float         # hand-held: the (keypad half's) thickness; desk: the base's height
    rounding: float
    bezel: float         # screen margins: sides, top, bottom (a fraction of the free face)
    screen_top: float
    screen_bottom: float
    camera: str          # "none", "square", "round", "strip"
    camera_size: float
    camera_h: float      # how far the bump stands out of the back
    camera_x: float
    button: bool
    keypad_frac: float   # the keypad's share of the face (or of the slope)
    antenna: bool
    antenna_h: float
    slide: float         # slider: the screen half's offset, a fraction of the length
    sideways: bool       # slider: it slides along x
    lid_frac: float      # slider / flip: the second half's length over the first's
    lid_thick: float
    opening: float       # flip: radians between the halves (0: closed)
    hinge_r: float
    stand: str           # "none", "dock" (a box or a round foot), "easel"
    dock_round: bool
    strut_w: float       # easel: the strut's width over the phone's, and where it meets the back
    strut_at: float
    lean: float          # radians, back
    stand_depth: float
    stand_h: float
    depth: float         # desk: the base's depth
    slope: float         # desk: how far the top drops to the front (fraction of the height)
    ledge: float         # desk: the flat part under a side handset (fraction of the width)
    layout: str          # desk: "side", "across", "upright"
    handset_len: float
    handset_r: float
    cradle_h: float
    display: bool
    cord: bool
    battery: float = 0.0     # slab / candybar: a battery pack's thickness on the back (0: none)
    battery_h: float = 0.5   # its height (fraction of the body) and width (fraction of the width)
    battery_w: float = 0.8
    strut_t: float = THICK   # easel: the strut's thickness
    dock_back: float = 0.0   # dock: a back rest's height (fraction of the phone's; 0: none)
    dock_w: float = 0.5      # dock: the block's half width over the phone's width
    bend: float = 0.0        # handset: the ear end's tilt to the front (radians)
    ear_thick: float = 0.1   # handset: the ear end's thickness
    keys_raised: float = 0.0  # candybar: how far a keypad block stands out of the front (0: a flush panel)
    cover: float = 0.0       # slab: a wallet case's cover swung open about the left edge (radians; 0: none)
    cover_t: float = 0.06
    taper: float = 0.0       # slab / candybar: the share of the thickness the back loses towards the top (a wedge)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def sample(rng: np.random.Generator, style: str) -> PhoneParams:
    u = lambda lo, hi: uniform(rng, lo, hi)  # noqa: E731
    lu = lambda lo, hi: _log_uniform(rng, lo, hi)  # noqa: E731
    width = u(0.28, 0.8)
    if style == "slab":
        thick = lu(0.06, 0.26)
    elif style == "candybar":
        thick, width = lu(0.09, 0.32), u(0.28, 0.56)
    elif style == "desk":
        width, thick = u(0.5, 1.0), lu(0.06, 0.35)
    elif style == "handset":
        width = u(0.18, 0.4)
        thick = min(lu(0.07, 0.24), 0.75 * width)
    else:
        thick = lu(0.06, 0.17)
    stand = "none"
    if style in ("slab", "candybar", "slider", "handset"):
        stand = str(rng.choice(["none", "none", "dock", "dock", "easel"]))
    elif style == "flip" and chance(rng, 0.25):
        stand = "dock"
    opening = 0.0 if (style == "flip" and chance(rng, 0.2)) else u(0.4, math.pi)
    stand_h, antenna = u(0.06, 0.2), style in ("candybar", "handset") and chance(rng, 0.5)
    antenna_h = u(0.05, 0.2)
    slide, lid_frac, sideways = u(0.0, 0.55), u(0.7, 1.05), chance(rng, 0.25)
    # the length that keeps the whole within about 1 (a dock, an antenna, a slid or opened half add to it)
    room = 1.0 - (stand_h - 0.04 if stand == "dock" else 0.0) - (antenna_h if antenna else 0.0)
    if style == "slider" and not sideways:
        room /= max(1.0, slide + (1 + lid_frac) / 2)
    elif style == "flip":
        room /= 0.52 * (1 + lid_frac) if opening > 0 else 0.52 * max(1.0, lid_frac)
    cover = u(0.25, math.pi) if style == "slab" and chance(rng, 0.4) else 0.0
    if cover > math.pi / 2:  # a cover opened past square widens the whole: keep it within about 1
        width = min(width, 1.0 / (1.0 - math.cos(cover)))
    if stand == "none":
        lean = u(0.0, 0.3)
    else:
        lean = u(0.05, 0.5 if stand == "dock" else 0.7)
    return _fit(PhoneParams(
        style=style, height=room, width=width, thick=thick, rounding=u(0.0, 1.0),
        bezel=u(0.02, 0.12), screen_top=u(0.03, 0.16), screen_bottom=u(0.03, 0.18),
        camera=str(rng.choice(["none", "square", "round", "strip"])), camera_size=u(0.1, 0.5),
        camera_h=u(0.0275, 0.08),
        camera_x=u(-1.0, 1.0), button=chance(rng, 0.5), keypad_frac=u(0.3, 0.6),
        antenna=antenna, antenna_h=antenna_h,
        slide=slide, sideways=sideways, lid_frac=lid_frac, lid_thick=lu(0.055, 0.16),
        opening=opening, hinge_r=u(0.035, 0.07),
        stand=stand, lean=lean, stand_depth=u(0.12, 0.5), stand_h=stand_h,
        dock_round=chance(rng, 0.4), strut_w=u(0.15, 0.85), strut_at=u(0.3, 0.75),
        depth=u(0.35, 1.0), slope=u(0.1, 0.6), ledge=u(0.25, 0.4),
        layout=str(rng.choice(["side", "across", "upright"])),
        handset_len=u(0.65, 0.95), handset_r=u(0.03, 0.07), cradle_h=u(0.04, 0.12), display=chance(rng, 0.5),
        cord=chance(rng, 0.5),
        battery=u(0.055, 0.16) if style in ("slab", "candybar") and chance(rng, 0.5) else 0.0,
        battery_h=u(0.3, 0.8), battery_w=u(0.5, 0.95), strut_t=u(0.055, 0.11),
        dock_back=u(0.25, 0.7) if chance(rng, 0.5) else 0.0, dock_w=u(0.3, 0.65),
        bend=u(0.0, 0.45), ear_thick=lu(0.06, 0.2),
        keys_raised=u(0.045, 0.1) if style == "candybar" and chance(rng, 0.5) else 0.0,
        cover=cover, cover_t=u(0.055, 0.1),
        taper=u(0.1, 0.6) if style in ("slab", "candybar") and chance(rng, 0.5) else 0.0))


def _fit(p: PhoneParams) -> PhoneParams:
    """The record with its length and width shrunk until the raw shape's box (its primitives' box,
    which contains it) is at most about 1 on every side: an open cover, a lean and a strut add up."""
    for _ in range(4):
        lo, hi = build(p).bounds
        size = float(np.max(np.asarray(hi) - np.asarray(lo)))
        if size <= 1.06:
            break
        f = 1.04 / size
        p = dataclasses.replace(p, height=p.height * f, width=p.width * f if p.style != "desk" else p.width)
    return p


class _Placed:
    """A CSGBuilder seen through a rigid placement: centres and rotations in a local frame."""

    def __init__(self, b: CSGBuilder, rot: np.ndarray, origin) -> None:
        self.b, self.rot, self.origin = b, np.asarray(rot, float), np.asarray(origin, float)

    def at(self, p) -> np.ndarray:
        return self.origin + self.rot @ np.asarray(p, float)

    def box(self, centre, half, rot=None, op="union", rounding=0.0):
        self.b.box(self.at(centre), half, self.rot if rot is None else self.rot @ rot, op=op, rounding=rounding)

    def cylinder(self, centre, radius, half_height, rot, op="union"):
        self.b.cylinder(self.at(centre), radius, half_height, self.rot @ rot, op=op)


def _keypad(f: _Placed, w: float, y0: float, y1: float, z_face: float) -> None:
    """A keypad: one shallow panel in a face at z = z_face facing -z (its keys are its colour; a
    groove per key would cost a row in every render)."""
    f.box((0, (y0 + y1) / 2, z_face), (w / 2, (y1 - y0) / 2, 0.016), op="subtract")


def _slab(f: _Placed, p: PhoneParams, w: float, h: float, t: float, y0: float, z0: float, screen: tuple) -> None:
    """A rounded slab from y0 to y0 + h, its front face at z0, a screen recess (sides, bottom, top
    margins) in it."""
    f.box((0, y0 + h / 2, z0 + t / 2), (w / 2, h / 2, t / 2), rounding=max(0.01, p.rounding * min(t / 2, 0.08)))
    if screen is not None:
        mx, mb, mt = screen
        f.b.part("screen")
        f.box((0, y0 + (mb + h - mt) / 2, z0), (w / 2 - mx, (h - mt - mb) / 2, 0.012), op="subtract")
        f.b.part("body")


def _hand_held(b: CSGBuilder, p: PhoneParams) -> None:
    w, h, t = p.width, p.height, p.thick
    # the phone leaning back (the body first: the largest row lets the SDF skip rows far from a point)
    base = p.stand_h if p.stand == "dock" else 0.0
    origin = (0.0, max(0.0, base - 0.04) + t / 2 * math.sin(p.lean), 0.0)
    f = _Placed(b, rotation(X, p.lean), origin)
    b.part("body")
    if p.style in ("slab", "candybar"):
        keypad_top = h * p.keypad_frac * 0.85 if p.style == "candybar" else 0.0
        scr = (p.bezel * w / 2 + 0.02, keypad_top + p.screen_bottom * 0.3 + 0.03, p.screen_top * 0.6 + 0.03)
        _slab(f, p, w, h, t, 0.0, -t / 2, scr)
        if p.style == "candybar":
            b.part("keys")
            if p.keys_raised > 0:  # a keypad block standing out of the front
                f.box((0, (0.05 + keypad_top) / 2, -t / 2 - p.keys_raised / 2 + 0.01),
                      ((w - 0.1) / 2, (keypad_top - 0.05) / 2, p.keys_raised / 2 + 0.01), rounding=0.01)
            else:
                _keypad(f, w - 0.12, 0.05, keypad_top, -t / 2)
            if p.antenna:
                b.part("body")
                f.cylinder((w / 2 - 0.08, h + p.antenna_h / 2 - 0.01, 0.0), 0.035, p.antenna_h / 2 + 0.01, np.eye(3))
        back = t / 2
        wedge = min(p.taper * t, t - THICK)
        if wedge > 0.01:  # the back slopes in towards the top
            cut_beyond(b, f.at((0, -0.05, back + wedge * 0.05 / h)), f.at((0, h + 0.005, back - wedge)),
                       f.rot @ np.array(X), f.rot @ np.array(Z), w / 2 + 0.05, depth=0.3, margin=0.0)
        if p.cover > 0:  # a wallet case: its cover hinged on the left front edge, swung open to the front
            b.part("cover")
            lid = _Placed(b, f.rot @ rotation(Y, p.cover), f.at((-w / 2, 0.0, -t / 2)))
            lid.box((w / 2, h / 2, -p.cover_t / 2 + 0.01), (w / 2, h / 2, p.cover_t / 2), rounding=0.01)
        if p.battery > 0:  # a battery pack (or a battery case) on the back's lower part
            b.part("body")
            bh = h * p.battery_h
            f.box((0, bh / 2 + 0.02, back + p.battery / 2 - 0.01), (w * p.battery_w / 2, bh / 2, p.battery / 2 + 0.01),
                  rounding=0.015)
    elif p.style == "slider":
        tl = p.lid_thick
        _slab(f, p, w, h, t, 0.0, -t / 2, None)
        b.part("keys")
        if p.sideways:
            _keypad(f, w - 0.1, 0.08, h - 0.08, -t / 2)
        else:
            _keypad(f, w - 0.1, 0.06, h * min(p.slide, 0.5) + 0.02, -t / 2)
        b.part("body")
        hl = h * p.lid_frac
        dx = (p.slide * w if p.sideways else 0.0)
        dy = (0.0 if p.sideways else p.slide * h) + (h - hl) / 2
        f2 = _Placed(b, f.rot, f.at((dx, 0.0, 0.0)))
        _slab(f2, p, w, hl, tl, dy, -t / 2 - tl + 0.005, (p.bezel * w / 2 + 0.02, 0.04, 0.06))
        back = t / 2
    elif p.style == "handset":  # a cordless handset: keypad end, its ear end bent to the front at the back edge
        top = h * (0.25 + 0.25 * p.lid_frac)
        low = h - top
        _slab(f, p, w, low + 0.02, t, 0.0, -t / 2, None)
        b.part("keys")
        _keypad(f, w - 0.08, 0.06, low * p.keypad_frac + 0.06, -t / 2)
        te = p.ear_thick
        ear = _Placed(b, f.rot @ rotation(X, -p.bend), f.at((0.0, low, t / 2)))
        b.part("body")
        _slab(ear, p, w, top, te, 0.0, -te, (0.04, top * 0.3, top * 0.3))
        if p.antenna:
            ear.cylinder((w / 2 - 0.05, top + p.antenna_h / 2 - 0.01, -te / 2), 0.0325, p.antenna_h / 2 + 0.01,
                         np.eye(3))
        back = t / 2
    else:  # flip: the keypad half, a hinge on its top front edge, the lid turned about it
        hl, tl = h * p.lid_frac * 0.52, p.lid_thick
        hb = h * 0.52
        _slab(f, p, w, hb, t, 0.0, -t / 2, None)
        b.part("keys")
        _keypad(f, w - 0.1, 0.05, hb * p.keypad_frac + 0.1, -t / 2)
        hinge = np.array([0.0, hb, -t / 2 + 0.01])
        lid = _Placed(b, f.rot @ rotation(X, -(math.pi - p.opening)), f.at(hinge))
        b.part("body")
        _slab(lid, p, w, hl, tl, 0.0, 0.0 if p.opening > 0 else -0.01, None)
        if p.opening > 0:  # the screen on the lid's inner face
            b.part("screen")
            lid.box((0, hl / 2 + 0.02, 0.0), (w / 2 - 0.05, hl / 2 - 0.08, 0.012), op="subtract")
        b.part("hinge")
        f.cylinder(hinge, p.hinge_r, w / 2 * 0.75, ALONG_X)
        back = t / 2
    if p.stand == "dock":  # a block or a round foot the phone stands in, maybe with a back rest
        b.part("stand")
        if p.dock_round:
            b.cylinder((0, base / 2, 0.0), max(p.stand_depth, w / 2 + 0.04), base / 2)
        else:
            b.box((0, base / 2, 0.0), (min(w * p.dock_w + 0.03, 0.45), base / 2, p.stand_depth / 2), rounding=0.02)
        if p.dock_back > 0:
            rest = h * p.dock_back
            zb = back + (p.battery if p.battery > 0 and p.battery_h > p.dock_back else 0.0) + p.strut_t / 2 - 0.01
            f.box((0, rest / 2, zb), (w * p.dock_w, rest / 2, p.strut_t / 2), rounding=0.01)
    b.part("camera")
    camera = "none" if p.style == "handset" else p.camera
    cs = p.camera_size * w
    cy = (h if p.style != "flip" else h * 0.52) - cs / 2 - 0.04
    wedge = min(p.taper * t, t - THICK) if p.style in ("slab", "candybar") and p.taper * t > 0.01 else 0.0
    at_back = lambda y: back - wedge * y / h  # noqa: E731  (the back's z at a height, a wedge's included)
    if camera == "square":
        f.box((p.camera_x * (w / 2 - cs / 2 - 0.03), cy, at_back(cy)), (cs / 2, cs / 2, p.camera_h), rounding=0.02)
    elif camera == "round":
        f.cylinder((p.camera_x * (w / 2 - cs / 2 - 0.03), cy, at_back(cy)), cs / 2, p.camera_h, ALONG_Z)
    elif camera == "strip":
        f.box((0, cy, at_back(cy)), (w / 2 - 0.02, cs / 3 + 0.0275, p.camera_h), rounding=0.02)
    if p.button and p.style != "handset":
        f.box((w / 2, h * 0.65 if p.style != "flip" else h * 0.35, 0.0), (0.0275, 0.06, 0.0275), rounding=0.01)
    if p.stand == "easel":  # a strut from the back down to the ground behind
        b.part("stand")
        top = f.at((0, h * p.strut_at, at_back(h * p.strut_at)))
        foot = np.array([0.0, 0.0, top[2] + top[1] * math.tan(0.55 - p.lean * 0.5)])
        d = foot - top
        strut = np.stack([np.array(X), d / np.linalg.norm(d), np.cross(X, d / np.linalg.norm(d))], axis=1)
        b.box((top + foot) / 2, (max(w * p.strut_w / 2, 0.04), np.linalg.norm(d) / 2, p.strut_t / 2), strut,
              rounding=0.01)


def _desk(b: CSGBuilder, p: PhoneParams) -> None:
    w, d, h = p.width, p.depth, p.thick
    b.part("body")
    b.box((0, h / 2, 0), (w / 2, h / 2, d / 2), rounding=0.03)
    side = p.layout == "side"
    x0 = -w / 2 + p.ledge * w if side else -w / 2 - 0.05  # the slope's left end
    z1 = d / 2 - (p.handset_r * 2 + 0.12 if p.layout == "across" else 0.06)  # the slope's back end
    drop = h * p.slope
    # the top slopes down to the front over [x0, w/2] x [-d/2, z1]
    theta = math.atan2(drop, z1 + d / 2)
    n = np.array([0.0, math.cos(theta), -math.sin(theta)])
    reach = drop / 2 + 0.05  # half the cut's depth: it clears the material over the plane, no more
    centre = np.array([(x0 + w / 2 + 0.05) / 2, h - drop / 2, (z1 - d / 2) / 2]) + n * reach
    slope = rotation(X, -theta)
    b.box(centre, ((w / 2 + 0.05 - x0) / 2, reach, (z1 + d / 2) / 2 + 0.1), slope, op="subtract")
    # keypad and display on the slope
    kx = (x0 + w / 2) / 2 if side else w * 0.15
    pad_w = min(0.34, (w / 2 - x0) * 0.8) if side else 0.34
    pad_d = (z1 + d / 2) * p.keypad_frac
    zk = -d / 2 + 0.04 + pad_d / 2
    on_slope = lambda x, z: np.array([x, h - drop * (z1 - z) / (z1 + d / 2), z])  # noqa: E731
    b.part("keys")
    b.box(on_slope(kx, zk), (pad_w / 2, 0.03, pad_d / 2), slope, rounding=0.01)
    if p.display:
        b.part("screen")
        zd = min(zk + pad_d / 2 + 0.08, z1 - 0.06)
        b.box(on_slope(kx, zd) + slope @ np.array([0, 0.03, 0]), (pad_w / 2, 0.03, 0.05), slope, rounding=0.01)
    b.part("handset")
    r, hl = p.handset_r, p.handset_len
    if p.layout == "upright":  # a cordless handset standing in a dock on the left
        dx, dz = -w / 2 + 0.12, d / 2 - 0.14
        b.box((dx, h + 0.04, dz), (0.09, 0.06, 0.08), rounding=0.02)
        b.box((dx, h + hl * 0.35, dz), (0.06 + r * 0.5, hl * 0.35, max(r, 0.035)), rounding=0.02)
        return
    if side:
        hx = -w / 2 + p.ledge * w / 2
        a, c = np.array([hx, 0, -d / 2 * hl + 0.06]), np.array([hx, 0, d / 2 * hl - 0.06])
        along = np.array([0.0, 0.0, 1.0])
    else:
        zh = d / 2 - r - 0.06
        a, c = np.array([-w / 2 * hl + 0.06, 0, zh]), np.array([w / 2 * hl - 0.06, 0, zh])
        along = np.array([1.0, 0.0, 0.0])
    hy = h + p.cradle_h + r
    b.capsule(a + [0, hy, 0], c + [0, hy, 0], r)
    for e in (a, c):  # ear and mouth pieces on cradle blocks: the handset bridges a gap (a hole)
        e = e - along * 0.02 * np.sign(along @ (e - (a + c) / 2))
        ext = np.abs(along) * 0.06 + (1 - np.abs(along)) * 0.07
        b.box(e + [0, hy - r * 0.6, 0], (ext[0], r * 0.8, ext[2]), rounding=0.02)
        b.box(e + [0, h + (p.cradle_h + 0.02) / 2 - 0.01, 0], (ext[0] + 0.01, (p.cradle_h + 0.02) / 2, ext[2] + 0.01),
              rounding=0.01)
    if p.cord:  # from the handset's end down to the base's side
        end = a + [0, hy, 0]
        if side:
            low = np.array([-w / 2 + 0.02, h * 0.4, -d / 2 + 0.1])
        else:
            low = np.array([end[0] - 0.04, h * 0.4, d / 2 - 0.02])
        b.capsule(end, low, 0.03)


def build(p: PhoneParams) -> CSGShape:
    b = CSGBuilder()
    if p.style == "desk":
        _desk(b, p)
    else:
        _hand_held(b, p)
    return b.shape()
