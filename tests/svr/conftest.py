"""Shared single-view test data: a tiny procedural dataset, made once per test session."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from svr.data.procedural.csg import CSGBuilder, CSGShape, rotation
from svr.data.procedural.generator import ProceduralSettings, ensure_procedural_dataset

# Three categories, one of them with a handle on the +x side (mug) and one with a back on +z (chair).
TINY_SETTINGS = ProceduralSettings(categories=("chair", "mug", "lamp"), train=2, val=1, test=1, seed=3, supersample=2)


@pytest.fixture(scope="session")
def tiny_procedural(tmp_path_factory) -> tuple[Path, Path, ProceduralSettings]:
    """(cache dir, dataset folder, settings) of a 3-category, 4-objects-per-category dataset."""
    cache = tmp_path_factory.mktemp("procedural-cache")
    root = ensure_procedural_dataset(cache, TINY_SETTINGS, progress=False)
    return cache, root, TINY_SETTINGS


def asymmetric_shape() -> CSGShape:
    """A normalised shape with no mirror symmetry and no axis swap symmetry: a tall box with a
    sphere towards +x, a rod towards +z and a torus at the top towards -x."""
    b = CSGBuilder()
    b.box((0.0, 0.0, 0.0), (0.12, 0.35, 0.1))
    b.sphere((0.3, -0.2, 0.0), 0.14)
    b.rod((0.0, 0.15, 0.0), (0.0, 0.15, 0.3), 0.06)
    b.torus((-0.12, 0.33, 0.0), 0.1, 0.04, rotation((1, 0, 0), np.pi / 2))
    return b.shape().normalized()
