"""The procedural vessel, along z with the bow to -z, 1 long, the keel on y = 0. Six styles: "ship"
(one to four stacked deckhouse tiers anywhere from amidships to aft, zero to two funnels, one or two
masts, optional gun turrets; in 20% a carrier, a flight deck wider than the hull with the island to
starboard; in 12% a catamaran ferry), "tanker" (long flat deck, a stacked bridge aft, a funnel,
containers, a hatch block or a pipe deck, optional forecastle; ships and tankers have an open well
deck in 70%, its floor 0.2-0.7 of the depth), "sailboat" (narrow hull with a keel or, in 45%, a
catamaran; one or two masts with a mainsail each, 0.055-0.12 thick, sheeted out up to 0.7 rad, a
triangle or a gaff sail, an optional jib, cabin roof, an open cockpit aft in 60%), "speedboat" (V
hull or, in 40%, a tunnel hull; an open cockpit 0.25-0.75 of the length with its floor 0.25-0.75 of
the depth, raked windscreen, optional deckhouse, hard top and outboard motor), "rowboat" (an open
hull, walls 0.055-0.1, floor 0-0.4 of the depth, one to four thwarts, a transom or a pointed canoe
stern, optional oars or motor) and "submarine" (a capsule hull, a tail cone 1.5-4 radii long, a
sail and a cross of stern fins). Every hull draws its beam (0.07-0.5 of the length), depth
(0.05-0.21), bow length (0.08-0.5), flare, stem rake, V bottom, stern taper, a deck that falls aft
(sheer, in half of them) and a catamaran's tunnel (0.35-0.72 of the beam wide, 0.25-0.65 of the
depth high); superstructures draw their count, sizes and placement from continuous ranges.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, cut_beyond, X, Y, Z, ALONG_Z

STYLES = ("ship", "sailboat", "speedboat", "rowboat", "tanker", "submarine")
CARGO = ("none", "containers", "hatches", "pipes")


@dataclass(frozen=True)
class VesselParams:
    style: str
    length: float
    beam: float
    depth: float
    bow: float            # length of the pointed bow
    flare: float          # how far the bow's sides lean out (the side cuts' tilt)
    stem: float           # the stem's rake: the forefoot cut's height at the bow, fraction of depth
    v_rise: float         # V bottom: chine height, fraction of depth (0: flat)
    stern_taper: float    # length over which the stern narrows (0: a square transom)
    tiers: tuple[tuple[float, float, float, float], ...]  # superstructure: (z, half length, half width, height)
    funnels: tuple[tuple[float, float, float], ...]       # (z, radius, height)
    masts: tuple[tuple[float, float], ...]                # (z, height)
    turrets: tuple[float, ...]                            # z of each gun turret
    cargo: str            # CARGO
    cargo_h: float
    cargo_n: int
    forecastle: float     # length of a raised forecastle (0: none)
    sails: tuple[float, ...]  # per mast: the boom's length (sailboat)
    jib: bool
    cabin: float          # cabin / hardtop length (0: none)
    cabin_h: float
    cockpit: float        # cockpit / open hull length (0: decked)
    wall: float
    thwarts: int
    motor: bool
    keel: float           # keel depth (sailboat)
    sheer: float          # the deck falls by this fraction of the depth from amidships to the stern
    oars: float           # rowboat: the oars' angle back from across (0: no oars)
    fins: float           # submarine fin span
    jib_top: float = 0.85  # the jib's head, fraction of the mast
    screen_rake: float = 0.75  # the speedboat's windscreen tilt back (rad)
    deck_th: float = 0.0  # a carrier's flight deck: its thickness (0: none)
    deck_hw: float = 0.0  # and half width, wider than the hull
    tier_x: float = 0.0   # the superstructure's offset to starboard (a carrier's island)
    floor: float = 0.0    # an open well's floor over the keel, fraction of depth (cockpit, open hull, well deck)
    well_z0: float = 0.0  # a ship's or tanker's open well deck between these z (0, 0: none)
    well_z1: float = 0.0
    tunnel_w: float = 0.0  # a catamaran: the tunnel under the bridge deck, fraction of the beam (0: a monohull)
    tunnel_h: float = 0.0  # and its height, fraction of the depth
    sail_th: float = 0.055  # the sails' thickness
    sail_angle: float = 0.0  # the sails sheeted out to starboard or port (rad about the mast)
    gaff: float = 0.0     # a gaff sail's head, fraction of the boom (0: a triangle)


def sample(rng: np.random.Generator, style: str) -> VesselParams:
    u = lambda lo, hi: uniform(rng, lo, hi)  # noqa: E731
    length = 1.0
    tiers, funnels, masts, turrets, sails = (), (), (), (), ()
    cargo, cargo_h, cargo_n, forecastle, jib = "none", 0.0, 0, 0.0, False
    cabin, cabin_h, cockpit, wall, thwarts, motor, keel, fins = 0.0, 0.0, 0.0, 0.0, 0, False, 0.0, 0.0
    v_rise, stern_taper, flare, stem = 0.0, 0.0, u(0.0, 0.7), u(0.2, 1.0)
    sheer = u(0.0, 0.45) if chance(rng, 0.5) else 0.0
    oars, deck_th, deck_hw, tier_x, jib_top = 0.0, 0.0, 0.0, 0.0, 0.85
    floor, well_z0, well_z1, tunnel_w, tunnel_h = 0.0, 0.0, 0.0, 0.0, 0.0
    sail_th, sail_angle, gaff = 0.055, 0.0, 0.0
    wall = u(0.055, 0.11)
    if style in ("ship", "tanker"):
        beam, depth = u(0.1, 0.27), u(0.05, 0.19)
        bow = u(0.08, 0.35)
        stern_taper = u(0.0, 0.15)
        v_rise = u(0.2, 0.6) if chance(rng, 0.4) else 0.0
        n = int(rng.integers(1, 5)) if style == "ship" else int(rng.integers(1, 4))
        if style == "ship":
            z = u(-0.2, 0.25)
        else:
            z = u(0.3, 0.4)
        half, w = (u(0.06, 0.22) if style == "ship" else u(0.04, 0.12)), u(0.28, 0.46)
        tiers_l = []
        for k in range(n):
            h = u(0.057, 0.13)
            tiers_l.append((z, half, w * beam, h))
            z -= u(0.0, 0.5) * half if style == "ship" else u(0.0, 0.3) * half
            half, w = max(half * u(0.45, 0.85), 0.035), w * u(0.7, 1.0)
        tiers = tuple(tiers_l)
        top_z, top_half = tiers[-1][0], tiers[-1][1]
        nf = int(rng.choice([0, 1, 2], p=[0.2, 0.6, 0.2])) if style == "ship" else 1
        base_z = tiers[0][0] + tiers[0][1] * u(0.2, 0.6)
        funnels = tuple((base_z + k * u(0.08, 0.14), u(0.04, 0.055), u(0.08, 0.16)) for k in range(nf))
        masts = tuple((max(top_z - top_half * u(-0.3, 0.6) + k * u(-0.35, -0.2), -0.5 + bow + 0.05), u(0.1, 0.25))
                      for k in range(int(rng.integers(1, 3)) if style == "ship" else 1))
        carrier = style == "ship" and chance(rng, 0.2)
        if carrier:  # a flight deck over the hull, the island to starboard
            deck_th, deck_hw, sheer, nf = u(0.057, 0.08), beam * u(0.65, 0.9), 0.0, min(nf, 1)
            tiers = tuple((z, half, max(hw * 0.6, 0.04), h) for z, half, hw, h in tiers[:2])
            tier_x = deck_hw - max(tiers[0][2], 0.04) - u(0.0, 0.03)
            funnels = funnels[:nf]
        if style == "ship" and not carrier and chance(rng, 0.35):
            turrets = tuple(-0.5 + u(0.2, 0.3) + k * 0.12 for k in range(int(rng.integers(1, 3))))
        if style == "tanker":
            cargo = str(rng.choice(["containers", "hatches", "pipes"], p=[0.4, 0.3, 0.3]))
            cargo_h, cargo_n = u(0.06, 0.15), int(rng.integers(2, 6))
            forecastle = u(0.06, 0.14) if chance(rng, 0.5) else 0.0
        if not carrier and chance(rng, 0.7):  # an open well deck (holds) between the bow and the bridge
            depth = max(depth, u(0.1, 0.19))
            well_z0 = -0.5 + bow + max(forecastle, 0.0) + u(0.0, 0.1)
            well_z1 = tiers[0][0] - tiers[0][1] - u(0.0, 0.06)
            floor = u(0.2, 0.7)
            if well_z1 - well_z0 < 0.15:
                well_z0 = well_z1 = 0.0
        if style == "ship" and not carrier and chance(rng, 0.12):  # a catamaran ferry
            beam, tunnel_w, tunnel_h, v_rise = u(0.24, 0.36), u(0.35, 0.6), u(0.3, 0.6), 0.0
            depth = max(depth, 0.12)
    elif style == "sailboat":
        beam, depth = u(0.14, 0.32), u(0.055, 0.12)
        bow, v_rise, stern_taper = u(0.25, 0.45), u(0.2, 0.5), u(0.0, 0.2)
        two = chance(rng, 0.25)
        zm = -0.5 + u(0.25, 0.5)
        masts = ((zm, u(0.35, 0.9)),) + (((zm + u(0.25, 0.4), u(0.2, 0.5)),) if two else ())
        sails = tuple(u(0.18, 0.48) if k == 0 else u(0.1, 0.22) for k in range(len(masts)))
        jib_top = u(0.6, 0.95)
        jib = chance(rng, 0.7)
        cabin, cabin_h = u(0.12, 0.3), u(0.035, 0.07)
        keel = u(0.06, 0.14)
        sail_th, sail_angle = u(0.055, 0.12), u(-0.7, 0.7)
        gaff = u(0.15, 0.45) if chance(rng, 0.3) else 0.0
        if chance(rng, 0.45):  # a catamaran: a wide bridge deck over a tunnel between two hulls
            beam, depth, keel, v_rise = u(0.3, 0.5), u(0.08, 0.16), 0.0, 0.0
            tunnel_w, tunnel_h = u(0.4, 0.72), u(0.3, 0.65)
        fore = max(zm + cabin - 0.01, masts[-1][0] + 0.05)  # an open cockpit aft of the cabin and the masts
        cockpit, floor = min(u(0.12, 0.35), 0.5 - 1.5 * wall - fore), u(0.3, 0.75)
        if cockpit < 0.08 or chance(rng, 0.4):
            cockpit = 0.0
    elif style == "speedboat":
        beam, depth = u(0.22, 0.45), u(0.09, 0.2)
        bow, v_rise = u(0.2, 0.5), u(0.15, 0.5)
        cockpit, floor = min(u(0.25, 0.75), 0.94 - bow - 1.5 * wall), u(0.25, 0.75)
        sheer = 0.0
        if chance(rng, 0.4):  # a catamaran: a tunnel hull
            tunnel_w, tunnel_h, v_rise = u(0.35, 0.65), u(0.25, 0.55), u(0.0, 0.3)
        cabin = u(0.1, 0.25) if chance(rng, 0.4) else 0.0
        cabin_h = u(0.06, 0.1)
        if chance(rng, 0.5):  # a cabin cruiser: a deckhouse ahead of the cockpit
            half = u(0.08, 0.2)
            cockpit = min(cockpit, 0.5)
            tiers = ((0.5 - 1.5 * wall - cockpit - half + 0.01, half, beam * u(0.3, 0.42), u(0.057, 0.12)),)
        motor = chance(rng, 0.6)
    elif style == "rowboat":
        canoe = chance(rng, 0.3)
        beam, depth = (u(0.12, 0.2), u(0.07, 0.12)) if canoe else (u(0.25, 0.45), u(0.145, 0.21))
        bow = u(0.25, 0.4)
        stern_taper = u(0.2, 0.35) if canoe else u(0.03, 0.12)
        wall = u(0.055, 0.062) if canoe else u(0.055, 0.1)
        cockpit, floor = 1.0, u(0.0, 0.4)
        thwarts = int(rng.integers(1, 5)) if not canoe else int(rng.integers(1, 3))
        oars = u(0.2, 1.0) if not canoe and chance(rng, 0.45) else 0.0
        motor = not canoe and oars == 0 and chance(rng, 0.35)
    elif style == "submarine":
        beam = u(0.07, 0.2)
        sheer = 0.0
        depth = beam
        tiers = ((u(-0.3, 0.15), u(0.04, 0.15), max(beam * u(0.25, 0.4), 0.04), u(0.06, 0.2)),)
        fins = u(0.06, 0.2)
        stern_taper = u(1.5, 4.0)  # the tail cone's length in hull radii
        bow = 0.0
    else:
        raise ValueError(f"unknown vessel style {style!r}; expected one of {STYLES}")
    if tunnel_w > 0:  # each hull at least 0.075 wide
        tunnel_w = min(tunnel_w, 1.0 - 0.15 / beam)
    return VesselParams(
        style=style, length=length, beam=beam, depth=depth, bow=bow, flare=flare, stem=stem, v_rise=v_rise,
        stern_taper=stern_taper, tiers=tiers, funnels=funnels, masts=masts, turrets=turrets, cargo=cargo,
        cargo_h=cargo_h, cargo_n=cargo_n, forecastle=forecastle, sails=sails, jib=jib, cabin=cabin,
        cabin_h=cabin_h, cockpit=cockpit, wall=wall, thwarts=thwarts, motor=motor, keel=keel, fins=fins, sheer=sheer,
        oars=oars, deck_th=deck_th, deck_hw=deck_hw, tier_x=tier_x, jib_top=jib_top,
        screen_rake=u(0.45, 1.1), floor=floor, well_z0=well_z0, well_z1=well_z1, tunnel_w=tunnel_w,
        tunnel_h=tunnel_h, sail_th=sail_th, sail_angle=sail_angle, gaff=gaff)


def _hull(b: CSGBuilder, p: VesselParams) -> None:
    """A hull on y in [0, depth] along z: a box cut to a pointed bow, its stem raked, optionally a V
    bottom and a narrowed stern. The cuts stay below the deck (y = depth), so they miss masts and
    sails built before the hull."""
    length, beam, depth, bow = p.length, p.beam, p.depth, p.bow * p.length
    front = -length / 2
    b.box((0, depth / 2, 0), (beam / 2, depth / 2, length / 2))
    hy = depth / 2 + 0.005
    for s in (-1, 1):
        cut_beyond(b, (s * beam / 2, depth / 2, front + bow), (0, depth / 2, front), Y, (s, 0, -p.flare), hy,
                    margin=0.05)
    cut_beyond(b, (0, 0, front + bow * 1.2), (0, depth * p.stem, front), X, (0, -1, -1), beam / 2 + 0.01,
                margin=0.05)
    if p.v_rise > 0:
        for s in (-1, 1):
            cut_beyond(b, (s * beam / 2, depth * p.v_rise, 0), (0, 0, 0), Z, (s, -1, 0), length / 2 + 0.01,
                        margin=0.0)
    if p.sheer > 0:  # the deck falls aft of amidships (the cut's box stays below the sails' feet)
        drop = p.sheer * depth
        cut_beyond(b, (0, depth, 0.0), (0, depth - drop, length / 2), X, (0, 1, 0), beam / 2 + 0.01,
                    depth=drop + 0.015, margin=0.02)
    if p.tunnel_w > 0:  # a catamaran: two hulls under one bridge deck
        b.box((0, p.tunnel_h * depth / 2 - 0.01, 0), (p.tunnel_w * beam / 2, p.tunnel_h * depth / 2 + 0.01,
                                                     length / 2 + 0.05), op="subtract")
    if p.stern_taper > 0.01:
        taper = p.stern_taper * length
        for s in (-1, 1):
            cut_beyond(b, (s * beam / 2, depth / 2, length / 2 - taper), (s * beam * 0.3, depth / 2, length / 2), Y,
                        (s, 0, 1), hy, margin=0.02)


def build(p: VesselParams) -> CSGShape:
    b = CSGBuilder()
    if p.style == "submarine":
        return _submarine(b, p)
    front, depth, beam = -p.length / 2, p.depth, p.beam
    if p.style == "sailboat":  # the sails first: cut to triangles by planes that must miss the rest
        b.part("sails")
        zm, top = p.masts[0][0], depth + p.masts[0][1]
        th = p.sail_th / 2
        if p.jib:  # from the masthead to the bow
            jz = front + 0.08
            jt = depth + (top - depth) * p.jib_top
            b.box_between((-th, depth + 0.02, jz), (th, jt, zm))
            cut_beyond(b, (0, jt, zm), (0, depth + 0.02, jz), X, (0, 1, -1), 0.05)
        sheet = rotation(Y, p.sail_angle)  # the mainsails swing out about their masts
        aft, across, up_aft = sheet @ np.array(Z), sheet @ np.array(X), sheet @ np.array([0.0, 1.0, 1.0])
        for (z, h), boom in zip(p.masts, p.sails):
            foot, mtop = depth + 0.08, depth + h
            heel = np.array([0.0, 0.0, z])
            b.box(heel + np.array([0, (foot + mtop) / 2, 0]) + aft * boom / 2, (th, (mtop - foot) / 2, boom / 2), sheet)
            cut_beyond(b, heel + np.array([0, mtop, 0]) + aft * boom * p.gaff, heel + np.array([0, foot, 0]) + aft * boom,
                       across, up_aft, 0.06)
    b.part("hull")
    _hull(b, p)
    well = _well(p)
    if well is not None:  # an open hull, a cockpit or a well deck: a hollow open at the top
        z0, z1, floor = well
        wall = max(p.wall, 0.055)
        top = depth + (0.015 if p.style == "sailboat" else 0.1)  # (clear of the sails' feet)
        b.box_between((-beam / 2 + wall, floor, z0), (beam / 2 - wall, top, z1), op="subtract")
    if p.cockpit > 0:
        b.part("seats")
        for k in range(p.thwarts):  # seats across the open hull (holes under them)
            z = z0 + (z1 - z0) * (k + 0.6) / (p.thwarts + 0.2)
            b.box((0, depth - 0.033, z), (beam / 2 - wall / 2, 0.0285, 0.04))
    if p.oars > 0:  # through the gunwales, blades down in the water
        b.part("oars")
        z = front + p.bow * p.length + 0.5 * (p.length / 2 - front - p.bow * p.length)
        for s in (-1, 1):
            tip = np.array([s * (beam / 2 + 0.22), -0.02, z + 0.22 * np.sin(p.oars)])
            b.rod((0, depth - 0.03, z), tip, 0.0285)
    if p.keel > 0 and p.tunnel_w == 0:
        b.part("hull")
        zm = p.masts[0][0]
        b.box((0, -p.keel / 2 + 0.02, zm + 0.05), (0.0285, p.keel / 2 + 0.02, 0.09))

    b.part("deck")
    if p.deck_th > 0:
        z0 = front + p.bow * 0.5
        b.box((0, depth + p.deck_th / 2 - 0.005, (z0 + 0.49) / 2), (p.deck_hw, p.deck_th / 2, (0.49 - z0) / 2))
    y = depth + p.deck_th
    for k, (z, half, hw, h) in enumerate(p.tiers):  # stacked: each on the one before
        lo = _base_y(p, z - half, z + half) if k == 0 else y  # down to a deck that falls aft, or a well's floor
        b.box((p.tier_x, (lo + y + h) / 2 - 0.005, z), (max(hw, 0.04), (y + h - lo) / 2, half), rounding=0.01)
        y += h - 0.005
    if p.forecastle > 0:
        b.box((0, depth + 0.025, front + p.bow * 0.6 + p.forecastle / 2), (beam * 0.3, 0.0285, p.forecastle / 2))
    if p.cargo == "containers":  # stacks across the deck between bow and bridge
        z0, z1 = front + p.bow + 0.03, p.tiers[0][0] - p.tiers[0][1] - 0.03
        n = max(1, min(p.cargo_n, int((z1 - z0) / 0.08)))
        span = (z1 - z0) / n
        for k in range(n):
            zc = z0 + span * (k + 0.5)
            lo = _base_y(p, zc - span * 0.42, zc + span * 0.42) - 0.005
            b.box((0, (lo + depth + p.cargo_h) / 2, zc), (beam * 0.42, (depth + p.cargo_h - lo) / 2, span * 0.42))
    elif p.cargo == "hatches":
        z0, z1 = front + p.bow + 0.03, p.tiers[0][0] - p.tiers[0][1] - 0.03
        lo = _base_y(p, z0, z1) - 0.005
        top = depth + max(p.cargo_h * 0.5, 0.057)
        b.box((0, (lo + top) / 2, (z0 + z1) / 2), (beam * 0.4, (top - lo) / 2, (z1 - z0) / 2))
    elif p.cargo == "pipes":  # a catwalk down the middle
        z0, z1 = front + p.bow * 0.8, p.tiers[0][0] - p.tiers[0][1]
        lo = _base_y(p, z0, z1) - 0.005
        b.box((0, (lo + depth + 0.06) / 2, (z0 + z1) / 2), (0.0285, (depth + 0.06 - lo) / 2, (z1 - z0) / 2))
    if p.cabin > 0:
        if p.style == "sailboat":
            zc = p.masts[0][0] + p.cabin / 2 - 0.03
            lo = _deck_y(p, zc + p.cabin / 2) - 0.02
            b.box((0, (lo + depth + p.cabin_h) / 2, zc), (beam * 0.32, (depth + p.cabin_h - lo) / 2, p.cabin / 2),
                  rounding=0.02)
        else:  # a hard top over the cockpit's front on two posts (holes)
            z1 = p.length / 2 - 1.5 * max(p.wall, 0.055) - p.cockpit
            zc = z1 + p.cabin / 2
            b.box((0, depth + p.cabin_h + 0.03, zc), (beam / 2 - 0.04, 0.0285, p.cabin / 2))
            b.box((0, depth + (p.cabin_h + 0.03) / 2, zc + p.cabin / 2 - 0.03), (beam / 2 - 0.04, (p.cabin_h + 0.03) / 2,
                                                                               0.0285))
    if p.style == "speedboat":
        z1 = p.length / 2 - 1.5 * max(p.wall, 0.055) - p.cockpit
        ws = rotation(X, -p.screen_rake)
        b.box(np.array([0.0, depth + 0.04, z1 + 0.02]), (beam / 2 - 0.04, 0.05, 0.0275), ws, rounding=0.01)
    if p.motor:
        b.part("motor")
        b.box((0, depth + 0.02, p.length / 2 + 0.04), (0.05, 0.06, 0.05), rounding=0.02)
        b.box((0, depth * 0.2, p.length / 2 + 0.04), (0.0285, depth * 0.6, 0.03))
    if p.funnels or p.masts and p.style != "sailboat" or p.turrets:
        b.part("fittings")
    for z, r, h in p.funnels:
        y1 = _deck_at(p, z)
        b.cylinder((p.tier_x, y1 + h / 2 - 0.01, z), r, h / 2, rotation(X, 0.15))
    if p.style == "sailboat":
        b.part("masts")
        for z, h in p.masts:
            lo = _deck_y(p, z) - 0.01
            b.cylinder((0, (lo + depth + h) / 2, z), 0.0285, (depth + h - lo) / 2)
            b.box(np.array([0, depth + 0.05, z]) + sheet @ np.array([0, 0, 0.1]), (0.0285, 0.03, 0.12), sheet)  # boom
    else:
        for z, h in p.masts:
            y_top = _deck_at(p, z)
            b.cylinder((p.tier_x, y_top + h / 2 - 0.01, z), 0.0285, h / 2)
            b.box((p.tier_x, y_top + h * 0.7, z), (0.08, 0.0285, 0.0285))  # yard
    for tz in p.turrets:
        lo = _base_y(p, tz - 0.05, tz + 0.05) - 0.005
        b.cylinder((0, (lo + depth + 0.06) / 2, tz), 0.05, (depth + 0.06 - lo) / 2)
        b.cylinder((0, depth + 0.035, tz - 0.08), 0.0285, 0.06, ALONG_Z)
    return b.shape()


def _deck_at(p: VesselParams, z: float) -> float:
    """The height of the superstructure's top at z (the deck where no tier covers z)."""
    y = _deck_y(p, z)
    for tz, half, _, h in p.tiers:
        if abs(z - tz) > half - 0.02:
            break
        y = max(y, p.depth + p.deck_th) + h - 0.005
    return y


