"""How procedural objects look: per-object and per-part colours drawn from a wide palette, and the
light of the NMR renders (SPEC section 5b). ShapeNet objects carry material colours per part (near
black speakers, liveried cars, white cabinets, two-tone chairs), so each object draws a colour
scheme (one colour, two tones, or a colour per part) and its colours from families that span dark,
grey, near-white, saturated, pastel and wood tones (``draw_colours``), from a random stream of its
own (``colour_rng``) so that colours never change a shape. ``NMR_LIGHTING`` shades them as NMR's
Blender Internal scene would have: one lamp (energy 1, a material's diffuse intensity 0.8) and
environment light 0.5 scaled by the material's ambient 0.5. The lamp's placement was never
published; we put it where Blender's default scene keeps its lamp, seen from the origin, and the
lamp stays fixed in the world while the camera orbits.
"""
from __future__ import annotations

import colorsys
from dataclasses import dataclass
from typing import Mapping, Sequence, Union

import numpy as np
import torch

import renderer

Seed = Union[int, Sequence[int]]

# Colour families: (weight, hue range, saturation range, value range) in HSV. A hue range of None
# draws any hue.
FAMILIES: Mapping[str, tuple[float, tuple[float, float] | None, tuple[float, float], tuple[float, float]]] = {
    "dark": (0.2, None, (0.0, 0.5), (0.04, 0.22)),
    "grey": (0.15, None, (0.0, 0.1), (0.3, 0.75)),
    "near_white": (0.15, None, (0.0, 0.08), (0.85, 0.98)),
    "saturated": (0.2, None, (0.6, 1.0), (0.45, 0.95)),
    "pastel": (0.12, None, (0.18, 0.45), (0.7, 0.95)),
    "wood": (0.18, (0.04, 0.11), (0.35, 0.75), (0.25, 0.75)),
}
# Colour schemes of an object: every part one colour; a main colour with an accent on some parts;
# every part its own colour.
SCHEMES: Mapping[str, float] = {"one_colour": 0.4, "two_tone": 0.4, "per_part": 0.2}
# The extra entry of an object's seed that starts its colour stream.
COLOUR_STREAM = 0xC01

# Blender's default lamp at (4.08, 1.01, 5.90) in Blender's z-up frame is (4.08, 5.90, -1.01) in
# ShapeNet's y-up frame, as the OBJ importer maps it.
_DEFAULT_LAMP = (4.0762, 5.9039, -1.0055)


@dataclass(frozen=True)
class Lighting:
    """One distant lamp plus uniform environment light: ``rgb = albedo * (environment + lamp *
    max(0, n . l))``, clipped to 1.

    Attributes:
        direction: world direction towards the lamp (y up; normalised when used).
        lamp: the lamp's diffuse strength (energy x the material's diffuse intensity x falloff).
        environment: the uniform light (environment energy x the material's ambient).
    """

    direction: tuple[float, float, float]
    lamp: float
    environment: float

    def scene(self) -> renderer.Scene:
        """The renderer's Scene of this light on a white albedo (radiance per unit albedo)."""
        return renderer.Scene(effects=("shading",), lights=(renderer.DirectionalLight(tuple(self.direction), self.lamp),),
                              ambient=self.environment, albedo=(1.0,), background=(1.0,))

    def shade(self, normals: np.ndarray, albedo: np.ndarray) -> np.ndarray:
        """(K, 3) unit normals and (K, 3) albedo -> (K, 3) RGB in [0, 1]."""
        n = torch.from_numpy(np.ascontiguousarray(normals, dtype=np.float64))
        radiance = renderer.shade_lambert(n, torch.zeros_like(n), torch.zeros_like(n), self.scene())
        return np.clip(radiance.numpy() * np.asarray(albedo, dtype=np.float64), 0.0, 1.0)


# Lamp energy 1 x diffuse intensity 0.8 x the inverse-square falloff of a lamp of distance 30 at
# 7.2 from the origin (30^2 / (30^2 + 7.2^2) = 0.945); environment energy 0.5 x ambient 0.5.
NMR_LIGHTING = Lighting(direction=_DEFAULT_LAMP, lamp=0.8 * 0.945, environment=0.25)
# What an object looks like when no colours are given: every part mid grey.
NEUTRAL_COLOUR = (0.7, 0.7, 0.7)


def colour_rng(seed: Seed) -> np.random.Generator:
    """The random stream of an object's colours: its seed plus ``COLOUR_STREAM``, apart from the
    stream its shape is drawn from."""
    entropy = [int(seed)] if np.isscalar(seed) else [int(s) for s in seed]
    return np.random.default_rng(np.random.SeedSequence([*entropy, COLOUR_STREAM]))


def _pick(rng: np.random.Generator, table: Mapping) -> str:
    names = list(table)
    weights = np.array([table[n] if np.isscalar(table[n]) else table[n][0] for n in names], dtype=np.float64)
    return names[int(rng.choice(len(names), p=weights / weights.sum()))]


def draw_colour(rng: np.random.Generator, family: str | None = None) -> tuple[float, float, float]:
    """One RGB colour in [0, 1] from a family of ``FAMILIES`` (drawn by weight when None)."""
    family = family or _pick(rng, FAMILIES)
    _, hue, sat, val = FAMILIES[family]
    h = float(rng.uniform(*hue)) if hue is not None else float(rng.random())
    return tuple(float(c) for c in colorsys.hsv_to_rgb(h, float(rng.uniform(*sat)), float(rng.uniform(*val))))


def draw_colours(rng: np.random.Generator, parts: Sequence[str]) -> np.ndarray:
    """The colours of an object's parts, (P, 3) float64 in [0, 1], one row per name of ``parts``.

    The scheme (``SCHEMES``) is drawn first: one colour for all parts, a main colour with an accent
    colour on a random non-empty subset of the parts (not all of them), or a colour per part; each
    colour is drawn from a family of ``FAMILIES``.
    """
    scheme = _pick(rng, SCHEMES)
    main = draw_colour(rng)
    out = np.tile(np.asarray(main), (len(parts), 1))
    if len(parts) < 2 or scheme == "one_colour":
        return out
    if scheme == "two_tone":
        accent = draw_colour(rng)
        chosen = rng.random(len(parts)) < 0.5
        if not chosen.any() or chosen.all():
            chosen[:] = False
            chosen[int(rng.integers(len(parts)))] = True
        out[chosen] = accent
        return out
    for k in range(1, len(parts)):
        out[k] = draw_colour(rng)
    return out


__all__ = ["FAMILIES", "SCHEMES", "COLOUR_STREAM", "Lighting", "NMR_LIGHTING", "NEUTRAL_COLOUR", "colour_rng",
           "draw_colour", "draw_colours"]
