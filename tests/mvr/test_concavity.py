"""A concavity no silhouette reveals (the dent in ``dented_box``'s top face) is recovered at a small
resolution (24^3) from the depth cue of the head light's falloff, and without that cue (the paper's
light) from the motion of the dent's occlusion edges, which only the visibility gradient gives."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from mvr import OptimSettings, Schedule, TargetSettings, configure_runtime, reconstruct
from mvr.reconstruct import default_scene
from sdfcommon.numerics.raycast import mesh_caster


def _height(mesh: trimesh.Trimesh, x: float) -> float:
    """The height (y) where a ray down from (x, 3, 0) first meets the surface."""
    hits = mesh_caster(mesh.vertices, mesh.faces).first_hits(np.array([[x, 3.0, 0.0]]), np.array([[0.0, -1.0, 0.0]]))
    assert hits.hit[0]
    return 3.0 - float(hits.t[0])


def _dent(tmp_path, scene, passes=4, seed=0, erosion=2.0):
    configure_runtime(threads=1)
    res = [8, 16, 24]
    result = reconstruct("dented_box", tmp_path, target_settings=TargetSettings(mesh_resolution=64), scene=scene,
                         schedule=Schedule(resolutions=res), optim=OptimSettings(max_passes=passes, erosion=erosion), progress=False,
                         seed=seed)
    target = trimesh.load(tmp_path / "target.ply", process=False)
    voxel = 2.0 / (res[-1] - 1)
    top, bottom = _height(target, 0.7), _height(target, 0.0)  # the flat top face; the dent's deepest point
    assert top - bottom > 3 * voxel  # a dent the grid can hold
    return result, top, bottom, voxel


def test_dent_is_carved_by_the_default_light(tmp_path):
    result, top, bottom, voxel = _dent(tmp_path, default_scene())
    # Silhouettes alone leave the top flat (nothing carved). Measured on 2026-11-28 without the erosion
    # of the last level (optim.erosion=0): 96%, 89% and 93%
    # of the depth (seeds 0, 1, 2), with the visibility gradient 93% and 92% (seeds 1, 2).
    assert top - _height(result.mesh, 0.0) > 0.75 * (top - bottom)
    assert abs(_height(result.mesh, 0.7) - top) < voxel


def test_without_falloff_the_dent_is_ambiguous(tmp_path):
    """The head light without falloff (mvr/preset=paper) shades a dent and a bump alike from the
    camera it sits at: the run ends with the centre no lower than half the dent (measured: a bump,
    0.18 above the top face; relative Chamfer 0.013 against the default light's 0.005)."""
    scene = replace(default_scene(), camera_light=0.8, camera_light_falloff=False)
    result, top, bottom, _ = _dent(tmp_path, scene)
    assert _height(result.mesh, 0.0) > top - 0.5 * (top - bottom)


@pytest.mark.slow
def test_visibility_gradient_carves_the_dent_the_paper_gradient_bumps(tmp_path):
    """Under the paper's light (no falloff) shading cannot tell the dent from a bump; from the
    oblique views the dent's near rim hides part of it, an occlusion edge whose motion the
    visibility gradient follows and the paper's does not. Six passes a level, the first three
    seeds (docs/mvr_method.md, 2026-11-28: over seeds 0-7 the paper's gradient ended with a bump
    0.7-0.8 of the depth high on 7 of 8, the visibility gradient carved 88-99% of the depth on 7 of
    8 and 34% on seed 0)."""
    light = dict(camera_light=0.8, camera_light_falloff=False)
    carved = {}
    for gradient in ("paper", "visibility"):
        scene = replace(default_scene(), gradient=gradient, **light)
        for seed in (0, 1, 2):
            # without the last level's erosion, as measured (it came later)
            result, top, bottom, _ = _dent(tmp_path / f"{gradient}{seed}", scene, passes=6, seed=seed, erosion=0.0)
            carved[gradient, seed] = (top - _height(result.mesh, 0.0)) / (top - bottom)
    # Measured: paper -0.81, -0.68, -0.79; visibility 0.34, 0.88, 0.96.
    assert np.mean([carved["visibility", s] for s in (0, 1, 2)]) > 0.5
    assert np.mean([carved["paper", s] for s in (0, 1, 2)]) < 0.0
    assert all(carved["visibility", s] > carved["paper", s] + 0.5 for s in (0, 1, 2))
