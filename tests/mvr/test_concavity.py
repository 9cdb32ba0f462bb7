"""A concavity no silhouette reveals (the dent in ``dented_box``'s top face) is recovered from
shading at a small resolution (24^3): the depth cue of the head light's falloff carves it."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import trimesh

from mvr import OptimSettings, Schedule, TargetSettings, configure_runtime, reconstruct
from mvr.reconstruct import default_scene
from sdfcommon.numerics.raycast import mesh_caster


def _height(mesh: trimesh.Trimesh, x: float) -> float:
    """The height (y) where a ray down from (x, 3, 0) first meets the surface."""
    hits = mesh_caster(mesh.vertices, mesh.faces).first_hits(np.array([[x, 3.0, 0.0]]), np.array([[0.0, -1.0, 0.0]]))
    assert hits.hit[0]
    return 3.0 - float(hits.t[0])


def _dent(tmp_path, scene):
    configure_runtime(threads=1)
    res = [8, 16, 24]
    result = reconstruct("dented_box", tmp_path, target_settings=TargetSettings(mesh_resolution=64), scene=scene,
                         schedule=Schedule(resolutions=res), optim=OptimSettings(max_passes=4), progress=False)
    target = trimesh.load(tmp_path / "target.ply", process=False)
    voxel = 2.0 / (res[-1] - 1)
    top, bottom = _height(target, 0.7), _height(target, 0.0)  # the flat top face; the dent's deepest point
    assert top - bottom > 3 * voxel  # a dent the grid can hold
    return result, top, bottom, voxel


def test_dent_is_carved_by_the_default_light(tmp_path):
    result, top, bottom, voxel = _dent(tmp_path, default_scene())
    # Silhouettes alone leave the top flat (nothing carved). Measured: 48-56% of the depth (seeds 0
    # and 1); the rest stays bridged (docs/mvr_method.md, real scanned meshes).
    assert top - _height(result.mesh, 0.0) > 0.4 * (top - bottom)
    assert abs(_height(result.mesh, 0.7) - top) < voxel


def test_without_falloff_the_dent_is_ambiguous(tmp_path):
    """The head light without falloff (mvr/preset=paper) shades a dent and a bump alike from the
    camera it sits at: the run ends with the centre no lower than half the dent (measured: a bump,
    0.18 above the top face; relative Chamfer 0.013 against the default light's 0.005)."""
    scene = replace(default_scene(), camera_light=0.8, camera_light_falloff=False)
    result, top, bottom, _ = _dent(tmp_path, scene)
    assert _height(result.mesh, 0.0) > top - 0.5 * (top - bottom)