def _well(p: VesselParams) -> tuple[float, float, float] | None:
    """An open well's z0, z1 and floor height, or None."""
    wall, front, depth = max(p.wall, 0.055), -p.length / 2, p.depth
    if p.style == "rowboat":
        z0 = front + p.bow * p.length + 0.01
        z1 = p.length / 2 - max(p.stern_taper * p.length, 0.0) - wall
    elif p.cockpit > 0:
        z1 = p.length / 2 - wall * 1.5
        z0 = z1 - p.cockpit
    elif p.well_z1 > p.well_z0:
        z0, z1 = p.well_z0, p.well_z1
    else:
        return None
    lowest = max(wall, depth * p.v_rise * 0.75 + 0.06, depth * p.tunnel_h + 0.06 if p.tunnel_w > 0 else 0.0)
    floor = max(p.floor * depth, lowest)
    return (z0, z1, floor) if floor < depth - 0.03 or p.style == "rowboat" else None  # (none in too shallow a hull)


def _base_y(p: VesselParams, z0: float, z1: float) -> float:
    """What a part over z0..z1 stands on: the deck (at z1, where it falls aft) or a well's floor."""
    well = _well(p)
    if well is not None and p.style in ("ship", "tanker") and z0 < well[1] and z1 > well[0]:
        return min(well[2], _deck_y(p, z1))
    return _deck_y(p, z1)


def _deck_y(p: VesselParams, z: float) -> float:
    """The deck's height at z: level, or falling aft of amidships by ``sheer``."""
    return p.depth * (1.0 - p.sheer * max(z, 0.0) / (p.length / 2)) + p.deck_th


def _submarine(b: CSGBuilder, p: VesselParams) -> CSGShape:
    r = p.beam / 2
    b.part("hull")
    tail = p.stern_taper * r
    b.capsule((0, r, -0.5 + r), (0, r, 0.5 - tail), r)
    b.cone((0, r, 0.5 - tail / 2), tail / 2, r, 0.03, ALONG_Z)
    b.part("deck")
    z, half, hw, h = p.tiers[0]
    b.box((0, 2 * r + h / 2 - 0.02, z), (hw, h / 2 + 0.02, half), rounding=0.02)
    b.box((0, 2 * r + h * 0.6, z), (hw + 0.06, 0.0285, 0.04))  # dive planes on the sail
    b.part("fins")
    zf = 0.5 - 0.6 * tail
    b.box((0, r, zf), (r + p.fins / 2, 0.0285, 0.045))
    b.box((0, r, zf), (0.0285, r + p.fins / 2, 0.045))
    return b.shape()
