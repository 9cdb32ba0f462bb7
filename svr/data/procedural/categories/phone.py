"""The procedural phone (see ``make_phone`` for its styles)."""
from __future__ import annotations

import math

import numpy as np

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.categories.blocks import uniform, chance, cut_beyond, recess, X, ALONG_X, ALONG_Z


def make_phone(rng: np.random.Generator, style: str) -> CSGShape:
    """Standing upright, screen to -z. "slab": a smartphone with a recessed screen and a camera
    bump; "flip": an open flip phone, the lid tilted back on a hinge; "desk": a desk telephone
    with a sloped keypad and a handset on its cradle (a hole under the handset); "candybar": a
    thick phone with a small screen, a keypad grid and an antenna stub."""
    b = CSGBuilder()
    if style == "desk":
        w, d, h = uniform(rng, 0.85, 1.0), uniform(rng, 0.6, 0.8), uniform(rng, 0.16, 0.24)
        b.box((0, h / 2, 0), (w / 2, h / 2, d / 2), rounding=0.03)
        # the right part slopes down to the front; the left part stays flat under the handset
        ledge = uniform(rng, 0.3, 0.36)
        x0 = -w / 2 + ledge
        y0 = h * uniform(rng, 0.35, 0.55)
        xc = (x0 + w / 2 + 0.05) / 2
        cut_beyond(b, (xc, y0, -d / 2), (xc, h, d / 2 - 0.05), X, (0, 1, -0.3), (w / 2 + 0.05 - x0) / 2, margin=0.1)
        theta = math.atan2(h - y0, d - 0.05)
        slope = rotation(X, -theta)
        zk = uniform(rng, -0.06, 0.04)
        pad = np.array([(x0 + w / 2) / 2, y0 + (zk + d / 2) * math.tan(theta), zk]) + slope @ np.array([0, 0.01, 0])
        b.box(pad, (0.16, 0.03, 0.13), slope, rounding=0.01)
        for gx in (-0.053, 0.053):  # a 3 x 4 grid of keys
            b.box(pad + slope @ np.array([gx, 0.03, 0.0]), (0.008, 0.012, 0.14), slope, op="subtract")
        for gz in (-0.065, 0.0, 0.065):
            b.box(pad + slope @ np.array([0.0, 0.03, gz]), (0.17, 0.012, 0.008), slope, op="subtract")
        hx = -w / 2 + ledge / 2
        hl = d * uniform(rng, 0.75, 0.9)
        hy = h + uniform(rng, 0.09, 0.11)
        b.capsule((hx, hy, -hl / 2 + 0.06), (hx, hy, hl / 2 - 0.06), uniform(rng, 0.04, 0.045))
        for s in (-1, 1):  # ear and mouth pieces rest on the cradle: the handset bridges a gap (a hole)
            b.box((hx, hy - 0.04, s * (hl / 2 - 0.07)), (0.06, 0.045, 0.07), rounding=0.02)
            b.box((hx, h + 0.01, s * (hl / 2 - 0.07)), (0.08, 0.035, 0.075), rounding=0.01)
        return b.shape()
    if style == "flip":
        w, t = uniform(rng, 0.42, 0.5), uniform(rng, 0.075, 0.09)
        hb = uniform(rng, 0.46, 0.52)
        ht = hb * uniform(rng, 0.9, 1.0)
        open_a = uniform(rng, 0.25, 0.5)
        # lid first: its recess is a cut
        hinge = np.array([0.0, hb, t / 2])
        rot = rotation(X, -open_a)
        b.box(hinge + rot @ np.array([0.0, ht / 2, -t / 2]), (w / 2, ht / 2, t / 2), rot, rounding=0.03)
        b.box(hinge + rot @ np.array([0.0, ht * 0.55, -t]), (w / 2 - 0.05, ht * 0.3, 0.012), rot, op="subtract")
        b.box((0, hb / 2, 0), (w / 2, hb / 2, t / 2), rounding=0.03)
        b.box((0, hb * 0.45, -t / 2), (w / 2 - 0.06, hb * 0.3, 0.012), op="subtract")
        for k in range(1, 4):  # keypad grid
            b.box((0, hb * 0.15 + hb * 0.6 * k / 4, -t / 2), (w / 2 - 0.06, 0.009, 0.015), op="subtract")
        b.box((0, hb * 0.45, -t / 2), (0.009, hb * 0.3, 0.015), op="subtract")
        b.cylinder(hinge - np.array([0.0, 0.0, 0.01]), 0.045, w / 2 - 0.02, ALONG_X)
        return b.shape()
    h = uniform(rng, 0.88, 0.95) if style == "candybar" else uniform(rng, 0.95, 1.0)  # room for the antenna
    if style == "candybar":
        w, t = uniform(rng, 0.4, 0.5), uniform(rng, 0.12, 0.18)
    else:
        w, t = uniform(rng, 0.45, 0.52), uniform(rng, 0.07, 0.09)
    b.box((0, h / 2, 0), (w / 2, h / 2, t / 2), rounding=uniform(rng, 0.025, 0.045))
    if style == "slab":
        bz, top, bot = uniform(rng, 0.025, 0.04), uniform(rng, 0.05, 0.1), uniform(rng, 0.05, 0.1)
        recess(b, -w / 2 + bz, w / 2 - bz, bot, h - top, -t / 2, 0.01)
        if chance(rng, 0.5):  # home button
            b.cylinder((0, bot / 2, -t / 2), min(0.035, bot / 2 - 0.005), 0.01, ALONG_Z, op="subtract")
        cam = uniform(rng, 0.1, 0.16)
        b.box((-w / 2 + cam / 2 + 0.04, h - cam / 2 - 0.04, t / 2), (cam / 2, cam / 2, 0.0275), rounding=0.02)
        b.box((w / 2, h * 0.7, 0), (0.0275, 0.07, 0.0275), rounding=0.01)  # side button
        return b.shape()
    # candybar: screen in the upper half, a keypad grid below, an antenna stub
    recess(b, -w / 2 + 0.06, w / 2 - 0.06, h * 0.55, h - 0.08, -t / 2, 0.02)
    for k in range(1, 5):
        b.box((0, h * 0.06 + h * 0.4 * k / 5, -t / 2), (w / 2 - 0.06, 0.009, 0.02), op="subtract")
    for s in (-1, 1):
        b.box((s * (w / 2 - 0.06) / 3, h * 0.26, -t / 2), (0.009, h * 0.2, 0.02), op="subtract")
    if chance(rng, 0.6):
        b.cylinder((w / 2 - 0.07, h + 0.05, 0), 0.03, 0.07)
    return b.shape()


STYLES = ('slab', 'flip', 'desk', 'candybar')


def sample(rng: np.random.Generator, style: str):
    return rng, style  # the generator itself: this category draws while it builds


def build(params) -> CSGShape:
    return make_phone(*params)
