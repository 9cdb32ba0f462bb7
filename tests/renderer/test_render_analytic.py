"""The renderer against analytic answers: sphere and torus hit masks, depth and normals."""
from __future__ import annotations

import pytest
import torch

from renderer import Cameras, SDFGrid, Scene, TraceSettings, render

from .analytic import edge_pixels, ray_analytic, ray_sphere, sphere_sdf, torus_sdf

EYES = [[0.3, 0.4, 2.5], [-2.0, 1.0, -1.0]]


@pytest.mark.parametrize("n", [32, 64, 128])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_sphere_hits_depth_normals(n, dtype):
    grid = SDFGrid.from_function(sphere_sdf(0.5), n, dtype=dtype)
    h = float(grid.voxel_size[0])
    cams = Cameras.look_at(EYES, fov_deg=40, image_size=64, dtype=dtype)
    out = render(grid, cams, trace_settings=TraceSettings(threshold=0.01 * h, max_steps=512))
    o, d = cams.rays()
    hit, t, normal = ray_sphere(o.double(), d.double(), 0.5)
    mismatch = out.hit != hit
    assert not (mismatch & ~edge_pixels(hit)).any(), "hit mask differs away from the silhouette edge"
    cos = -(normal * d.double()).sum(-1)
    good = out.hit & hit & (cos > 0.2)
    assert good.sum() > 500
    depth_err = (out.depth.double() - t)[good].abs().max().item()
    normal_err = (out.normal.double() - normal)[good].norm(dim=-1).max().item()
    assert depth_err < 0.15 * h, depth_err / h
    # Interpolated central differences converge as h^2 on a sphere of radius 0.5.
    assert normal_err < 4 * h * h / 0.5, normal_err
    assert (out.depth[~out.hit] == 0).all() and (out.normal[~out.hit] == 0).all()


@pytest.mark.parametrize("n", [48, 96])
def test_torus_hits_depth_normals(n):
    grid = SDFGrid.from_function(torus_sdf, n, dtype=torch.float64)
    h = float(grid.voxel_size[0])
    cams = Cameras.look_at(EYES, fov_deg=45, image_size=64, dtype=torch.float64)
    out = render(grid, cams, trace_settings=TraceSettings(threshold=0.01 * h, max_steps=512))
    o, d = cams.rays()
    hit, t, normal = ray_analytic(torus_sdf, o, d)
    mismatch = out.hit != hit
    assert not (mismatch & ~edge_pixels(hit)).any()
    cos = -(normal * d).sum(-1)
    good = out.hit & hit & (cos > 0.3)
    assert good.sum() > 300
    assert (out.depth - t)[good].abs().max() < 0.25 * h
    assert (out.normal - normal)[good].norm(dim=-1).max() < 0.1


def test_default_threshold_follows_pixel_footprint():
    """With the default threshold the hit point error is bounded by the footprint, not the grid."""
    grid = SDFGrid.from_function(sphere_sdf(0.5), 64)
    cams = Cameras.look_at([[0.0, 0.0, 2.5]], fov_deg=40, image_size=64)
    out = render(grid, cams)
    o, d = cams.rays()
    hit, t, normal = ray_sphere(o, d, 0.5)
    cos = -(normal * d).sum(-1)
    good = out.hit & hit & (cos > 0.5)
    footprint = 2.0 * float(cams.pixel_angle[0])
    assert (out.depth - t)[good].abs().max() < 0.5 * footprint
    assert not ((out.hit != hit) & ~edge_pixels(hit)).any()


def test_shading_is_lambert_plus_ambient():
    grid = SDFGrid.from_function(sphere_sdf(0.5), 64, dtype=torch.float64)
    from renderer import DirectionalLight

    light = DirectionalLight((0.0, 0.0, 1.0), 0.7)
    scene = Scene(lights=(light,), ambient=0.1, albedo=(1.0, 0.5, 0.25), background=(0.2, 0.3, 0.4))
    cams = Cameras.look_at([[0.0, 0.0, 2.5]], fov_deg=40, image_size=32, dtype=torch.float64)
    out = render(grid, cams, scene)
    n = out.normal[out.hit]
    expect = (0.1 + 0.7 * n[:, 2].clamp(min=0))[:, None] * torch.tensor([1.0, 0.5, 0.25], dtype=torch.float64)
    torch.testing.assert_close(out.image[out.hit], expect)
    torch.testing.assert_close(out.image[~out.hit], torch.tensor([0.2, 0.3, 0.4], dtype=torch.float64).expand(
        int((~out.hit).sum()), 3))


def test_silhouette_matches_hits_and_is_soft_at_the_edge():
    grid = SDFGrid.from_function(sphere_sdf(0.5), 64)
    cams = Cameras.look_at([[0.0, 0.0, 2.5]], fov_deg=40, image_size=64)
    out = render(grid, cams, Scene(effects=("silhouette",)))
    o, d = cams.rays()
    hit, _, _ = ray_sphere(o, d, 0.5)
    near_edge = edge_pixels(edge_pixels(hit))  # within 2 pixels of the silhouette edge
    inner = hit & ~near_edge
    outer = ~hit & ~near_edge
    assert out.silhouette[inner].min() > 0.99
    assert out.silhouette[outer].max() < 0.01
    edge = out.silhouette[edge_pixels(hit)]
    assert ((edge > 0.05) & (edge < 0.95)).any()
