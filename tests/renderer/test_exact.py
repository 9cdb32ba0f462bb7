"""The exact intersection mode: more accurate than the conservative point, correct gradients
through the root, finite on the hard cases."""
from __future__ import annotations

import pytest
import torch

from renderer import Cameras, SDFGrid, Scene, TraceSettings, render, shade_trace, sphere_trace

from .analytic import ray_sphere, sphere_sdf, torus_sdf
from .test_robustness import ALL


def test_exact_is_more_accurate_than_conservative_at_the_default_threshold():
    grid = SDFGrid.from_function(sphere_sdf(0.5), 64, dtype=torch.float64)
    h = float(grid.voxel_size[0])
    cams = Cameras.look_at([[0.3, 0.4, 2.5]], fov_deg=40, image_size=64, dtype=torch.float64)
    o, d = cams.rays()
    hit, t, normal = ray_sphere(o, d, 0.5)
    good = hit & (-(normal * d).sum(-1) > 0.2)
    errs = {}
    for mode in ("conservative", "exact"):
        out = render(grid, cams, Scene(effects=("depth",), intersection=mode))
        errs[mode] = (out.depth - t)[good & out.hit].abs().max().item()
    assert errs["exact"] < 0.1 * h
    assert errs["exact"] < 0.2 * errs["conservative"]


def test_gradcheck_through_the_root():
    torch.manual_seed(0)
    base = SDFGrid.from_function(sphere_sdf(0.45, (0.03, -0.02, 0.01)), 7, dtype=torch.float64)
    values = (base.values + 0.01 * torch.randn_like(base.values)).requires_grad_(True)
    cams = Cameras.look_at([[0.31, 0.27, 2.3]], fov_deg=38, image_size=8, dtype=torch.float64)
    trace = sphere_trace(SDFGrid(values), cams, TraceSettings(threshold=1e-2))
    scene = Scene(effects=("depth", "normal"), intersection="exact")
    assert trace.hit.sum() > 10

    def f(v):
        out = shade_trace(SDFGrid(v), cams, trace, scene)
        return out.depth, out.normal

    assert torch.autograd.gradcheck(f, (values,), eps=1e-6, atol=1e-5, rtol=1e-3)


@pytest.mark.parametrize("case", ["grazing", "corners", "flat", "full", "tiny", "huge", "size2", "inside"])
def test_exact_mode_stays_finite_on_hard_cases(case):
    torch.manual_seed(3)
    cams = Cameras.look_at([[0.3, 0.2, 3.0]], fov_deg=50, image_size=12)
    if case == "grazing":
        values = SDFGrid.from_function(sphere_sdf(0.5), 32).values
        cams = Cameras.look_at([[0.5, 0.0, 3.0]], at=[[0.5, 0.0, 0.0]], fov_deg=2.0, image_size=9)
    elif case == "corners":
        values = SDFGrid.from_function(lambda p: p[..., 2] - 0.25, 9).values
    elif case == "flat":
        values = torch.zeros(1, 8, 8, 8)
    elif case == "full":
        values = torch.full((1, 8, 8, 8), -0.5)
    elif case in ("tiny", "huge"):
        values = SDFGrid.from_function(torus_sdf, 16).values * (1e-6 if case == "tiny" else 1e6)
    elif case == "size2":
        values = torch.randn(1, 2, 2, 2)
    else:
        values = SDFGrid.from_function(sphere_sdf(0.6), 24).values
        cams = Cameras.look_at([[0.0, 0.1, 0.0]], at=[[0.3, 0.1, 1.0]], fov_deg=60, image_size=12)
    v = values.clone().requires_grad_(True)
    scene = Scene(effects=ALL.effects, camera_light=1.0, intersection="exact")
    out = render(SDFGrid(v), cams, scene)
    (out.depth.sum() + out.normal.sum() + out.image.sum() + out.silhouette.sum()).backward()
    for field in ("depth", "normal", "image", "silhouette"):
        assert torch.isfinite(getattr(out, field)).all(), field
    assert torch.isfinite(v.grad).all()
