"""The procedural vessel (see ``make_vessel`` for its styles)."""
from __future__ import annotations

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, cut_beyond, X, Y, Z, ALONG_Z


def _hull(b: CSGBuilder, length: float, beam: float, depth: float, bow: float, v_rise: float,
          stern_taper: float) -> None:
    """A hull on y in [0, depth] along z: a box cut to a pointed bow over ``bow`` of its length,
    its forefoot raked, optionally a V bottom and a narrowed stern. The cuts stay below the deck
    (y = depth), so they miss masts and sails built before the hull. ``v_rise``: the height of the
    V bottom's chines as a fraction of the depth (0: flat bottom)."""
    front = -length / 2
    b.box((0, depth / 2, 0), (beam / 2, depth / 2, length / 2))
    hy = depth / 2 + 0.005
    for s in (-1, 1):
        cut_beyond(b, (s * beam / 2, depth / 2, front + bow), (0, depth / 2, front), Y, (s, 0, -0.3), hy,
                    margin=0.05)
    cut_beyond(b, (0, 0, front + bow * 1.2), (0, depth * 0.7, front), X, (0, -1, -1), beam / 2 + 0.01,
                margin=0.05)
    if v_rise > 0:
        for s in (-1, 1):
            cut_beyond(b, (s * beam / 2, depth * v_rise, 0), (0, 0, 0), Z, (s, -1, 0), length / 2 + 0.01, margin=0.0)
    if stern_taper > 0:
        for s in (-1, 1):
            cut_beyond(b, (s * beam / 2, depth / 2, length / 2 - stern_taper),
                        (s * beam * 0.35, depth / 2, length / 2), Y, (s, 0, 1), hy, margin=0.02)


