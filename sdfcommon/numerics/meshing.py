"""Grid <-> mesh: marching cubes of SDF grids (below svr and mvr, which both mesh their grids)."""
from __future__ import annotations

from typing import Sequence, Union

import numpy as np
import torch

from sdfcommon.tooling.checks import check_shape

BoundLike = Union[float, Sequence[float]]


def sdf_to_mesh(values, bbox_min: BoundLike = -1.0, bbox_max: BoundLike = 1.0, level: float = 0.0,
                close: bool = True, off_level: bool = False):
    """The ``level`` isosurface of one SDF grid as a trimesh.Trimesh in world coordinates.

    Args:
        values: (Nx, Ny, Nz) array/tensor, ``values[i, j, k]`` at ``(x_i, y_j, z_k)`` (renderer.SDFGrid's
            layout: samples on the box faces).
        bbox_min, bbox_max: the box (scalars or 3-vectors).
        close: pad the grid with one layer of positive values first, so a shape cut by the box is
            closed there and the mesh is watertight.
        off_level: move samples within a thousandth of a voxel of the level that far off it
            (outwards when at it), so no face collapses (meshes for users; the benchmark's
            voxeliser meshes the grid as it is).
    Returns:
        trimesh.Trimesh with outward normals (faces wound counter-clockwise seen from outside);
        an empty mesh when the grid has no zero crossing.
    """
    import trimesh  # heavy: only meshing needs it
    from skimage import measure  # heavy: only marching cubes needs it

    v = values.detach().cpu().double().numpy() if isinstance(values, torch.Tensor) else np.asarray(values, float)
    check_shape(v, "values", "Nx, Ny, Nz", at_least={"Nx": 2, "Ny": 2, "Nz": 2})
    if not np.isfinite(v).all():
        raise ValueError("values contains NaN or Inf")
    lo = np.broadcast_to(np.asarray(bbox_min, float), (3,))
    hi = np.broadcast_to(np.asarray(bbox_max, float), (3,))
    spacing = (hi - lo) / (np.array(v.shape) - 1)
    # A sample at the level puts the vertices of all its edges on one point: the faces between them
    # have no area, and merged they make the mesh non-manifold (a silhouette carving's max() leaves
    # such samples). Move those samples off the level by a thousandth of a voxel.
    if off_level:
        eps = 1e-3 * float(np.abs(spacing).min())
        v = np.where(np.abs(v - level) < eps, np.where(v < level, level - eps, level + eps), v)
    offset = lo.copy()
    if close:
        pad = max(float(np.abs(v).max()), 1e-6) + abs(level) + 1.0
        v = np.pad(v, 1, mode="constant", constant_values=pad)
        offset = lo - spacing
    if not (v.min() < level < v.max()):
        return trimesh.Trimesh(vertices=np.zeros((0, 3)), faces=np.zeros((0, 3), dtype=np.int64))
    verts, faces, _, _ = measure.marching_cubes(v, level=level, spacing=tuple(spacing))
    verts = verts + offset
    # With the arguments as given here skimage winds faces so that trimesh sees outward normals
    # (positive volume for a solid); the test of this module checks it.
    return trimesh.Trimesh(vertices=verts, faces=faces, process=True)
