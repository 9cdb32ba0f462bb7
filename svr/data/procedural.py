"""A procedural single-view dataset in the exact NMR ShapeNet layout.

Eight categories of parametric CSG shapes (``svr.data.csg``), several with holes (genus > 0),
random but reproducible from a seed, normalised like ShapeNet (centred on the bounding box,
longest side 1). Per object:

* 24 RGBA views, uint8 (24, 4, 64, 64), with the NMR cameras (``renderer.Cameras.nmr``: elevation
  30, distance 2.732, FOV 30), sphere-traced on the *analytic* SDF, anti-aliased by supersampling
  (S x S rays per pixel, S = 3 by default, NMR's own renderer used 2 x 2; ``render_shape`` gives
  the adaptive rule), shaded with the fixed light of ``DEFAULT_SHADING`` through
  ``renderer.shading.shade_lambert`` on a white background, so that training can re-render the
  same shading with ``ShadingModel.scene()``.
* solid voxels, bool (32, 32, 32), in the NMR voxel frame: by default (``voxel_rule="centre"``)
  ``vox[i, j, k]`` is occupied iff the analytic SDF is negative at the world point
  ``((j - 15.5)/31, (i - 15.5)/31, (15.5 - k)/31)``; ``voxel_rule="protocol"`` uses the benchmark's
  mesh voxelisation instead (see ``voxelize_shape``).

``generate_procedural_dataset`` writes ``{cid}_{split}_images.npz`` / ``{cid}_{split}_voxels.npz``
(key ``arr_0``, as NMR ShapeNet), a ``metadata.json`` (categories, shading model, settings), and the
memory-mapped ``.npy`` copies of ``svr.data.nmr.prepare_nmr``. ``ensure_procedural_dataset`` does it
once into a cache folder named by a hash of the settings and reuses it afterwards.
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence, Union

import numba
import numpy as np
import torch

from ..geometry import NMR_VOXEL_RESOLUTION, nmr_voxel_centres
from .csg import CSGBuilder, CSGShape, rotation, surface_normals, trace_rays
from .types import ShadingModel

# Bump when the shapes, renders or file contents change: it is part of the cache key.
GENERATOR_VERSION = 1

NUM_VIEWS = 24
IMAGE_SIZE = 64
SPLITS = ("train", "val", "test")

# The fixed light of the procedural renders (world frame, y up; view 0 looks from -z).
DEFAULT_SHADING = ShadingModel(
    light_direction=(0.45, 1.0, -0.6),
    light_intensity=0.65,
    ambient=0.35,
    albedo=(0.85, 0.62, 0.42),
    background=(1.0, 1.0, 1.0),
)


# ---------------------------------------------------------------------------------------------
# Categories. Shapes are built roughly in unit size, y up, facing -z (towards view 0), with every
# part at least ~0.05 thick so that it survives 32^3 voxel-centre sampling (voxel size 1/31).


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _legs(b: CSGBuilder, rng, xs, zs, top: float, thick: float, round_legs: bool) -> None:
    for x in xs:
        for z in zs:
            if round_legs:
                b.cylinder((x, top / 2, z), thick / 2, top / 2)
            else:
                b.box((x, top / 2, z), (thick / 2, top / 2, thick / 2))


def make_chair(rng: np.random.Generator) -> CSGShape:
    """Seat, four legs, a (possibly tilted) back that is a panel, slats or rails; optional arms and
    leg stretchers. Slatted backs, arms and stretchers make holes."""
    b = CSGBuilder()
    sw, sd, st = _u(rng, 0.42, 0.56), _u(rng, 0.38, 0.5), _u(rng, 0.05, 0.08)
    sh = _u(rng, 0.36, 0.48)
    lt = _u(rng, 0.05, 0.07)
    inset = _u(rng, 0.0, 0.03)
    lx, lz = sw / 2 - lt / 2 - inset, sd / 2 - lt / 2 - inset
    _legs(b, rng, (-lx, lx), (-lz, lz), sh, lt, rng.random() < 0.5)
    b.box((0, sh + st / 2, 0), (sw / 2, st / 2, sd / 2), rounding=0.01)
    if rng.random() < 0.4:  # side stretchers: a loop with two legs and the seat
        y = _u(rng, 0.08, 0.2)
        for x in (-lx, lx):
            b.box_between((x - 0.025, y - 0.025, -lz), (x + 0.025, y + 0.025, lz))
    # back, built upright at the seat's rear edge and tilted backwards about the x axis
    bh, bt = _u(rng, 0.35, 0.55), _u(rng, 0.05, 0.07)
    tilt = _u(rng, 0.0, 0.25)
    pivot = np.array([0.0, sh + st, sd / 2 - bt / 2])
    rot = rotation((1, 0, 0), -tilt)  # top moves towards +z

    def back_box(lo, hi):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        centre = pivot + rot @ ((lo + hi) / 2)
        b.box(centre, np.abs(hi - lo) / 2, rot)

    style = rng.integers(0, 3)
    if style == 0:
        back_box((-sw / 2, 0, -bt / 2), (sw / 2, bh, bt / 2))
    else:
        pw = _u(rng, 0.05, 0.07)
        rail = _u(rng, 0.06, 0.1)
        back_box((-sw / 2, 0, -bt / 2), (-sw / 2 + pw, bh, bt / 2))
        back_box((sw / 2 - pw, 0, -bt / 2), (sw / 2, bh, bt / 2))
        back_box((-sw / 2, bh - rail, -bt / 2), (sw / 2, bh, bt / 2))
        if style == 1:  # vertical slats
            n = int(rng.integers(1, 4))
            inner = sw - 2 * pw
            w = min(0.06, inner / (2 * n + 1))
            w = max(w, 0.05)
            for k in range(n):
                x = -inner / 2 + inner * (k + 1) / (n + 1)
                back_box((x - w / 2, 0, -bt / 2 * 0.8), (x + w / 2, bh - rail, bt / 2 * 0.8))
        else:  # horizontal rails
            n = int(rng.integers(1, 3))
            for k in range(n):
                y = (bh - rail) * (k + 1) / (n + 1)
                back_box((-sw / 2 + pw, y - 0.03, -bt / 2 * 0.8), (sw / 2 - pw, y + 0.03, bt / 2 * 0.8))
    if rng.random() < 0.3:  # arms: rest + front post, each a loop with seat and back
        ah = _u(rng, 0.17, 0.25)
        for x in (-sw / 2 + 0.03, sw / 2 - 0.03):
            b.box_between((x - 0.03, sh + st + ah - 0.05, -sd / 2 + 0.03), (x + 0.03, sh + st + ah, sd / 2 - bt))
            b.box_between((x - 0.025, sh + st, -sd / 2 + 0.03), (x + 0.025, sh + st + ah, -sd / 2 + 0.08))
    return b.shape()


def make_table(rng: np.random.Generator) -> CSGShape:
    """Rectangular or round top on four legs (with optional apron and stretchers: holes) or on a
    pedestal."""
    b = CSGBuilder()
    tw, td, tt = _u(rng, 0.8, 1.0), _u(rng, 0.45, 0.9), _u(rng, 0.05, 0.08)
    th = _u(rng, 0.45, 0.75)
    round_top = rng.random() < 0.3
    if round_top:
        r = min(tw, td) / 2
        b.cylinder((0, th - tt / 2, 0), r, tt / 2)
        hx = hz = r * 0.62
    else:
        b.box((0, th - tt / 2, 0), (tw / 2, tt / 2, td / 2), rounding=0.01)
        hx, hz = tw / 2, td / 2
    if rng.random() < 0.25:  # pedestal
        pr = _u(rng, 0.04, 0.08)
        b.cylinder((0, th / 2, 0), pr, th / 2)
        b.cylinder((0, 0.03, 0), _u(rng, 0.18, 0.3), 0.03)
        return b.shape()
    lt = _u(rng, 0.05, 0.08)
    inset = _u(rng, 0.0, 0.06)
    lx, lz = hx - lt / 2 - inset, hz - lt / 2 - inset
    _legs(b, rng, (-lx, lx), (-lz, lz), th - tt, lt, rng.random() < 0.5)
    if rng.random() < 0.4:  # apron under the top
        ah = _u(rng, 0.06, 0.1)
        y0 = th - tt - ah
        b.box_between((-lx, y0, -lz - 0.025), (lx, th - tt, -lz + 0.025))
        b.box_between((-lx, y0, lz - 0.025), (lx, th - tt, lz + 0.025))
    if rng.random() < 0.5:  # stretchers
        y = _u(rng, 0.1, 0.25)
        for z in (-lz, lz):
            b.box_between((-lx, y - 0.025, z - 0.025), (lx, y + 0.025, z + 0.025))
        if rng.random() < 0.5:
            b.box_between((-0.025, y - 0.025, -lz), (0.025, y + 0.025, lz))
    return b.shape()


def make_lamp(rng: np.random.Generator) -> CSGShape:
    """A base disc and a pole, then either a floor lamp (open tube shade on top: a hole) or a desk
    lamp (angled arm, shade tilted down, open at the bottom): asymmetric."""
    b = CSGBuilder()
    br, bh = _u(rng, 0.12, 0.2), _u(rng, 0.025, 0.04)
    b.cylinder((0, bh, 0), br, bh)
    pr = _u(rng, 0.025, 0.035)
    if rng.random() < 0.5:  # floor lamp
        height = _u(rng, 0.7, 1.0)
        b.cylinder((0, height / 2, 0), pr, height / 2)
        sh, rb, rt = _u(rng, 0.08, 0.12), _u(rng, 0.15, 0.24), _u(rng, 0.07, 0.12)
        cy = height + sh * 0.6
        b.cone((0, cy, 0), sh, rb, rt)
        w = 0.05
        b.cone((0, cy, 0), sh + 0.02, rb - w - 0.01, rt - w + 0.01, op="subtract")
        # spokes from the pole top to the shade
        for ang in (0.0, math.pi):
            b.rod((0, height, 0), (math.cos(ang) * (rt - 0.02), cy + sh * 0.5, math.sin(ang) * (rt - 0.02)), 0.025)
        return b.shape()
    height = _u(rng, 0.35, 0.55)
    b.cylinder((0, height / 2, 0), pr, height / 2)
    ang = _u(rng, 0.3, 1.1)  # arm elevation above horizontal
    az = _u(rng, -0.6, 0.6)  # arm direction around y
    length = _u(rng, 0.25, 0.4)
    tip = np.array([math.cos(ang) * math.cos(az), math.sin(ang), math.cos(ang) * math.sin(az)]) * length
    top = np.array([0.0, height, 0.0])
    b.capsule(top, top + tip, pr)
    sh, rb, rt = _u(rng, 0.07, 0.1), _u(rng, 0.1, 0.16), _u(rng, 0.05, 0.07)
    down = rotation((-math.sin(az), 0, math.cos(az)), -_u(rng, 0.2, 0.6))  # tilt the shade outwards
    centre = top + tip + down @ np.array([0.0, -sh, 0.0])
    b.cone(centre, sh, rb, rt, down)
    b.cone(centre + down @ np.array([0.0, -0.03, 0.0]), sh, rb - 0.05, rt - 0.05, down, op="subtract")
    return b.shape()


def make_airplane(rng: np.random.Generator) -> CSGShape:
    """Fuselage along z (nose towards -z), swept wings with dihedral, tail fin and stabilisers,
    optional engines."""
    b = CSGBuilder()
    length, fr = _u(rng, 0.8, 1.0), _u(rng, 0.045, 0.07)
    b.capsule((0, 0, -length / 2 + fr), (0, 0, length / 2 - fr), fr)
    span, chord, th = _u(rng, 0.7, 1.0), _u(rng, 0.12, 0.2), 0.05
    sweep, dihedral = _u(rng, 0.0, 0.5), _u(rng, 0.0, 0.12)
    wz, wy = _u(rng, -0.12, 0.08), _u(rng, -fr / 2, fr / 3)
    for side in (-1, 1):
        rot = rotation((0, 1, 0), side * sweep) @ rotation((0, 0, 1), side * dihedral)
        centre = np.array([0.0, wy, wz]) + rot @ np.array([side * span / 4, 0, 0])
        b.box(centre, (span / 4, th / 2, chord / 2), rot, rounding=0.01)
    tz = length / 2 - _u(rng, 0.08, 0.14)
    fin_h, fin_c = _u(rng, 0.1, 0.18), _u(rng, 0.1, 0.16)
    fin_rot = rotation((1, 0, 0), _u(rng, 0.2, 0.5))
    b.box(np.array([0, fr + fin_h / 2 - 0.02, tz]), (0.025, fin_h / 2, fin_c / 2), fin_rot)
    sspan = _u(rng, 0.2, 0.35)
    for side in (-1, 1):
        rot = rotation((0, 1, 0), side * sweep)
        b.box(np.array([0, 0.0, tz]) + rot @ np.array([side * sspan / 4, 0, 0]), (sspan / 4, 0.025, fin_c / 2.5), rot)
    if rng.random() < 0.6:
        er, el = _u(rng, 0.03, 0.045), _u(rng, 0.12, 0.2)
        n = 1 if rng.random() < 0.6 else 2
        for side in (-1, 1):
            for k in range(n):
                x = side * span / 2 * (0.3 + 0.3 * k)
                z = wz + math.tan(sweep) * abs(x) - chord * 0.4
                b.cylinder((x, wy - th / 2 - er * 0.9, z), er, el / 2, rotation((1, 0, 0), math.pi / 2))
    return b.shape()


def make_bench(rng: np.random.Generator) -> CSGShape:
    """Long seat on two side panels with cut-outs (holes) or on legs, optional slatted back."""
    b = CSGBuilder()
    bw, bd, st, sh = _u(rng, 0.9, 1.0), _u(rng, 0.28, 0.4), _u(rng, 0.05, 0.07), _u(rng, 0.35, 0.45)
    b.box((0, sh + st / 2, 0), (bw / 2, st / 2, bd / 2), rounding=0.01)
    px = bw / 2 - _u(rng, 0.04, 0.12)
    if rng.random() < 0.55:  # panels with a rectangular cut-out
        pt = _u(rng, 0.05, 0.06)
        for x in (-px, px):
            b.box((x, sh / 2, 0), (pt / 2, sh / 2, bd / 2 - 0.01))
        for x in (-px, px):
            b.box((x, sh / 2 - 0.02, 0), (pt, sh / 2 - 0.08, bd / 2 - 0.07), op="subtract")
    else:
        lt = _u(rng, 0.05, 0.07)
        _legs(b, rng, (-px, px), (-(bd / 2 - lt), bd / 2 - lt), sh, lt, rng.random() < 0.5)
        if rng.random() < 0.5:
            y = _u(rng, 0.08, 0.18)
            b.box_between((-px, y - 0.025, -0.025), (px, y + 0.025, 0.025))
            for x in (-px, px):
                b.box_between((x - 0.025, y - 0.025, -(bd / 2 - lt)), (x + 0.025, y + 0.025, bd / 2 - lt))
    if rng.random() < 0.7:  # back: posts and 1-3 slats
        bh = _u(rng, 0.25, 0.4)
        z = bd / 2 - 0.03
        for x in (-px, px):
            b.box_between((x - 0.03, sh + st, z - 0.03), (x + 0.03, sh + st + bh, z + 0.03))
        n = int(rng.integers(1, 4))
        for k in range(n):
            y = sh + st + bh - 0.04 - k * (bh - 0.05) / max(n, 1)
            b.box_between((-bw / 2 + 0.02, y - 0.03, z - 0.025), (bw / 2 - 0.02, y + 0.03, z + 0.025))
    return b.shape()


def make_mug(rng: np.random.Generator) -> CSGShape:
    """A (possibly tapered) cup with a bottom and a torus handle: genus 1."""
    b = CSGBuilder()
    r, h = _u(rng, 0.25, 0.35), _u(rng, 0.5, 0.8)
    wall, bottom = _u(rng, 0.05, 0.07), _u(rng, 0.05, 0.08)
    taper = _u(rng, 0.0, 0.08) if rng.random() < 0.4 else 0.0
    b.cone((0, h / 2, 0), h / 2, r - taper, r)
    hr, hm = _u(rng, 0.12, 0.2) * h / 0.65, _u(rng, 0.035, 0.05)
    hr = min(hr, h / 2 - hm - 0.02)
    b.torus((r - 0.02 + hr * 0.55, h * _u(rng, 0.45, 0.55), 0), hr, hm, rotation((1, 0, 0), math.pi / 2))
    # the cavity, cut last so the handle never enters the cup
    b.cone((0, bottom + (h - bottom) / 2 + 0.05, 0), (h - bottom) / 2 + 0.05,
           r - taper - wall, r - wall + 0.05 * taper / h, op="subtract")
    return b.shape()


def make_sofa(rng: np.random.Generator) -> CSGShape:
    """Rounded base, back and arms with seat cushions on short legs."""
    b = CSGBuilder()
    w, d = _u(rng, 0.8, 1.0), _u(rng, 0.38, 0.5)
    leg = _u(rng, 0.04, 0.07)
    bh = _u(rng, 0.15, 0.22)
    b.box_between((-w / 2, leg, -d / 2), (w / 2, leg + bh, d / 2), rounding=0.03)
    bt = _u(rng, 0.1, 0.16)
    back_h = _u(rng, 0.2, 0.35)
    b.box_between((-w / 2, leg + bh - 0.02, d / 2 - bt), (w / 2, leg + bh + back_h, d / 2), rounding=0.04)
    at, ah = _u(rng, 0.08, 0.14), _u(rng, 0.08, 0.2)
    if rng.random() < 0.85:
        for s in (-1, 1):
            x0, x1 = sorted((s * w / 2, s * (w / 2 - at)))
            b.box_between((x0, leg + bh - 0.02, -d / 2), (x1, leg + bh + ah, d / 2), rounding=0.03)
    n = int(rng.integers(1, 4))
    ch = _u(rng, 0.05, 0.09)
    inner = w - 2 * at
    for k in range(n):
        x0 = -inner / 2 + inner * k / n + 0.005
        x1 = -inner / 2 + inner * (k + 1) / n - 0.005
        b.box_between((x0, leg + bh - 0.01, -d / 2 + 0.01), (x1, leg + bh + ch, d / 2 - bt), rounding=0.025)
    for x in (-w / 2 + 0.06, w / 2 - 0.06):
        for z in (-d / 2 + 0.06, d / 2 - 0.06):
            b.cylinder((x, leg / 2 + 0.01, z), 0.03, leg / 2 + 0.01)
    return b.shape()


def make_shelf(rng: np.random.Generator) -> CSGShape:
    """A bookcase: a box with a grid of compartments open at the front; with an open back the
    compartments go through (holes)."""
    b = CSGBuilder()
    w, h, d = _u(rng, 0.45, 0.9), _u(rng, 0.7, 1.0), _u(rng, 0.25, 0.4)
    t = _u(rng, 0.05, 0.06)
    b.box((0, h / 2, 0), (w / 2, h / 2, d / 2))
    rows, cols = int(rng.integers(2, 5)), int(rng.integers(1, 3))
    open_back = rng.random() < 0.4
    cw = (w - (cols + 1) * t) / cols
    chh = (h - (rows + 1) * t) / rows
    z1 = d / 2 + 0.1 if open_back else d / 2 - t
    for i in range(rows):
        for j in range(cols):
            x0 = -w / 2 + t + j * (cw + t)
            y0 = t + i * (chh + t)
            b.box_between((x0, y0, -d / 2 - 0.1), (x0 + cw, y0 + chh, z1), op="subtract")
    return b.shape()


@dataclass(frozen=True)
class ProceduralCategory:
    """A procedural category: an 8-digit id (distinct from ShapeNet's synset ids, which start with
    0), a name and the generator of its raw (un-normalised) shapes."""

    category_id: str
    name: str
    make: Callable[[np.random.Generator], CSGShape]


PROCEDURAL_CATEGORIES: tuple[ProceduralCategory, ...] = (
    ProceduralCategory("90000001", "chair", make_chair),
    ProceduralCategory("90000002", "table", make_table),
    ProceduralCategory("90000003", "lamp", make_lamp),
    ProceduralCategory("90000004", "airplane", make_airplane),
    ProceduralCategory("90000005", "bench", make_bench),
    ProceduralCategory("90000006", "mug", make_mug),
    ProceduralCategory("90000007", "sofa", make_sofa),
    ProceduralCategory("90000008", "shelf", make_shelf),
)
_BY_NAME = {c.name: c for c in PROCEDURAL_CATEGORIES}
_BY_ID = {c.category_id: c for c in PROCEDURAL_CATEGORIES}


def procedural_category(key: str) -> ProceduralCategory:
    """A category by name ("chair") or id ("90000001")."""
    if key in _BY_NAME:
        return _BY_NAME[key]
    if key in _BY_ID:
        return _BY_ID[key]
    raise ValueError(f"unknown procedural category {key!r}; expected one of {sorted(_BY_NAME)} "
                     f"or their ids {sorted(_BY_ID)}")


def make_shape(category: str, seed: Union[int, Sequence[int]]) -> CSGShape:
    """One normalised shape (centred, longest bounding-box side 1) of a category, from a seed."""
    cat = procedural_category(category)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    return cat.make(rng).normalized()


def object_seed(seed: int, category_id: str, split: str, index: int) -> list[int]:
    """The seed of one object: independent of how many objects and which other categories are made."""
    return [int(seed), int(category_id), SPLITS.index(split), int(index)]


# ---------------------------------------------------------------------------------------------
# Rendering and voxels


@functools.lru_cache(maxsize=4)
def _nmr_rays(image_size: int, num_views: int = NUM_VIEWS) -> tuple[np.ndarray, np.ndarray]:
    """Eyes (V, 3) and unit ray directions (V, H, W, 3), float64, of the NMR cameras."""
    import renderer

    cams = renderer.Cameras.nmr(list(range(num_views)), image_size=image_size, dtype=torch.float64)
    _, d = cams.rays()
    return cams.eye.numpy().copy(), d.numpy().copy()


@numba.njit(cache=True)
def _interior_pixels(hit, t, normals, depth_k, cos_min):
    """(V, H, W) bool: hit pixels whose 8 neighbours hit at a depth within ``depth_k * t`` and with a
    normal within ``acos(cos_min)`` (a smooth patch seen by the whole pixel)."""
    v, h, w = hit.shape
    out = np.zeros((v, h, w), dtype=np.bool_)
    for a in range(v):
        for r in range(1, h - 1):
            for c in range(1, w - 1):
                if not hit[a, r, c]:
                    continue
                ok = True
                for dr in range(-1, 2):
                    for dc in range(-1, 2):
                        rr, cc = r + dr, c + dc
                        if not hit[a, rr, cc] or abs(t[a, rr, cc] - t[a, r, c]) >= depth_k * t[a, r, c]:
                            ok = False
                        elif (normals[a, rr, cc, 0] * normals[a, r, c, 0] + normals[a, rr, cc, 1] * normals[a, r, c, 1]
                              + normals[a, rr, cc, 2] * normals[a, r, c, 2]) <= cos_min:
                            ok = False
                out[a, r, c] = ok
    return out


def render_shape(shape: CSGShape, shading: ShadingModel = DEFAULT_SHADING, supersample: int = 3,
                 image_size: int = IMAGE_SIZE, num_views: int = NUM_VIEWS, adaptive: bool = True) -> np.ndarray:
    """The NMR views of an analytic shape, anti-aliased.

    Adaptive supersampling: every pixel's centre ray is traced first. A pixel whose centre ray
    certifies (cone tracing with the sphere-tracing balls) that no ray through the pixel meets the
    shape is background; a hit pixel whose 8 neighbours hit the same smooth surface (similar depth
    and normal) takes its centre sample; every other pixel (silhouettes, creases, depth edges)
    averages S x S rays through the centres of an S x S sub-pixel grid, each starting where the
    centre ray's certificate ends.

    Args:
        shape: a normalised CSGShape (world frame, y up).
        shading: the light, material and background (``shading.scene()`` shades the hits).
        supersample: S, rays per pixel side.
        adaptive: False supersamples every pixel (the reference the adaptive rule is tested against).
    Returns:
        (V, 4, H, W) uint8 RGBA: RGB composited on the background, alpha = coverage.
    """
    from renderer.shading import shade_lambert

    if not isinstance(supersample, int) or supersample < 1:
        raise ValueError(f"supersample must be a positive int, got {supersample!r}")
    s = supersample
    eyes, dirs = _nmr_rays(image_size, num_views)
    _, sub_dirs = _nmr_rays(image_size * s, num_views)
    v, h, w = dirs.shape[:3]
    pixel_angle = 2.0 * math.tan(math.radians(15.0)) / image_size
    hit_threshold = 0.25 * pixel_angle / s
    delta = 1.05 * pixel_angle / math.sqrt(2.0)  # half-diagonal of a pixel (+5%)
    lo, hi = shape.bounds
    # The certificate needs a box margin above 2 delta t: the eyes are 2.732 from the centre and the
    # normalised shape lies within 0.87 of it, so t < 4.
    margin = 2.0 * delta * 4.0 + 0.01
    lo, hi = np.asarray(lo) - margin, np.asarray(hi) + margin

    # pass 1: centre rays
    n_pix = v * h * w
    view_of = np.repeat(np.arange(v), h * w)
    d1 = dirs.reshape(-1, 3)
    res = trace_rays(shape, eyes, d1, hit_threshold, (lo, hi), view_of, None, delta)
    hit1, t_hit1, t_cert, clear = res.hit, res.t, res.t_certified, res.clear
    normals1 = np.zeros((n_pix, 3))
    points1 = eyes[view_of[hit1]] + t_hit1[hit1, None] * d1[hit1]
    normals1[hit1] = surface_normals(shape, points1)

    # interior pixels: hit, and so are the 8 neighbours, on a smooth patch at similar depth
    interior = _interior_pixels(hit1.reshape(v, h, w), t_hit1.reshape(v, h, w), normals1.reshape(v, h, w, 3),
                                3.0 * pixel_angle, 0.97).reshape(-1)
    if not adaptive:
        interior[:] = False
        clear = np.zeros_like(clear)
    refine = ~clear & ~interior

    # pass 2: S x S rays per refined pixel, starting at the centre ray's certified distance
    pix = np.nonzero(refine)[0]
    pv, pr, pc = np.unravel_index(pix, (v, h, w))
    sd = sub_dirs.reshape(v, h, s, w, s, 3)
    d2 = sd[pv, pr, :, pc, :, :].reshape(-1, 3)  # (P * S * S, 3)
    view2 = np.repeat(pv, s * s)
    res = trace_rays(shape, eyes, d2, hit_threshold, (lo, hi), view2, np.repeat(t_cert[pix], s * s))
    hit2, t_hit2 = res.hit, res.t

    # shading of every sample that hit
    use1 = interior & hit1
    p_int = eyes[view_of[use1]] + t_hit1[use1, None] * d1[use1]
    n_int = normals1[use1]
    p_sub = eyes[view2[hit2]] + t_hit2[hit2, None] * d2[hit2]
    n_sub = surface_normals(shape, p_sub) if len(p_sub) else np.zeros((0, 3))
    scene = shading.scene(("shading",))
    # float32, as training renders: the 8-bit result does not see the difference
    pts = torch.from_numpy(np.concatenate([p_int, p_sub]).astype(np.float32))
    eye_all = torch.from_numpy(eyes[np.concatenate([view_of[use1], view2[hit2]])].astype(np.float32))
    nrm = torch.from_numpy(np.concatenate([n_int, n_sub]).astype(np.float32))
    rgb = shade_lambert(nrm, pts, eye_all, scene).double().numpy()
    bg = np.asarray(shading.background, dtype=np.float64)

    out = np.zeros((n_pix, 4))
    out[:, :3] = bg
    out[use1, :3] = rgb[: len(p_int)]
    out[use1, 3] = 1.0
    samples = np.tile(bg, (len(d2), 1))
    samples[hit2] = rgb[len(p_int):]
    out[pix, :3] = samples.reshape(len(pix), s * s, 3).mean(1)
    out[pix, 3] = hit2.reshape(len(pix), s * s).mean(1)
    img = out.reshape(v, h, w, 4).transpose(0, 3, 1, 2)
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)


VOXEL_RULES = ("centre", "protocol")


def voxelize_shape(shape: CSGShape, resolution: int = NMR_VOXEL_RESOLUTION, rule: str = "centre",
                   mesh_resolution: int = 96) -> np.ndarray:
    """Solid voxels in the NMR frame.

    Args:
        rule: "centre" (SPEC section 5's definition): occupied iff the analytic SDF is negative at
            the voxel centre ``((j - c)/(R-1), (i - c)/(R-1), (c - k)/(R-1))``. "protocol": the
            benchmark's voxelisation (``svr.geometry.voxelize_sdf_protocol``) of a marching-cubes
            mesh of the analytic SDF sampled at ``mesh_resolution``^3: surface voxels included, so
            thin parts come out about one voxel thicker, as the protocol makes predictions.
    Returns:
        (R, R, R) bool.
    """
    if rule == "centre":
        pts = nmr_voxel_centres(resolution, dtype=torch.float64).numpy()
        return shape.sdf_numpy(pts) < 0.0
    if rule == "protocol":
        from ..geometry import voxelize_sdf_protocol

        half = 0.5 + 2.0 / (resolution - 1)
        axis = np.linspace(-half, half, mesh_resolution)
        values = shape.sdf_numpy(np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1))
        return voxelize_sdf_protocol(values, -half, half, resolution=resolution)
    raise ValueError(f"rule must be one of {VOXEL_RULES}, got {rule!r}")


# ---------------------------------------------------------------------------------------------
# The dataset on disk


@dataclass(frozen=True)
class ProceduralSettings:
    """What the procedural dataset holds. Every field is part of the cache key.

    Attributes:
        categories: category names or ids (``PROCEDURAL_CATEGORIES``); empty = all eight.
        train, val, test: objects per category in each split.
        seed: the dataset's seed (objects are reproducible from it).
        supersample: rays per pixel side for anti-aliasing.
        voxel_rule: how the ground-truth voxels are made (``voxelize_shape``): "centre" (SPEC 5's
            definition, the default) or "protocol" (the benchmark's own voxelisation of the exact
            shape; a perfect prediction then scores about 1 under ``svr.metrics.iou_protocol``).
    """

    categories: tuple[str, ...] = ()
    train: int = 32
    val: int = 4
    test: int = 6
    seed: int = 0
    supersample: int = 3
    voxel_rule: str = "centre"

    def __post_init__(self) -> None:
        cats = tuple(self.categories) if self.categories else tuple(c.name for c in PROCEDURAL_CATEGORIES)
        names = tuple(procedural_category(str(c)).name for c in cats)
        if len(set(names)) != len(names):
            raise ValueError(f"categories must not repeat, got {list(cats)}")
        object.__setattr__(self, "categories", names)
        for split in SPLITS:
            n = getattr(self, split)
            if not isinstance(n, int) or isinstance(n, bool) or n < 0:
                raise ValueError(f"{split} must be a non-negative int (objects per category), got {n!r}")
        if not isinstance(self.supersample, int) or self.supersample < 1:
            raise ValueError(f"supersample must be a positive int, got {self.supersample!r}")
        if not isinstance(self.seed, int):
            raise ValueError(f"seed must be an int, got {self.seed!r}")
        if self.voxel_rule not in VOXEL_RULES:
            raise ValueError(f"voxel_rule must be one of {VOXEL_RULES}, got {self.voxel_rule!r}")

    def sizes(self) -> dict[str, int]:
        return {split: getattr(self, split) for split in SPLITS}

    def category_pairs(self) -> list[tuple[str, str]]:
        """(id, name) per category, in the dataset's order."""
        return [(procedural_category(n).category_id, n) for n in self.categories]

    def key(self) -> str:
        """A short hash of the settings and the generator version (the cache folder's suffix)."""
        blob = json.dumps({**dataclasses.asdict(self), "categories": list(self.categories),
                           "version": GENERATOR_VERSION}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]


METADATA_FILE = "metadata.json"


def generate_procedural_dataset(out_dir: Union[str, os.PathLike], settings: ProceduralSettings = ProceduralSettings(),
                                shading: ShadingModel = DEFAULT_SHADING, progress: bool = True) -> Path:
    """Renders and voxelises every object and writes the NMR layout into ``out_dir``.

    The files appear atomically: everything is written into a temporary sibling folder which is
    then renamed to ``out_dir`` (which must not exist yet).

    Returns:
        the folder.
    """
    from tqdm.auto import tqdm

    from .nmr import prepare_nmr

    out = Path(out_dir)
    if out.exists():
        raise FileExistsError(f"{out} already exists; remove it or use ensure_procedural_dataset")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        total = sum(settings.sizes().values()) * len(settings.categories)
        bar = tqdm(total=total, desc=f"procedural dataset -> {out.name}", unit="obj", disable=not progress)
        for cid, name in settings.category_pairs():
            for split in SPLITS:
                n = getattr(settings, split)
                images = np.zeros((n, NUM_VIEWS, 4, IMAGE_SIZE, IMAGE_SIZE), dtype=np.uint8)
                voxels = np.zeros((n,) + (NMR_VOXEL_RESOLUTION,) * 3, dtype=bool)
                for i in range(n):
                    shape = make_shape(name, object_seed(settings.seed, cid, split, i))
                    images[i] = render_shape(shape, shading, settings.supersample)
                    voxels[i] = voxelize_shape(shape, rule=settings.voxel_rule)
                    bar.update(1)
                np.savez_compressed(tmp / f"{cid}_{split}_images.npz", images)
                np.savez_compressed(tmp / f"{cid}_{split}_voxels.npz", voxels)
        bar.close()
        meta = {
            "format": "nmr-shapenet",
            "source": "procedural",
            "generator_version": GENERATOR_VERSION,
            "categories": [[cid, name] for cid, name in settings.category_pairs()],
            "sizes": settings.sizes(),
            "settings": {**dataclasses.asdict(settings), "categories": list(settings.categories)},
            "shading": dataclasses.asdict(shading),
        }
        (tmp / METADATA_FILE).write_text(json.dumps(meta, indent=2))
        prepare_nmr(tmp, categories=[cid for cid, _ in settings.category_pairs()], progress=False)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def procedural_dataset_dir(cache_dir: Union[str, os.PathLike], settings: ProceduralSettings) -> Path:
    """The cache folder of a settings: ``<cache_dir>/procedural-<hash>``."""
    return Path(cache_dir) / f"procedural-{settings.key()}"


def ensure_procedural_dataset(cache_dir: Union[str, os.PathLike], settings: ProceduralSettings = ProceduralSettings(),
                              progress: bool = True) -> Path:
    """The dataset's folder under ``cache_dir``, generated on first use and reused afterwards."""
    out = procedural_dataset_dir(cache_dir, settings)
    if (out / METADATA_FILE).exists():
        return out
    try:
        return generate_procedural_dataset(out, settings, progress=progress)
    except OSError:
        # Another process may have finished the same folder first (the rename lost the race).
        if (out / METADATA_FILE).exists():
            return out
        raise


def load_shading(root: Union[str, os.PathLike]) -> Optional[ShadingModel]:
    """The shading model recorded in ``<root>/metadata.json``, or None (e.g. NMR ShapeNet)."""
    path = Path(root) / METADATA_FILE
    if not path.exists():
        return None
    try:
        meta = json.loads(path.read_text())
    except ValueError as err:
        raise ValueError(f"{path} is not valid JSON: {err}") from None
    sh = meta.get("shading")
    if sh is None:
        return None
    try:
        return ShadingModel(light_direction=tuple(sh["light_direction"]), light_intensity=float(sh["light_intensity"]),
                            ambient=float(sh["ambient"]), albedo=tuple(sh["albedo"]), background=tuple(sh["background"]))
    except (KeyError, TypeError) as err:
        raise ValueError(f"{path}: malformed 'shading' entry ({err})") from None


__all__ = [
    "DEFAULT_SHADING", "GENERATOR_VERSION", "PROCEDURAL_CATEGORIES", "ProceduralCategory", "ProceduralSettings",
    "make_shape", "object_seed", "procedural_category", "render_shape", "voxelize_shape", "VOXEL_RULES",
    "generate_procedural_dataset", "ensure_procedural_dataset", "procedural_dataset_dir", "load_shading",
]
