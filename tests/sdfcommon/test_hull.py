"""sdfcommon.numerics.hull: signed pixel distances by hand, the compiled transform against scipy's
on random masks, and the visual hull of a sphere's exact silhouettes from the 26-camera rig against
the sphere itself."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from renderer import Cameras
from sdfcommon.numerics import hull
from sdfcommon.numerics.hull import signed_pixel_distance, visual_hull


def test_signed_pixel_distance_by_hand():
    alpha = torch.zeros(1, 9, 9)
    alpha[0, 3:6, 3:6] = 1.0  # a 3x3 square
    d = signed_pixel_distance(alpha)[0]
    assert float(d[4, 4]) == pytest.approx(-1.5)   # 2 pixels from the nearest background pixel
    assert float(d[3, 4]) == pytest.approx(-0.5)   # on the square's edge
    assert float(d[2, 4]) == pytest.approx(0.5)    # just outside: the edge is half a pixel away
    assert float(d[0, 4]) == pytest.approx(2.5)
    assert float(d[0, 0]) == pytest.approx(math.hypot(3, 3) - 0.5)
    assert bool((signed_pixel_distance(torch.zeros(1, 4, 4)) > 0).all())
    assert bool((signed_pixel_distance(torch.ones(1, 4, 4)) < 0).all())


@pytest.mark.skipif(hull.njit is None, reason="needs numba")
def test_the_compiled_distances_are_scipys():
    """The same values to the bit as scipy's transform, image by image (the specification), on
    discs, noise, single pixels, empty and full masks, square and not."""
    rng = np.random.default_rng(0)
    for h, w in [(64, 64), (32, 48), (7, 5), (1, 9)]:
        yy, xx = np.mgrid[:h, :w]
        masks = np.zeros((60, h, w), bool)
        for i in range(60):
            for _ in range(rng.integers(1, 4)):
                cy, cx, r = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(0.5, max(h, w) / 3)
                masks[i] |= (yy - cy) ** 2 + (xx - cx) ** 2 < r * r
        masks[1] = rng.random((h, w)) < 0.3
        masks[2] = False
        masks[3] = True
        masks[4] = False
        masks[4, h // 2, w // 2] = True
        masks[5] = ~masks[4]
        want = hull._signed_distances_scipy(masks)
        assert np.array_equal(hull._signed_distances_numba(masks), want)
        assert np.array_equal(signed_pixel_distance(torch.from_numpy(masks.astype(np.float32))).numpy(), want)


def _sphere_silhouettes(cams: Cameras, radius: float) -> torch.Tensor:
    """(V, H, W) exact coverage of pixel-centre rays by a sphere at the origin."""
    o, d = cams.rays()
    closest = torch.linalg.cross(o, d).norm(dim=-1)  # the ray's distance from the origin (|d| = 1)
    return (closest <= radius).float()


def test_visual_hull_of_a_sphere():
    """The sphere's 26 views bound it: the hull's field is negative inside the sphere and positive
    beyond a pixel's width outside it, and outside it grows like the distance to the sphere (the
    26 cones are nearly tangent to the sphere there)."""
    radius, size = 0.5, 96
    cams = Cameras.cube_rig(3.0, fov_deg=40.0, image_size=size)
    dist = signed_pixel_distance(_sphere_silhouettes(cams, radius))
    pixel = 3.0 * float(cams.pixel_angle[0])  # a pixel's width at the sphere's depth
    gen = torch.Generator().manual_seed(0)
    dirs = torch.nn.functional.normalize(torch.randn(400, 3, generator=gen), dim=-1)
    inner = visual_hull(dist, cams, dirs * (radius - 3 * pixel))
    assert bool((inner < 0).all())
    for gap in (0.05, 0.15):
        outer = visual_hull(dist, cams, dirs * (radius + gap))
        assert bool((outer > 0).all())
        # no view's cone is farther than the sphere; the best view's is close to it
        assert float(outer.max()) <= gap * 1.1 + pixel
        assert float(outer.min()) >= gap * 0.5 - pixel


def test_visual_hull_checks_its_input():
    cams = Cameras.cube_rig(3.0, image_size=8)
    with pytest.raises(ValueError, match="26 cameras"):
        visual_hull(torch.zeros(3, 8, 8), cams, torch.zeros(5, 3))
    with pytest.raises(ValueError, match="points must be"):
        visual_hull(torch.zeros(26, 8, 8), cams, torch.zeros(5, 2))
