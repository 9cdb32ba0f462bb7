"""svr.data.symmetry: the mirror axis is measured from voxels in the NMR frame, and the training
command resolves model=pixel's ``mirror_axis: auto`` with it."""
from __future__ import annotations

import numpy as np
import pytest

from svr.data.symmetry import mirror_scores, symmetry_axis
from svr.nmr.voxels import nmr_voxel_centres


def shapes_symmetric_in_x(n: int = 3) -> np.ndarray:
    """(n, 32, 32, 32) NMR-frame voxels of boxes centred on x = 0 but pushed towards +y and -z."""
    c = nmr_voxel_centres().numpy()  # (32, 32, 32, 3) world x, y, z of each voxel
    out = []
    for k in range(n):
        half = 0.1 + 0.05 * k
        out.append((np.abs(c[..., 0]) < half) & (c[..., 1] > 0.05) & (c[..., 1] < 0.4) & (c[..., 2] < -0.1))
    return np.stack(out)


def test_the_measured_axis_is_the_world_axis_of_the_symmetry():
    vox = shapes_symmetric_in_x()
    sx, sy, sz = mirror_scores(vox)
    assert sx == pytest.approx(1.0) and sy == 0.0 and sz == 0.0
    assert symmetry_axis(vox) == 0
    # The same shapes turned by 90 degrees about y (x -> z): now symmetric across z = 0.
    c = nmr_voxel_centres().numpy()
    turned = np.stack([(np.abs(c[..., 2]) < 0.2) & (c[..., 1] > 0.05) & (c[..., 0] > 0.1)])
    assert symmetry_axis(turned) == 2
    # Half-symmetric shapes: below the threshold there is no axis.
    mixed = np.concatenate([vox[:1], turned])
    assert symmetry_axis(mixed, threshold=0.8) is None
    assert symmetry_axis(mixed, threshold=0.4) in (0, 2)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="voxels"):
        mirror_scores(np.zeros((0, 32, 32, 32), bool))
    with pytest.raises(ValueError, match="threshold"):
        symmetry_axis(shapes_symmetric_in_x(), threshold=0.0)
