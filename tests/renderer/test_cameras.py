"""Camera conventions: the NMR benchmark cameras, look-at handedness, the 26-view rig."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from renderer import Cameras, SDFGrid, Scene, render


def nmr_pixel_from_spec(point: np.ndarray, view: int, size: int = 64) -> tuple[float, float]:
    """SPEC section 5 written out independently: (column, row) of a world point in view k."""
    d, e, az = 2.732, math.radians(30.0), math.radians(-15.0 * view)
    eye = np.array([d * math.cos(e) * math.sin(az), d * math.sin(e), -d * math.cos(e) * math.cos(az)])
    z = -eye / np.linalg.norm(eye)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rel = point - eye
    sx = rel @ x / (rel @ z) / math.tan(math.radians(15.0))
    sy = rel @ y / (rel @ z) / math.tan(math.radians(15.0))
    return (sx + 1) * size / 2 - 0.5, (1 - sy) * size / 2 - 0.5


@pytest.mark.parametrize("view", [0, 5, 13, 23])
def test_nmr_projection_matches_spec(view):
    rng = np.random.default_rng(view)
    pts = rng.uniform(-0.5, 0.5, size=(20, 3))
    cams = Cameras.nmr([view], dtype=torch.float64)
    pix, depth = cams.project(torch.from_numpy(pts))
    expect = np.array([nmr_pixel_from_spec(p, view) for p in pts])
    np.testing.assert_allclose(pix[0].numpy(), expect, atol=1e-9)
    assert (depth > 0).all()


def test_nmr_ray_through_pixel_centre_hits_the_point_there():
    """A tiny sphere at a known point is seen at the pixel the SPEC's formulas give."""
    centre = np.array([0.21, -0.13, 0.17])
    for view in (0, 7, 18):
        col, row = nmr_pixel_from_spec(centre, view)
        grid = SDFGrid.from_function(lambda p: (p - torch.tensor(centre)).norm(dim=-1) - 0.02, 96,
                                     bbox_min=-0.6, bbox_max=0.6, dtype=torch.float64)
        out = render(grid, Cameras.nmr([view], dtype=torch.float64), Scene(effects=("depth",)))
        rows, cols = out.hit[0].nonzero(as_tuple=True)
        assert len(rows) > 0
        assert abs(rows.double().mean().item() - row) < 0.75
        assert abs(cols.double().mean().item() - col) < 0.75


def test_nmr_is_mirrored_relative_to_look_at():
    nmr = Cameras.nmr([0], dtype=torch.float64)
    la = Cameras.look_at(nmr.eye, fov_deg=30, image_size=64, dtype=torch.float64)
    torch.testing.assert_close(nmr.forward, la.forward)
    torch.testing.assert_close(nmr.right, -la.right)
    torch.testing.assert_close(nmr.up, la.up)
    # View 0 looks from -z: world +x is on the right of the NMR image.
    assert nmr.right[0, 0] > 0.99


def test_look_at_is_right_handed():
    cams = Cameras.look_at([[0.0, 0.0, 3.0], [0.0, 0.0, -3.0]], fov_deg=60, image_size=(32, 48))
    pix, _ = cams.project(torch.tensor([[0.5, 0.0, 0.0], [0.0, 0.5, 0.0]]))
    assert pix[0, 0, 0] > 24 and pix[1, 0, 0] < 24  # +x right from +z, left from -z
    assert pix[0, 1, 1] < 16 and pix[1, 1, 1] < 16  # +y towards row 0 (the top)


def test_rays_go_through_pixel_centres():
    cams = Cameras.look_at([[0.4, 0.8, 2.0]], fov_deg=50, image_size=(12, 20), dtype=torch.float64)
    o, d = cams.rays()
    pts = o + 1.7 * d
    pix, _ = cams.project(pts.reshape(1, -1, 3))
    rows, cols = torch.meshgrid(torch.arange(12.0), torch.arange(20.0), indexing="ij")
    torch.testing.assert_close(pix[0, :, 0].reshape(12, 20), cols.double())
    torch.testing.assert_close(pix[0, :, 1].reshape(12, 20), rows.double())
    torch.testing.assert_close(d.norm(dim=-1), torch.ones(1, 12, 20, dtype=torch.float64))


