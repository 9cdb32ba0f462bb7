"""Speaker and cabinet (round 2 of issue 29): hidden depths (recessed baffles, open backs, hollows
underneath, open doors, pulled-out drawers, open cells of drawn depth), new forms, and that every
object stays one labelled solid of a few tens of rows."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from svr.data.procedural.categories import cabinet, speaker
from svr.data.procedural.generator import voxelize_shape


def _records(module, n: int = 200):
    return [module.sample(np.random.default_rng([31, k]), module.STYLES[k % len(module.STYLES)]) for k in range(n)]


def test_speaker_hidden_depths_and_forms_are_drawn():
    recs = _records(speaker)
    assert {r.form for r in recs if r.style == "soundbar"} == set(speaker.BAR_FORMS)
    assert any(r.handle for r in recs if r.form == "boombox")
    box = [r for r in recs if r.style != "round"]
    rec = [r.recess / r.depth for r in box if r.recess > 0]
    assert 0.2 < len(rec) / len(box) < 0.9 and min(rec) < 0.2 and max(rec) > 0.5
    assert sum(r.back_open > 0 for r in box) >= 15
    assert sum(r.gap[1] > 0 for r in recs) >= 5
    assert sum(r.bottom_well > 0 for r in recs) >= 3
    walls = [r.wall for r in box]
    assert min(walls) < 0.07 and max(walls) > 0.13
    assert np.ptp([r.top_well for r in recs]) > 0.6


def test_cabinet_open_doors_pulled_drawers_and_cell_depths_are_drawn():
    recs = _records(cabinet)
    kinds = [kind for r in recs for s in r.sections for t in s.tiers for kind, _ in t.cells]
    assert set(kinds) == set(cabinet.CELL_KINDS)
    assert kinds.count("ajar") >= 10 and kinds.count("pulled") >= 10
    depths = [t.depth for r in recs for s in r.sections for t in s.tiers]
    assert min(depths) < 0.4 and any(d == 1.0 for d in depths)
    angles = [r.door_angle for r in recs]
    assert min(angles) < 0.5 and max(angles) > 1.7
    assert np.ptp([r.pull for r in recs]) > 0.4
    fr = [r.front_recess / r.depth for r in recs if r.front_recess > 0]
    assert len(fr) > 40 and max(fr) > 0.3
    assert np.ptp([r.panel for r in recs]) > 0.06


@pytest.mark.parametrize("module", [speaker, cabinet], ids=["speaker", "cabinet"])
def test_every_style_builds_one_labelled_solid(module):
    for k in range(24):
        style = module.STYLES[k % len(module.STYLES)]
        shape = module.build(module.sample(np.random.default_rng([33, k]), style)).normalized()
        vox = voxelize_shape(shape, rule="protocol")
        _, count = ndimage.label(vox, structure=np.ones((3, 3, 3)))
        assert count == 1, (style, k, count)
        assert 2 <= len(shape.parts) <= 8, shape.parts
        assert len(shape.program) <= 45, (style, k, len(shape.program))
