"""Mirror symmetry of a dataset's shapes, measured from its voxels (which NMR-format data holds): for
each world axis, the mean IoU between every object's voxels and their mirror image across the plane
through the origin normal to that axis. Man-made objects in a canonical frame are mostly symmetric
left to right; which axis that is depends on the dataset's frame, so it is measured, never assumed.
``model=pixel``'s ``local.mirror_axis: auto`` is resolved with ``symmetry_axis`` on the training
split before the network is built."""
from __future__ import annotations

from typing import Optional

import numpy as np

# World axis (x, y, z) -> the NMR voxel array's axis (svr/nmr/voxels.py: axis 0 = +y, 1 = +x,
# 2 = -z); the voxel centres are symmetric about the grid's middle, so a flip is the world mirror.
_VOXEL_AXIS = {0: 1, 1: 0, 2: 2}
AXIS_NAMES = ("x", "y", "z")


def mirror_scores(voxels: np.ndarray) -> tuple[float, float, float]:
    """Mean over objects of IoU(voxels, their mirror across x = 0, y = 0, z = 0).

    Args:
        voxels: (N, R, R, R) bool in the NMR voxel frame, N >= 1.
    """
    v = np.asarray(voxels).astype(bool)
    if v.ndim != 4 or v.shape[0] == 0 or len(set(v.shape[1:])) != 1:
        raise ValueError(f"voxels must have shape (N, R, R, R) with N >= 1, got {v.shape}")
    out = []
    for axis in range(3):
        m = np.flip(v, axis=1 + _VOXEL_AXIS[axis])
        inter = (v & m).reshape(len(v), -1).sum(1)
        union = (v | m).reshape(len(v), -1).sum(1)
        out.append(float(np.mean(np.where(union > 0, inter / np.maximum(union, 1), 1.0))))
    return tuple(out)


def symmetry_axis(voxels: np.ndarray, threshold: float = 0.8) -> Optional[int]:
    """The world axis (0 = x, 1 = y, 2 = z) across which the shapes are most symmetric, or None when
    even that axis's mean mirror IoU (``mirror_scores``) is below ``threshold``."""
    if not 0.0 < float(threshold) <= 1.0:
        raise ValueError(f"threshold must lie in (0, 1], got {threshold!r}")
    scores = mirror_scores(voxels)
    best = int(np.argmax(scores))
    return best if scores[best] >= threshold else None


__all__ = ["AXIS_NAMES", "mirror_scores", "symmetry_axis"]
