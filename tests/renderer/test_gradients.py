"""Gradients of the differentiable stage (gradcheck), the size of the paper's approximation, and
gradient descent on a sphere's radius."""
from __future__ import annotations

import pytest
import torch

from renderer import Cameras, DirectionalLight, PointLight, SDFGrid, Scene, TraceSettings, render, shade_trace, sphere_trace

from .analytic import sphere_sdf


def _small_setup():
    torch.manual_seed(0)
    base = SDFGrid.from_function(sphere_sdf(0.45, (0.03, -0.02, 0.01)), 7, dtype=torch.float64)
    values = (base.values + 0.01 * torch.randn_like(base.values)).requires_grad_(True)
    grid = SDFGrid(values, -1.0, 1.0)
    cams = Cameras.look_at([[0.31, 0.27, 2.3], [-1.9, 0.4, 1.1]], fov_deg=38, image_size=10, dtype=torch.float64)
    trace = sphere_trace(grid, cams, TraceSettings(threshold=1e-3))
    return values, cams, trace


@pytest.mark.parametrize("effect", ["depth", "normal", "shading", "silhouette"])
def test_gradcheck_differentiable_stage(effect):
    values, cams, trace = _small_setup()
    assert trace.hit.sum() > 20
    scene = Scene(effects=(effect,), lights=(DirectionalLight((0.3, 1.0, 0.8), 0.8),
                                             PointLight((1.0, 2.0, 2.0), 2.0)),
                  camera_light=0.5, albedo=(0.9, 0.6, 0.3))

    def f(v):
        out = shade_trace(SDFGrid(v, -1.0, 1.0), cams, trace, scene)
        return {"depth": out.depth, "normal": out.normal, "shading": out.image, "silhouette": out.silhouette}[effect]

    assert torch.autograd.gradcheck(f, (values,), eps=1e-6, atol=1e-6, rtol=1e-4)


def test_paper_gradient_versus_whole_render_on_a_sphere():
    """The paper's hit-point gradient ignores how the traced point moves.

    Adding delta to every SDF sample moves a sphere's surface inwards by delta. The whole render's
    depth then grows by delta / cos(theta) (theta: angle between the ray and the normal); the
    differentiable stage reports exactly 1 per unit delta (it moves the hit point along the ray by
    the change of f(s)). So the gap is a factor cos(theta): none head-on, growing at grazing angles.
    """
    grid = SDFGrid.from_function(sphere_sdf(0.5), 64, dtype=torch.float64)
    cams = Cameras.look_at([[0.0, 0.0, 2.5]], fov_deg=40, image_size=33, dtype=torch.float64)
    settings = TraceSettings(threshold=1e-9, max_steps=2000)
    scene = Scene(effects=("depth", "normal"))
    values = grid.values.clone().requires_grad_(True)
    out = render(SDFGrid(values, -1.0, 1.0), cams, scene, settings)
    (grad,) = torch.autograd.grad(out.depth.sum(), values)
    # d(sum of depths)/d(delta) = sum of all gradients: 1 per hit pixel.
    assert grad.sum().item() == pytest.approx(float(out.hit.sum()), rel=1e-9)

    delta = 1e-3
    plus = render(SDFGrid(grid.values + delta, -1.0, 1.0), cams, scene, settings)
    minus = render(SDFGrid(grid.values - delta, -1.0, 1.0), cams, scene, settings)
    both = out.hit & plus.hit & minus.hit
    fd = (plus.depth - minus.depth)[both] / (2 * delta)
    cos = -(out.normal[both] * out.trace.directions[both]).sum(-1).detach()
    # Away from the very rim (where depth is not smooth in delta at this finite step) fd = 1/cos,
    # up to the difference between the interpolated normal and the trilinear surface's own.
    ok = cos > 0.3
    torch.testing.assert_close(fd[ok], 1.0 / cos[ok], atol=0.0, rtol=0.08)
    torch.testing.assert_close(fd[cos > 0.7], 1.0 / cos[cos > 0.7], atol=0.0, rtol=0.02)
    # The gap in numbers: head-on rays agree to a few per cent, grazing ones are far off.
    ratio = 1.0 / fd  # the paper's gradient over the whole render's derivative = cos(theta)
    assert (ratio[cos > 0.99] > 0.97).all()
    grazing = ok & (cos < 0.5)
    assert grazing.sum() > 0 and (ratio[grazing] < 0.55).all()


@pytest.mark.parametrize("start", [0.3, 0.65])
def test_gradient_descent_recovers_sphere_radius(start):
    target_r = 0.45
    cams = Cameras.look_at([[0.0, 0.3, 2.5], [2.2, 0.5, 1.0], [-1.5, 1.5, -1.5]], fov_deg=40, image_size=32)
    scene = Scene(effects=("silhouette", "shading"))
    target = render(SDFGrid.from_function(sphere_sdf(target_r), 32), cams, scene)
    pts = SDFGrid.from_function(sphere_sdf(0.0), 32).values  # |p|
    radius = torch.tensor(start, requires_grad=True)
    opt = torch.optim.Adam([radius], lr=0.02)
    for _ in range(80):
        opt.zero_grad()
        out = render(SDFGrid(pts - radius, -1.0, 1.0), cams, scene)
        loss = ((out.silhouette - target.silhouette) ** 2).mean() + ((out.image - target.image) ** 2).mean()
        loss.backward()
        opt.step()
    assert abs(radius.item() - target_r) < 0.01


def test_gradient_descent_on_grid_values_matches_silhouettes():
    """Optimising every sample (not a parameter) from one sphere towards another's silhouettes."""
    cams = Cameras.cube_rig(2.5, fov_deg=40, image_size=24)
    scene = Scene(effects=("silhouette",))
    target = render(SDFGrid.from_function(sphere_sdf(0.5), 16), cams, scene).silhouette
    values = SDFGrid.from_function(sphere_sdf(0.3), 16).values.clone().requires_grad_(True)
    opt = torch.optim.Adam([values], lr=0.01)
    first = None
    for _ in range(60):
        opt.zero_grad()
        sil = render(SDFGrid(values, -1.0, 1.0), cams, scene).silhouette
        loss = ((sil - target) ** 2).mean()
        first = first if first is not None else loss.item()
        loss.backward()
        opt.step()
    assert loss.item() < 0.1 * first
    # The zero level crosses the x axis near the target radius.
    g = SDFGrid(values.detach(), -1.0, 1.0)
    xs = torch.linspace(0.0, 0.9, 901)
    f = g.sample(torch.stack([xs, torch.zeros_like(xs), torch.zeros_like(xs)], -1))
    crossing = xs[(f > 0).nonzero()[0, 0]].item()
    assert abs(crossing - 0.5) < 0.07
