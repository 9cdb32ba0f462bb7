"""The building blocks every procedural category shares: size limits (``MIN_PART``,
``MAX_RAW_SIZE``, ``AXIS_ROD``), axes and frames, random draws (``uniform``, ``chance``) and parts
that several categories build (bars, cuts, hollow cones, legs, recesses, speaker drivers).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from svr.data.procedural.csg import CSGBuilder

# Raw-size limits behind the thinnest normalised part (see svr.data.procedural.categories.ProceduralCategory): MIN_PART / MAX_RAW_SIZE.
MIN_PART = 0.055
MAX_RAW_SIZE = 1.1

# Normalisation centres a symmetric object's bounding box on a corner of the benchmark's 32^3 voxel
# grid (voxel side 1/31). A rod on the symmetry axis whose radius just exceeds a voxel side touches
# the next ring of voxels by a sliver, and the protocol's voxels of it then hang on sub-voxel details
# of the mesh (even the exact shape loses a tenth of its IoU). Such rods get a normalised radius
# below one voxel side.
AXIS_ROD = (0.0255, 0.0285)

X = (1.0, 0.0, 0.0)
Y = (0.0, 1.0, 0.0)
Z = (0.0, 0.0, 1.0)


# ---------------------------------------------------------------------------------------------
# Building blocks


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def chance(rng: np.random.Generator, p: float) -> bool:
    return bool(rng.random() < p)


def pick(rng: np.random.Generator, options: Sequence, weights: Sequence[float] | None = None) -> str:
    """One of ``options`` (as a string), uniformly or by relative ``weights``."""
    p = None if weights is None else np.asarray(weights, float) / np.sum(weights)
    return str(options[int(rng.choice(len(options), p=p))])


def frame(y_dir: Sequence[float], x_hint: Sequence[float] = X) -> np.ndarray:
    """(3, 3) rotation (local -> world) whose local y is ``y_dir`` and whose local x is ``x_hint``
    made orthogonal to it, so that boxes keep a chosen roll (``csg.frame_with_y`` picks any)."""
    y = np.asarray(y_dir, dtype=np.float64)
    y = y / np.linalg.norm(y)
    x = np.asarray(x_hint, dtype=np.float64)
    x = x - (x @ y) * y
    x = x / np.linalg.norm(x)
    return np.stack([x, y, np.cross(x, y)], axis=1)


ALONG_X = frame(X, Y)  # local y (a cylinder's or cone's axis) -> world x
ALONG_Z = frame(Z, X)  # local y -> world z


def bar(b: CSGBuilder, p0, p1, width: float, depth: float, x_hint: Sequence[float] = X,
         op: str = "union") -> None:
    """A box from p0 to p1 (its axis) with a width x depth cross-section, width along ``x_hint``."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    b.box((p0 + p1) / 2, (width / 2, np.linalg.norm(p1 - p0) / 2, depth / 2), frame(p1 - p0, x_hint), op=op)


def cut_beyond(b: CSGBuilder, a, c, across: Sequence[float], away: Sequence[float], half_across: float,
                depth: float = 0.6, margin: float = 0.3) -> None:
    """Subtracts a box lying on the ``away`` side of the plane that holds the segment a-c and the
    direction ``across``: the box spans ``half_across`` either side of the segment along ``across``
    and runs ``margin`` past its ends, so that a cut stays local to the part it shapes."""
    a, c = np.asarray(a, dtype=np.float64), np.asarray(c, dtype=np.float64)
    u = np.asarray(across, dtype=np.float64)
    u = u / np.linalg.norm(u)
    n = np.cross(u, c - a)
    n = n / np.linalg.norm(n)
    if n @ np.asarray(away, dtype=np.float64) < 0:
        n = -n
    half = (half_across, depth / 2, np.linalg.norm(c - a) / 2 + margin)
    b.box((a + c) / 2 + n * depth / 2, half, frame(n, u), op="subtract")


def hollow_cone(b: CSGBuilder, centre, rot: np.ndarray, half: float, r_bottom: float, r_top: float,
                 wall: float, open_bottom: bool = True, open_top: bool = True) -> None:
    """A cone (``CSGBuilder.cone``) hollowed to a shell ``wall`` thick, open at either end.

    The cavity is a cone with the same slope whose radius is smaller by the wall measured across
    the slanted side, so the shell is ``wall`` thick everywhere."""
    k = (r_top - r_bottom) / (2 * half)  # radius change per unit of local y
    ext = 0.03
    y0 = -half - ext if open_bottom else -half + wall
    y1 = half + ext if open_top else half - wall
    delta = wall * math.sqrt(1 + k * k)
    rb = r_bottom + k * (y0 + half) - delta
    rt = r_bottom + k * (y1 + half) - delta
    centre = np.asarray(centre, dtype=np.float64)
    b.cone(centre, half, r_bottom, r_top, rot)
    b.cone(centre + rot @ np.array([0.0, (y0 + y1) / 2, 0.0]), (y1 - y0) / 2, rb, rt, rot, op="subtract")


def tail_cone(b: CSGBuilder, z0: float, z1: float, r0: float, r1: float) -> None:
    """A fuselage's tail: a cone from radius r0 at z0 (axis on y = 0) to r1 at z1, its axis rising
    so that the top line stays level, as an airliner's tail sweeps up from the belly."""
    a, c = np.array([0.0, 0.0, z0]), np.array([0.0, r0 - r1, z1])
    b.cone((a + c) / 2, np.linalg.norm(c - a) / 2, r0, r1, frame(c - a, X))


UPRIGHT_LEGS = ("straight", "round", "tapered")


def leg(b: CSGBuilder, kind: str, x: float, z: float, top: float, thick: float) -> None:
    """One upright leg from the floor to ``top`` at (x, z): "straight" (square), "round", or
    "tapered" (a cone narrowing towards the floor, never under MIN_PART)."""
    hh = top / 2
    if kind == "straight":
        b.box((x, hh, z), (thick / 2, hh, thick / 2))
    elif kind == "round":
        b.cylinder((x, hh, z), thick / 2, hh)
    elif kind == "tapered":
        b.cone((x, hh, z), hh, max(MIN_PART / 2, 0.55 * thick), 0.5 * thick + 0.025)
    else:
        raise ValueError(f"kind must be one of {UPRIGHT_LEGS}, got {kind!r}")


def legs(b: CSGBuilder, xs: Sequence[float], zs: Sequence[float], top: float, thick: float, round_legs: bool) -> None:
    for x in xs:
        for z in zs:
            leg(b, "round" if round_legs else "straight", x, z, top, thick)


def recess(b: CSGBuilder, x0: float, x1: float, y0: float, y1: float, z_face: float, depth: float) -> None:
    """Subtracts a shallow rectangular recess from a face at z = z_face that faces -z (a screen, a
    door panel): it reads as an outline in a render and barely changes the voxels."""
    b.box(((x0 + x1) / 2, (y0 + y1) / 2, z_face), (abs(x1 - x0) / 2, abs(y1 - y0) / 2, depth), op="subtract")


def driver(b: CSGBuilder, x: float, y: float, z_face: float, radius: float, depth: float) -> None:
    """A loudspeaker driver in a face at z = z_face that faces -z: a conical dish."""
    half = depth / 2 + 0.005
    b.cone((x, y, z_face + half - 0.01), half, radius, 0.45 * radius, ALONG_Z, op="subtract")