def make_vessel(rng: np.random.Generator, style: str) -> CSGShape:
    """Along z, bow to -z. "ship": deckhouse, bridge, funnel and mast; "sailboat": narrow hull
    with a keel, a mast and one or two triangular sails; "speedboat": wide V hull with a cockpit
    and a windscreen; "rowboat": an open hull with thwarts across it (holes), no superstructure;
    "tanker": long flat deck, bridge and funnel at the stern."""
    b = CSGBuilder()
    length = uniform(rng, 0.95, 1.0)
    front = -length / 2
    if style == "sailboat":
        beam, depth = uniform(rng, 0.2, 0.26), uniform(rng, 0.08, 0.11)
        mast_h = uniform(rng, 0.5, 0.8)
        zm = front + length * uniform(rng, 0.35, 0.45)
        top = depth + mast_h
        foot = depth + 0.08
        if chance(rng, 0.7):  # jib from the masthead to the bow
            jz = front + 0.08
            b.box_between((-0.0275, depth + 0.02, jz), (0.0275, top * 0.85, zm))
            cut_beyond(b, (0, top * 0.85, zm), (0, depth + 0.02, jz), X, (0, 1, -1), 0.05)
        boom = uniform(rng, 0.35, 0.5)
        b.box((0, (foot + top) / 2, zm + boom / 2), (0.0275, (top - foot) / 2, boom / 2))
        cut_beyond(b, (0, top, zm), (0, foot, zm + boom), X, (0, 1, 1), 0.05)
        b.cylinder((0, (depth + top) / 2, zm), 0.03, (top - depth) / 2)
        b.box((0, foot - 0.03, zm + boom / 2), (0.03, 0.03, boom / 2 + 0.02))  # boom
        _hull(b, length, beam, depth, length * uniform(rng, 0.3, 0.4), 0.4, length * 0.15)
        b.box((0, depth + 0.03, zm + 0.12), (beam * 0.3, 0.04, 0.1), rounding=0.02)  # cabin roof
        b.box((0, -0.06, zm + 0.05), (0.03, 0.08, 0.1))  # keel
        return b.shape()
    if style == "speedboat":
        beam, depth = uniform(rng, 0.3, 0.38), uniform(rng, 0.13, 0.16)
        v_rise = 0.3
        _hull(b, length, beam, depth, length * uniform(rng, 0.3, 0.4), v_rise, 0.0)
        cz0, cz1 = uniform(rng, -0.1, 0.0), length / 2 - uniform(rng, 0.08, 0.15)
        floor = depth * v_rise * 0.75 + 0.06  # over the V at the cockpit's sides
        b.box_between((-beam / 2 + 0.055, floor, cz0), (beam / 2 - 0.055, depth + 0.1, cz1), op="subtract")  # cockpit
        ws = rotation(X, -uniform(rng, 0.6, 0.9))
        b.box(np.array([0.0, depth + 0.04, cz0 - 0.02]), (beam / 2 - 0.04, 0.05, 0.0275), ws, rounding=0.01)
        if chance(rng, 0.6):  # outboard motor on the transom
            b.box((0, depth + 0.02, length / 2 + 0.04), (0.05, 0.06, 0.05), rounding=0.02)
            b.box((0, depth * 0.2, length / 2 + 0.04), (0.0275, depth * 0.6, 0.03))
        return b.shape()
    if style == "rowboat":
        beam, depth = uniform(rng, 0.3, 0.4), uniform(rng, 0.12, 0.16)
        bow = length * uniform(rng, 0.25, 0.35)
        _hull(b, length, beam, depth, bow, 0.0, length * uniform(rng, 0.06, 0.1))
        wall = uniform(rng, 0.055, 0.065)
        stern = length / 2 - length * 0.1 - wall
        b.box_between((-beam / 2 + wall, wall, front + bow + 0.01), (beam / 2 - wall, depth + 0.1, stern),
                      op="subtract")
        n = int(rng.integers(2, 4))
        for k in range(n):
            z = front + bow + (stern - front - bow) * (k + 0.7) / (n + 0.4)
            b.box((0, depth - 0.04, z), (beam / 2 - wall / 2, 0.0275, 0.045))
        return b.shape()
    # ship, tanker
    beam, depth = uniform(rng, 0.16, 0.24), uniform(rng, 0.09, 0.13)
    _hull(b, length, beam, depth, length * uniform(rng, 0.15, 0.25), 0.0, length * uniform(rng, 0.0, 0.06))
    if style == "tanker":
        zb = length / 2 - uniform(rng, 0.12, 0.16)
        bh = uniform(rng, 0.12, 0.18)
        b.box((0, depth + bh / 2, zb), (beam * 0.42, bh / 2, uniform(rng, 0.05, 0.07)))
        b.box((0, depth + bh - 0.0275, zb - 0.02), (beam * 0.55, 0.0275, 0.04))  # bridge wings
        b.box((0, depth + bh * 0.6, zb + 0.09), (0.035, bh * 0.6, 0.035), rotation(X, 0.15))  # funnel
        if chance(rng, 0.5):  # containers
            n = int(rng.integers(3, 6))
            span = zb - 0.1 - (front + length * 0.2)
            for k in range(n):
                z = front + length * 0.2 + span * (k + 0.5) / n
                b.box((0, depth + 0.04, z), (beam * 0.42, 0.04, span / n * 0.42))
        else:  # a pipe deck: a catwalk down the middle and a forecastle
            b.box((0, depth + 0.03, 0.0), (0.035, 0.03, length * 0.3))
            b.box((0, depth + 0.03, front + 0.12), (beam * 0.3, 0.03, 0.05))
        return b.shape()
    zh = uniform(rng, -0.05, 0.15)
    hl = uniform(rng, 0.12, 0.18)
    dh = uniform(rng, 0.06, 0.1)
    b.box((0, depth + dh / 2, zh), (beam * 0.38, dh / 2, hl), rounding=0.01)  # deckhouse
    bh = uniform(rng, 0.06, 0.08)
    zbr = zh - hl * 0.5
    b.box((0, depth + dh + bh / 2, zbr), (beam * 0.33, bh / 2, uniform(rng, 0.045, 0.065)), rounding=0.01)  # bridge
    if chance(rng, 0.6):
        b.box((0, depth + dh + bh - 0.0275, zbr), (beam * 0.5, 0.0275, 0.035))  # bridge wings
    fh = uniform(rng, 0.08, 0.13)
    b.cylinder((0, depth + dh + fh / 2, zh + hl * 0.45), uniform(rng, 0.035, 0.045), fh / 2, rotation(X, 0.2))  # funnel
    mh = uniform(rng, 0.12, 0.22)
    b.cylinder((0, depth + dh + bh + mh / 2, zbr + 0.03), 0.0275, mh / 2)  # mast
    b.box((0, depth + dh + bh + mh * 0.7, zbr + 0.03), (uniform(rng, 0.06, 0.09), 0.0275, 0.0275))  # yard
    if chance(rng, 0.4):  # a gun turret on the foredeck
        tz = front + length * 0.25
        b.cylinder((0, depth + 0.03, tz), 0.05, 0.03)
        b.cylinder((0, depth + 0.035, tz - 0.09), 0.0275, 0.07, ALONG_Z)
    return b.shape()


STYLES = ('ship', 'sailboat', 'speedboat', 'rowboat', 'tanker')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_vessel(*params)
