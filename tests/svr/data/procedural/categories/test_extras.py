"""The extra categories (mug, shelf: svr/data/procedural/categories/extras.py): parameter records,
named parts, one solid per object, and the mug's handle as its one hole."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from svr.data.procedural.categories import extras, make_shape, procedural_category

from .helpers import components, genus


@pytest.mark.parametrize("name,module", [("mug", "MUG"), ("shelf", "SHELF")])
def test_extras_have_records_and_parts(name, module):
    cat = procedural_category(name)
    sample, build = getattr(extras, f"sample_{name}"), getattr(extras, f"build_{name}")
    rng = np.random.default_rng(0)
    for style in getattr(extras, f"{module}_STYLES"):
        rec = sample(rng, style)
        assert dataclasses.is_dataclass(rec) and rec.style == style
        assert np.array_equal(build(rec).program, build(rec).program)
    shapes = [make_shape(name, [34, k]) for k in range(4)]
    assert all(len(s.parts) >= 2 for s in shapes) and cat.styles
    assert all(components(s) == 1 for s in shapes)
    if name == "mug":
        assert all(genus(s) == 1 for s in shapes[:2])
