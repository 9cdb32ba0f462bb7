"""The procedural car: length along z (1 raw unit), bonnet to -z, a lower body on wheels and a
greenhouse (cabin) on it, in six styles: "sedan" (three boxes: bonnet, cabin, boot; from upright
saloons to low wide coupes, 40% convertibles), "hatchback" (the cabin runs to the tail: hatchbacks,
wagons, SUVs, 30% with the roof off), "pickup" (single or crew cab, an open bed, maybe under a
canopy), "van" (one box: minivans, vans, buses), "truck" (a cab and a separate load 0.6-1 of the
frame long: closed box, open box, tank or flat deck; one or two rear axles) and "open" (roadsters
and jeeps: an open cockpit behind a windscreen frame, maybe a roll bar). Drawn per object: width
0.26-0.66 of the length, wheel radius 0.045-0.19 and width 0.055-0.15, tyres in arches or standing
0.02-0.08 out of the body, clearance 0.2-1.6 wheel radii, overhangs 0.02-0.26, sill-to-beltline
height 0.06-0.34 (raised over the arches), cabin start, length (0.16 to the whole body), height
0.06-0.52, windscreen and rear-window runs, tumblehome 0-0.14, bonnet and boot drops and lengths,
body rounding 0.01-0.09, bed and cockpit wells 0.05-0.2 deep with walls 0.055-0.12, in 55% of
closed cabins the glass out (side windows through a hollow cabin, pillars and roof 0.055-0.1, the
hollow 0-0.25 into the body), in 85% a hollow under the floor open below (skirts 0.055-0.16, 0.2-1
of the room up to the floor; behind the glass, in half, the cabin hollow down to it), and optional
roof racks or roof boxes, spoilers (a lip or a wing on posts), a spare wheel on the tail and a bull
bar.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import MIN_PART, uniform, chance, cut_beyond, X, ALONG_X, ALONG_Z

STYLES = ("sedan", "hatchback", "pickup", "van", "truck", "open")
HALF_LEN = 0.5
ARCH_GAP = 0.01  # the arch's radius over the tyre's
ARCH_LIFT = 0.025  # the arch's centre over the axle: the tyre touches the body at the arch's lower corners
THICK = 0.06  # walls, slabs, posts: a little over MIN_PART

# Per style: (lo, hi) of the draws that differ between styles.
_RANGES = {
    #               width         wheel_r        clear (x r)  body_h        cab_h         tumble
    "sedan":     ((0.32, 0.64), (0.05, 0.12), (0.2, 0.7), (0.06, 0.24), (0.06, 0.2), (0.01, 0.14)),
    "hatchback": ((0.34, 0.66), (0.055, 0.16), (0.25, 1.5), (0.08, 0.3), (0.07, 0.28), (0.01, 0.13)),
    "pickup":    ((0.32, 0.62), (0.065, 0.19), (0.4, 1.6), (0.1, 0.28), (0.09, 0.24), (0.0, 0.08)),
    "van":       ((0.26, 0.6), (0.045, 0.12), (0.2, 0.7), (0.08, 0.34), (0.14, 0.52), (0.0, 0.06)),
    "truck":     ((0.26, 0.52), (0.055, 0.12), (0.4, 1.6), (0.06, 0.16), (0.16, 0.46), (0.0, 0.05)),
    "open":      ((0.36, 0.66), (0.055, 0.18), (0.3, 1.6), (0.08, 0.28), (0.07, 0.17), (0.0, 0.02)),
}


@dataclass(frozen=True)
class CarParams:
    style: str
    width: float
    wheel_r: float
    wheel_w: float
    wheel_out: float     # how far the tyres stand out of the body side; <= 0: inside arches
    clearance: float     # body bottom over the ground
    body_h: float        # sill to beltline (raised where the arches or a bed need room)
    overhang_f: float    # nose to the front tyre, tail to the rear tyre
    overhang_r: float
    rear_axles: int
    body_round: float
    nose_drop: float     # the bonnet slopes down by nose_drop over nose_len
    nose_len: float
    tail_drop: float
    tail_len: float
    cab_z0: float        # the greenhouse's base, front and back
    cab_z1: float
    cab_h: float
    screen_run: float    # windscreen and rear window: run along z over the cabin height
    rear_run: float
    tumble: float        # cabin inset from the body side
    cargo: str           # "none", "bed", "cockpit" (open top), "box", "open", "tank", "flat"
    cargo_z0: float
    cargo_h: float
    cargo_w: float
    cargo_len: float     # a truck's load over the frame behind the cab
    well: float          # depth of a bed or an open cockpit
    roof: str            # "none", "rack", "pod"
    roof_len: float
    roof_h: float
    pod_w: float         # a roof box's width over the roof's
    spoiler: str         # "none", "lip", "wing"
    spoiler_h: float
    spare: bool
    spare_x: float
    bullbar: bool
    rollbar: bool
    canopy: bool         # a pickup's bed under a cover as high as the cab
    wall: float = THICK  # the walls of a bed or an open cockpit
    open_cab: bool = False  # the glass out: side windows through the cabin, hollow inside
    pillar: float = THICK  # an open cabin's roof and pillars
    sink: float = 0.0    # how far an open cabin's hollow reaches down into the body
    under: float = 0.0   # a hollow under the floor between the axles, fraction of the room there (0: none)
    skirt: float = THICK  # the body's walls round that hollow
    shell: bool = False  # a closed cabin hollow too, open to the hollow under the floor: the car a shell


def sample(rng: np.random.Generator, style: str) -> CarParams:
    (w0, w1), (r0, r1), (k0, k1), (h0, h1), (c0, c1), (t0, t1) = _RANGES[style]
    width, wheel_r = uniform(rng, w0, w1), uniform(rng, r0, r1)
    wheel_w = uniform(rng, 0.055, 0.15 if style in ("open", "pickup", "truck") else 0.1)
    proud = {"open": 0.7, "hatchback": 0.35, "pickup": 0.4, "truck": 0.3, "sedan": 0.1}.get(style, 0.0)
    wheel_out = uniform(rng, 0.02, 0.08) if chance(rng, proud) else uniform(rng, -0.01, 0.01)
    nose_drop = nose_len = tail_drop = tail_len = 0.0
    rear_axles, cargo, cargo_z0, cargo_h, cargo_w, cargo_len, well = 1, "none", 0.0, 0.0, 0.0, 1.0, 0.0
    rollbar = False
    wall = uniform(rng, MIN_PART, 0.12)
    if style == "sedan":
        z0, z1 = uniform(rng, -0.32, 0.0), uniform(rng, 0.05, 0.38)
        runs = uniform(rng, 0.08, 0.35), uniform(rng, 0.04, 0.35)
        nose_drop, nose_len = uniform(rng, 0.01, 0.1), uniform(rng, 0.1, 0.5)
        tail_drop, tail_len = uniform(rng, 0.0, 0.08), uniform(rng, 0.05, 0.25)
        of, orr = uniform(rng, 0.05, 0.22), uniform(rng, 0.05, 0.26)
        if chance(rng, 0.4):  # a convertible
            cargo, well, rollbar = "cockpit", uniform(rng, 0.05, 0.16), chance(rng, 0.3)
    elif style == "hatchback":
        z0, z1 = uniform(rng, -0.32, -0.05), HALF_LEN - uniform(rng, 0.0, 0.18)
        runs = uniform(rng, 0.07, 0.3), uniform(rng, 0.0, 0.28)
        nose_drop, nose_len = uniform(rng, 0.0, 0.09), uniform(rng, 0.08, 0.45)
        of, orr = uniform(rng, 0.03, 0.2), uniform(rng, 0.02, 0.18)
        if chance(rng, 0.3):  # roof off
            cargo, well, rollbar = "cockpit", uniform(rng, 0.05, 0.16), chance(rng, 0.6)
    elif style == "pickup":
        z0 = uniform(rng, -0.28, -0.08)
        z1 = z0 + uniform(rng, 0.18, 0.42)
        runs = uniform(rng, 0.06, 0.18), uniform(rng, 0.0, 0.03)
        nose_drop, nose_len = uniform(rng, 0.0, 0.04), uniform(rng, 0.1, 0.25)
        of, orr = uniform(rng, 0.04, 0.16), uniform(rng, 0.04, 0.2)
        cargo, cargo_z0, well = "bed", z1 + uniform(rng, 0.0, 0.04), uniform(rng, 0.06, 0.2)
    elif style == "van":
        z0, z1 = -HALF_LEN + uniform(rng, 0.0, 0.32), HALF_LEN - uniform(rng, 0.0, 0.04)
        runs = uniform(rng, 0.02, 0.35), uniform(rng, 0.0, 0.18)
        nose_drop, nose_len = uniform(rng, 0.0, 0.05), uniform(rng, 0.08, 0.2)
        of, orr = uniform(rng, 0.03, 0.16), uniform(rng, 0.03, 0.2)
    elif style == "truck":
        z0 = -HALF_LEN + uniform(rng, 0.0, 0.22)
        z1 = z0 + uniform(rng, 0.16, 0.3)
        runs = uniform(rng, 0.01, 0.08), 0.0
        of, orr = uniform(rng, 0.02, 0.12), uniform(rng, 0.04, 0.2)
        rear_axles = 2 if chance(rng, 0.5) else 1
        cargo = str(rng.choice(["box", "box", "open", "tank", "flat"]))
        cargo_z0, cargo_h = z1 + uniform(rng, 0.02, 0.08), uniform(rng, 0.14, 0.45)
        cargo_w, well = uniform(rng, 0.85, 1.12), uniform(rng, 0.06, 0.2)
        cargo_len = uniform(rng, 0.6, 1.0)
    else:  # open
        z0 = uniform(rng, -0.22, 0.0)
        z1 = max(uniform(rng, 0.08, 0.36), z0 + 0.22)  # room for the seats behind the windscreen frame
        runs = uniform(rng, 0.02, 0.12), 0.0
        nose_drop, nose_len = uniform(rng, 0.0, 0.08), uniform(rng, 0.1, 0.3)
        tail_drop, tail_len = uniform(rng, 0.0, 0.05), uniform(rng, 0.05, 0.2)
        of, orr = uniform(rng, 0.02, 0.16), uniform(rng, 0.02, 0.18)
        cargo, well, rollbar = "cockpit", uniform(rng, 0.05, 0.16), chance(rng, 0.5)
    closed = cargo != "cockpit"
    roof = (str(rng.choice(["none", "rack", "pod", "pod"] if style == "van" else ["none", "rack", "pod"]))
            if closed and style != "truck" else "none")
    has_spoiler = style in ("sedan", "open") or (style == "hatchback" and closed)
    spoiler = str(rng.choice(["none", "lip", "wing"])) if has_spoiler else "none"
    return CarParams(
        style=style, width=width, wheel_r=wheel_r, wheel_w=wheel_w, wheel_out=wheel_out,
        clearance=wheel_r * uniform(rng, k0, k1), body_h=uniform(rng, h0, h1),
        overhang_f=of, overhang_r=orr, rear_axles=rear_axles, body_round=uniform(rng, 0.01, 0.09),
        nose_drop=nose_drop, nose_len=nose_len, tail_drop=tail_drop, tail_len=tail_len,
        cab_z0=z0, cab_z1=z1, cab_h=uniform(rng, c0, c1), screen_run=runs[0], rear_run=runs[1],
        tumble=uniform(rng, t0, t1), cargo=cargo, cargo_z0=cargo_z0, cargo_h=cargo_h, cargo_w=cargo_w,
        cargo_len=cargo_len,
        well=well, roof=roof, roof_len=uniform(rng, 0.35, 1.0), roof_h=uniform(rng, THICK, 0.16),
        pod_w=uniform(rng, 0.5, 0.97),
        spoiler=spoiler, spoiler_h=uniform(rng, 0.03, 0.1),
        spare=style in ("hatchback", "van", "open") and chance(rng, 0.4), spare_x=uniform(rng, -0.1, 0.1),
        bullbar=style in ("hatchback", "pickup", "truck", "open") and chance(rng, 0.35), rollbar=rollbar,
        canopy=cargo == "bed" and chance(rng, 0.3), wall=wall,
        open_cab=closed and chance(rng, 0.55), pillar=uniform(rng, MIN_PART, 0.1), sink=uniform(rng, 0.0, 0.25),
        under=uniform(rng, 0.2, 1.0) if chance(rng, 0.85) else 0.0, skirt=uniform(rng, MIN_PART, 0.16),
        shell=chance(rng, 0.5))


def build(p: CarParams) -> CSGShape:
    b = CSGBuilder()  # the body first: the largest row, which lets the SDF skip rows far from a point
    w2, rw = p.width / 2, p.wheel_r
    yb = p.clearance
    # the axles: the front one behind the nose's overhang, the rear ones (tandem: a tyre apart) before the tail's
    zf = -HALF_LEN + p.overhang_f + rw
    zr = [HALF_LEN - p.overhang_r - rw - k * (2 * rw + 0.03) for k in range(p.rear_axles)]
    axles = [zf] + zr
    # arches where the tyres sit under the body; the tyre then touches the body at the arch's lower
    # corners only while the body reaches down far enough (a lifted body rests on its tyres instead)
    arches = p.wheel_out < p.wheel_w / 2 and yb <= 0.6 * rw
    # the beltline stays over the arches (and a bed's floor over the tyres), or the cuts go through the body
    yt = yb + p.body_h
    if arches:
        yt = max(yt, 2 * rw + ARCH_LIFT + ARCH_GAP + MIN_PART)
    if p.cargo in ("bed", "cockpit"):
        yt = max(yt, 2 * rw + ARCH_LIFT + ARCH_GAP + p.well + THICK)
    floor = lowest = yt  # an open cabin's floor; the lowest any hollow from above reaches
    arch_top = 2 * rw + ARCH_LIFT + ARCH_GAP if arches else yb
    z0, z1, ch = p.cab_z0, p.cab_z1, p.cab_h
    if p.nose_drop > 0:
        z0 = max(z0, -HALF_LEN + p.nose_len + 0.05)
    if p.tail_drop > 0:
        z1 = min(z1, HALF_LEN - p.tail_len - 0.05)
    cw = w2 - p.tumble

    b.part("body")
    b.box((0, (yb + yt) / 2, 0), (w2, (yt - yb) / 2, HALF_LEN), rounding=p.body_round)
    if p.nose_drop > 0.005:  # the bonnet slopes down to the nose
        cut_beyond(b, (0, yt - p.nose_drop, -HALF_LEN), (0, yt, -HALF_LEN + p.nose_len), X, (0, 1, -0.2),
                   w2 + 0.01, depth=p.nose_drop + 0.05, margin=0.04)
    if p.tail_drop > 0.005:  # and the boot to the tail
        cut_beyond(b, (0, yt - p.tail_drop, HALF_LEN), (0, yt, HALF_LEN - p.tail_len), X, (0, 1, 0.2),
                   w2 + 0.01, depth=p.tail_drop + 0.05, margin=0.04)
    if arches:
        for z in axles:
            b.cylinder((0, rw + ARCH_LIFT, z), rw + ARCH_GAP, w2 + 0.05, ALONG_X, op="subtract")
    if p.cargo in ("bed", "cockpit"):  # an open bed or cockpit: a well with walls all round
        zw0 = p.cargo_z0 if p.cargo == "bed" else z0 + 0.02
        zw1 = HALF_LEN - p.wall if p.cargo == "bed" else z1
        lowest = yt - p.well
        b.box_between((-w2 + p.wall, lowest, zw0), (w2 - p.wall, yt + 0.02, zw1), op="subtract")
    if p.open_cab:  # the glass out: the cabin's hollow reaches down into the body
        floor = max(yt - p.sink, arch_top + MIN_PART, yb + MIN_PART)
        lowest = min(lowest, floor)
    room = min(lowest, yt - p.nose_drop, yt - p.tail_drop) - MIN_PART - yb
    under_top = yb + p.under * room if p.under > 0 and room > 0.03 else None
    if under_top is not None:  # the body a shell over a hollow under the floor, open below
        b.box_between((-w2 + p.skirt, yb - 0.01, -HALF_LEN + p.skirt), (w2 - p.skirt, yb + p.under * room,
                                                                        HALF_LEN - p.skirt), op="subtract")

    if p.cargo != "cockpit":  # the greenhouse: its window cuts run from its base up, clear of the body
        b.part("cabin")
        b.box((0, yt + (ch - 0.03) / 2, (z0 + z1) / 2), (cw, (ch + 0.03) / 2, (z1 - z0) / 2),
              rounding=min(0.05, p.body_round))
        run_f = min(p.screen_run, 0.45 * (z1 - z0))
        # (the cuts are only as deep as the cabin they shape: a smaller row is skipped at more points)
        cut_beyond(b, (0, yt, z0), (0, yt + ch + 0.1, z0 + run_f * (1 + 0.1 / ch)), X, (0, 0.3, -1), w2,
                   depth=run_f * ch / np.hypot(run_f, ch) + 0.06, margin=0.0)
        run_r = min(p.rear_run, 0.45 * (z1 - z0))
        if run_r > 0.01:
            cut_beyond(b, (0, yt, z1), (0, yt + ch + 0.1, z1 - run_r * (1 + 0.1 / ch)), X, (0, 0.3, 1), w2,
                       depth=run_r * ch / np.hypot(run_r, ch) + 0.06, margin=0.0)
        wz0, wz1 = z0 + run_f * 0.75 + 0.03, z1 - run_r * 0.75 - 0.03
        if wz1 - wz0 > 0.1:  # side windows: shallow recesses that outline the glass in a render, or openings
            b.part("windows")
            if p.open_cab:
                b.box((0, yt + ch * 0.5, (wz0 + wz1) / 2), (cw + 0.01, ch * 0.27, (wz1 - wz0) / 2), op="subtract")
            else:
                for s in (-1, 1):
                    b.box((s * cw, yt + ch * 0.5, (wz0 + wz1) / 2), (0.012, ch * 0.27, (wz1 - wz0) / 2),
                          op="subtract")
        if p.open_cab and ch > p.pillar + 0.04 and wz1 - wz0 > 0.1:  # hollow inside under a roof and pillars
            b.part("interior")
            b.box_between((-cw + p.pillar, floor, z0 + p.pillar), (cw - p.pillar, yt + ch - p.pillar, z1 - p.pillar),
                          op="subtract")
        elif p.shell and not p.open_cab and under_top is not None and ch > p.pillar + 0.04 and wz1 - wz0 > 0.1:
            # behind the glass the cabin is hollow down to the hollow under the floor (unseen from outside)
            b.box_between((-cw + p.pillar, under_top - 0.02, z0 + run_f + p.pillar),
                          (cw - p.pillar, yt + ch - p.pillar, z1 - run_r - p.pillar), op="subtract")

    if p.canopy:  # a cover over the bed
        b.part("cargo")
        b.box_between((-cw, yt - 0.02, p.cargo_z0 + 0.01), (cw, yt + ch * 0.9, HALF_LEN - 0.01),
                      rounding=min(0.03, p.body_round))
    if p.cargo in ("box", "open", "tank", "flat"):
        b.part("cargo")
        zc1 = p.cargo_z0 + (HALF_LEN - 0.01 - p.cargo_z0) * p.cargo_len
        hw = min(p.width * p.cargo_w, 0.62) / 2
        if p.cargo == "flat":
            b.box_between((-hw, yt - 0.02, p.cargo_z0), (hw, yt + THICK, zc1), rounding=0.01)
        elif p.cargo == "tank":
            r = min(hw, p.cargo_h / 2 + 0.03)
            b.cylinder((0, yt + r - 0.01, (p.cargo_z0 + zc1) / 2), r, (zc1 - p.cargo_z0) / 2, ALONG_Z)
        else:
            b.box_between((-hw, yt - 0.02, p.cargo_z0), (hw, yt + p.cargo_h, zc1), rounding=0.015)
            if p.cargo == "open":
                b.box_between((-hw + THICK, yt + p.cargo_h - p.well, p.cargo_z0 + THICK),
                              (hw - THICK, yt + p.cargo_h + 0.1, zc1 - THICK), op="subtract")

    b.part("trim")
    if p.cargo == "cockpit":  # a windscreen frame leaning back, and maybe a roll bar behind the seats
        lean = rotation(X, 0.35 + 2.5 * p.screen_run)
        hh = ch / 2 + 0.02
        b.box(np.array([0, yt - 0.02, z0 + 0.01]) + lean @ np.array([0, hh, 0]), (w2 - 0.02, hh, THICK / 2), lean,
              rounding=0.01)
        if p.rollbar:
            zb = z1 - 0.02
            b.box((0, yt + ch / 2, zb), (w2 - 0.03, ch / 2 + 0.02, THICK / 2), rounding=0.02)
            b.box_between((-w2 + 0.03 + THICK, yt, zb - THICK), (w2 - 0.03 - THICK, yt + ch - 0.04, zb + THICK),
                          op="subtract")
    roof_y = yt + ch
    flat0 = z0 + min(p.screen_run, 0.45 * (z1 - z0))
    flat1 = z1 - min(p.rear_run, 0.45 * (z1 - z0))
    if p.roof != "none" and flat1 - flat0 > 0.12:
        zl = (flat1 - flat0) * p.roof_len / 2
        zm = (flat0 + flat1) / 2
        if p.roof == "rack":
            b.box((0, roof_y + THICK / 2 - 0.005, zm), (cw - 0.01, THICK / 2, zl), rounding=0.01)
        else:
            b.box((0, roof_y + p.roof_h / 2 - 0.01, zm), (cw * p.pod_w, p.roof_h / 2, zl), rounding=0.025)
    if p.spoiler != "none":
        if p.style == "hatchback":  # a lip over the tailgate
            b.box((0, roof_y - 0.01, flat1 + 0.02), (cw - 0.01, THICK / 2, 0.04 + p.spoiler_h / 2), rounding=0.01)
        else:
            zs, ys = HALF_LEN - 0.06, yt - p.tail_drop
            if p.spoiler == "lip":
                b.box((0, ys + 0.01, zs + 0.02), (w2 - 0.02, THICK / 2, 0.05), rounding=0.01)
            else:  # a wing on two posts
                for s in (-1, 1):
                    b.box((s * w2 * 0.6, ys + p.spoiler_h / 2, zs), (THICK / 2, p.spoiler_h / 2 + 0.01, THICK / 2))
                b.box((0, ys + p.spoiler_h + THICK / 2, zs + 0.01), (w2 - 0.01, THICK / 2, 0.06), rounding=0.01)
    if p.spare:  # on the tail, a little off centre
        r = min(rw * 0.95, (yt - p.tail_drop - yb) / 2 + 0.04)
        b.cylinder((p.spare_x * p.width, yb + (yt - p.tail_drop - yb) / 2 + 0.02, HALF_LEN + 0.03), r, 0.04, ALONG_Z)
    if p.bullbar:
        yn = yt - p.nose_drop
        b.box((0, yb + (yn - yb) * 0.55, -HALF_LEN - 0.025), (w2 * 0.7, (yn - yb) * 0.45, 0.035), rounding=0.015)

    b.part("wheels")
    x = w2 + p.wheel_out - p.wheel_w / 2
    for z in axles:
        for s in (-1, 1):
            b.cylinder((s * x, rw, z), rw, p.wheel_w / 2, ALONG_X)
    return b.shape()
