"""The procedural shape categories of the ShapeNet-shaped benchmark, as parametric CSG shapes: the
13 categories of NMR ShapeNet (the same synset ids, in the order of ``svr.nmr.format.NMR_CATEGORIES``),
one module each, and two extras (mug, shelf, in ``extras``). Each category has a few *styles*,
structurally different variants, and within a style an object's proportions, part shapes, part
counts and optional parts are drawn into one parameter record from a ``numpy.random.Generator``, so
that an object is reproducible from its seed (``make_shape``, which also normalises it: bounding
box centred, longest side 1, as ShapeNet). The conventions every raw shape keeps (orientation,
thinnest part, holes, named parts, the size of a CSG program) are in the docstring of
``ProceduralCategory``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Sequence, Union

import numpy as np

from svr.data.procedural.categories import (airplane, bench, cabinet, car, chair, display, extras, lamp, phone, rifle,
                                            sofa, speaker, table, vessel)
from svr.data.procedural.categories.blocks import MAX_RAW_SIZE, MIN_PART
from svr.data.procedural.csg import CSGShape

Seed = Union[int, Sequence[int]]


@dataclass(frozen=True)
class ProceduralCategory:
    """A procedural category.

    A category module draws one parameter record per object (``sample(rng, style)``: every random
    draw happens there) and builds the raw shape from it (``build(params)``: no randomness), so that
    an object is its record. The raw shapes keep these conventions, which ``make_shape`` keeps when it
    normalises them. They are y up, and objects that stand stand on y = 0 before normalisation.
    The front faces -z, towards NMR view 0 (whose eye is on the -z axis): chair and sofa seats open
    to -z with their backs at +z, screens, speaker drivers and cabinet doors face -z, and phones
    stand upright with the screen to -z. Long objects lie along z with their front to -z: the
    airplane's nose, the car's bonnet, the rifle's muzzle and the vessel's bow. Raw shapes are built
    at about unit size with every part at least ``MIN_PART`` thick and a longest side of at most
    ``MAX_RAW_SIZE``, so that after normalisation the thinnest part is at least
    ``MIN_PART / MAX_RAW_SIZE`` = 0.05 thick, 1.5 voxels of the 32^3 benchmark grid: thin enough for
    holes and legs, thick enough for the benchmark's voxels. Shapes have holes (genus > 0) where
    the real category has them: chair backs and arms, table stretchers and shelves, bench slats,
    lamp arms, display stands, rifle trigger guards and scopes, boat thwarts. Each row of a CSG
    program costs time in every render and voxelisation, so a shape holds a few tens of primitives
    at most; hollow parts (shades, beds, recesses) are built before the parts that must not be cut,
    since a subtraction removes material from everything added before it.

    Attributes:
        category_id: 8 digits; ShapeNet's synset id for the NMR categories, 9000000x for extras.
        name: e.g. "chair".
        styles: the structurally different variants ``make`` knows.
        sample: ``(rng, style) -> params``, the object's parameter record.
        build: ``params -> CSGShape``, the raw (un-normalised) shape; ``make_shape`` normalises. Its
            primitives are labelled with named parts (``CSGBuilder.part``), which get the colours.
    """

    category_id: str
    name: str
    styles: tuple[str, ...]
    sample: Callable[[np.random.Generator, str], Any]
    build: Callable[[Any], CSGShape]

    def make(self, rng: np.random.Generator, style: str) -> CSGShape:
        """The raw shape of a newly drawn object of a style."""
        return self.build(self.sample(rng, style))


def _from(category_id: str, name: str, module) -> ProceduralCategory:
    return ProceduralCategory(category_id, name, module.STYLES, module.sample, module.build)


NMR_PROCEDURAL_CATEGORIES: tuple[ProceduralCategory, ...] = (
    _from("02691156", "airplane", airplane),
    _from("02828884", "bench", bench),
    _from("02933112", "cabinet", cabinet),
    _from("02958343", "car", car),
    _from("03001627", "chair", chair),
    _from("03211117", "display", display),
    _from("03636649", "lamp", lamp),
    _from("03691459", "speaker", speaker),
    _from("04090263", "rifle", rifle),
    _from("04256520", "sofa", sofa),
    _from("04379243", "table", table),
    _from("04401088", "phone", phone),
    _from("04530566", "vessel", vessel),
)
EXTRA_CATEGORIES: tuple[ProceduralCategory, ...] = (
    ProceduralCategory("90000006", "mug", extras.MUG_STYLES, extras.sample_mug, extras.build_mug),
    ProceduralCategory("90000008", "shelf", extras.SHELF_STYLES, extras.sample_shelf, extras.build_shelf),
)
ALL_CATEGORIES: tuple[ProceduralCategory, ...] = NMR_PROCEDURAL_CATEGORIES + EXTRA_CATEGORIES
_BY_KEY = {**{c.name: c for c in ALL_CATEGORIES}, **{c.category_id: c for c in ALL_CATEGORIES}}


def procedural_category(key: str) -> ProceduralCategory:
    """A category by name ("chair") or id ("03001627").

    Raises:
        ValueError: for an unknown key, listing the valid names.
    """
    try:
        return _BY_KEY[str(key)]
    except KeyError:
        raise ValueError(f"unknown procedural category {key!r}; expected one of "
                         f"{[c.name for c in ALL_CATEGORIES]} or their ids") from None


def _draw(category: str, seed: Seed) -> tuple[ProceduralCategory, np.random.Generator, str]:
    """The category, the object's generator and its style, drawn first from that generator."""
    cat = procedural_category(category)
    rng = np.random.default_rng(np.random.SeedSequence(seed))
    return cat, rng, cat.styles[int(rng.integers(len(cat.styles)))]


def style_of(category: str, seed: Seed) -> str:
    """The style ``make_shape(category, seed)`` uses."""
    return _draw(category, seed)[2]


def make_shape(category: str, seed: Seed, style: str | None = None) -> CSGShape:
    """One normalised shape (centred on its bounding box, longest side 1) of a category.

    Args:
        category: a name or id (``procedural_category``).
        seed: an int or a sequence of ints (``np.random.SeedSequence``).
        style: one of the category's styles, or None for the one drawn from the seed
            (``style_of``). The style is drawn either way, so that ``make_shape(c, s,
            style_of(c, s))`` is ``make_shape(c, s)``.
    Returns:
        the CSGShape in the world frame (y up, front to -z).
    """
    cat, rng, drawn = _draw(category, seed)
    if style is None:
        style = drawn
    elif style not in cat.styles:
        raise ValueError(f"style must be one of {cat.name}'s styles {list(cat.styles)}, got {style!r}")
    return cat.make(rng, style).normalized()


__all__ = [
    "ALL_CATEGORIES", "EXTRA_CATEGORIES", "MAX_RAW_SIZE", "MIN_PART", "NMR_PROCEDURAL_CATEGORIES",
    "ProceduralCategory", "make_shape", "procedural_category", "style_of",
]
