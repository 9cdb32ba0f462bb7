"""The mesh builder against answers known exactly (issue 30, point 3; benchmarks.mesh_build_accuracy):
voxels of the analytic solids' meshes, clean and damaged, against the exact solids' voxels; renders
against the procedural renderer on the exact shape; procedural shapes exported as meshes and rebuilt
against the procedural data. Toy sizes here, the sizes of docs/mesh_build.md under ``-m slow``."""
from __future__ import annotations

import numpy as np
import pytest

from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.settings import build_settings
from benchmarks.mesh_build_accuracy import check_procedural, check_renders, check_solids
from data.example_meshes import damage, shape_mesh, SOLIDS
from svr.data.build.meshes import analyse_mesh


def _settings(*overrides: str):
    return build_settings(compose("build", ["input=unused", "out=unused", *overrides]))


def test_damage_does_what_it_says():
    v, f = shape_mesh(SOLIDS["sphere"](), 24)
    stats, _ = analyse_mesh(v, f)
    assert stats.watertight and stats.inconsistent_edges == 0 and stats.components == 1
    hv, hf = damage(v, f, "hole")
    assert not analyse_mesh(hv, hf)[0].watertight and len(hf) < len(f) and len(hv) < len(v)
    fv, ff = damage(v, f, "flipped")
    stats, oriented = analyse_mesh(fv, ff)
    assert stats.inconsistent_edges > 0 and np.array_equal(oriented, f)  # orientation repaired
    sv, sf = damage(v, f, "inner_shell")
    assert analyse_mesh(sv, sf)[0].components == 2 and len(sf) == 2 * len(f)


def test_voxels_of_damaged_solids_stay_close_to_the_exact_solid():
    checks = check_solids(_settings("ray_directions=7"), mesh_resolution=28, solids=("sphere", "torus"),
                          damages=("clean", "hole", "scrambled", "all"))  # scrambled: orientation repaired
    for c in checks:
        assert c.iou_builder >= 0.93, c
    by = {(c.solid, c.damage): c for c in checks}
    # A hole defeats the benchmark's surface + flood fill, not the votes.
    assert by[("sphere", "hole")].iou_protocol < 0.6 < by[("sphere", "hole")].iou_builder
    assert by[("sphere", "clean")].leak_score < 0.001 < 0.01 < by[("sphere", "hole")].leak_score


def test_renders_match_the_procedural_renderer_on_the_exact_shape():
    (check,) = check_renders(_settings("supersample=2"), mesh_resolution=40, solids=("sphere",))
    assert check.silhouette_iou >= 0.97 and check.shading_error <= 3.0 and check.alpha_error <= 3.0, check


@pytest.mark.slow
def test_full_size_checks_of_docs_mesh_build():
    settings = _settings()
    for c in check_solids(settings, mesh_resolution=96):
        assert c.iou_builder >= 0.97, c
    for c in check_renders(settings, mesh_resolution=96):
        assert c.silhouette_iou >= 0.98 and c.shading_error <= 2.0, c
    for r in check_procedural(settings, mesh_resolution=128, categories=("chair", "table", "car", "sofa")):
        assert r.voxel_iou >= 0.93 and r.render.silhouette_iou >= 0.93, r


def test_a_procedural_shape_rebuilt_from_its_mesh_matches_the_procedural_data():
    (trip,) = check_procedural(_settings("supersample=2", "ray_directions=7"), mesh_resolution=48,
                               categories=("chair",))
    assert trip.voxel_iou >= 0.85 and trip.render.silhouette_iou >= 0.85, trip