def test_cube_rig_has_26_distinct_views_at_distance():
    cams = Cameras.cube_rig(3.0, fov_deg=40, image_size=16)
    assert cams.batch_size == 26
    torch.testing.assert_close(cams.eye.norm(dim=-1), torch.full((26,), 3.0))
    dirs = cams.eye / 3.0
    assert torch.cdist(dirs, dirs).add(torch.eye(26) * 10).min() > 0.3
    torch.testing.assert_close(cams.forward, -dirs)
    for m in (cams.forward, cams.right, cams.up):
        torch.testing.assert_close(m.norm(dim=-1), torch.ones(26))


@pytest.mark.parametrize("kwargs, word", [
    (dict(eye=[0.0, 0.0, 3.0], fov_deg=0.0), "fov_deg"),
    (dict(eye=[0.0, 0.0, 3.0], fov_deg=-10.0), "fov_deg"),
    (dict(eye=[0.0, 0.0, 3.0], fov_deg=180.0), "fov_deg"),
    (dict(eye=[0.0, 0.0, 3.0], image_size=0), "image_size"),
    (dict(eye=[0.0, 0.0, 3.0], image_size=(16, -2)), "image_size"),
    (dict(eye=[0.0, 0.0, 3.0], up=[0.0, 0.0, 0.0]), "up"),
    (dict(eye=[0.0, 0.0, 0.0]), "eye"),
    (dict(eye=[0.0, 3.0, 0.0]), "up"),
    (dict(eye=[[0.0, 0.0, 3.0]] * 2, at=[[0.0, 0.0, 0.0]] * 3), "at"),
    (dict(eye=[0.0, float("nan"), 3.0]), "eye"),
])
def test_bad_camera_arguments_raise(kwargs, word):
    with pytest.raises(ValueError, match=word):
        Cameras.look_at(**kwargs)


def test_moved_cameras_turn_about_the_eye_and_shift():
    """``Cameras.moved``: nothing moved is the same camera; a quarter turn about +y takes a camera
    on +z looking at the origin to one looking along -x from the same eye; the axes stay
    orthonormal; the gradient at zero is finite."""
    cams = Cameras.look_at([[0.0, 0.0, 3.0], [1.0, 2.0, 2.0]], dtype=torch.float64)
    same = cams.moved(torch.zeros(3, dtype=torch.float64), torch.zeros(2, 3, dtype=torch.float64))
    for a, b in ((same.eye, cams.eye), (same.forward, cams.forward), (same.right, cams.right), (same.up, cams.up)):
        torch.testing.assert_close(a, b, atol=1e-15, rtol=0)
    turned = cams[0].moved(rotation=[0.0, math.pi / 2, 0.0], translation=[0.5, 0.0, 0.0])
    torch.testing.assert_close(turned.forward[0], torch.tensor([-1.0, 0.0, 0.0], dtype=torch.float64))
    torch.testing.assert_close(turned.right[0], torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64))
    torch.testing.assert_close(turned.eye[0], torch.tensor([0.5, 0.0, 3.0], dtype=torch.float64))
    rot = torch.tensor([[0.3, -0.2, 0.5], [0.0, 0.0, 0.0]], dtype=torch.float64, requires_grad=True)
    moved = cams.moved(rotation=rot)
    axes = torch.stack([moved.forward, moved.right, moved.up], -1)
    torch.testing.assert_close(axes.transpose(1, 2) @ axes, torch.eye(3, dtype=torch.float64).expand(2, 3, 3))
    assert moved.requires_grad and not cams.requires_grad and not moved.detach().requires_grad
    (grad,) = torch.autograd.grad(moved.forward.sum() + moved.right[:, 0].sum(), rot)
    assert torch.isfinite(grad).all() and grad[1].abs().sum() > 0
    with pytest.raises(ValueError, match="rotation must have shape"):
        cams.moved(rotation=torch.zeros(3, 3))
    with pytest.raises(ValueError, match="translation must have shape"):
        cams.moved(translation=torch.zeros(2))
