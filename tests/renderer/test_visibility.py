"""Visibility gradients (``Scene(gradient="visibility")``): the grazing points the marches find
(the reference, and the fused CPU kernel against it), the same render on the fused and the PyTorch
paths, and the image gradient checked against finite differences of a supersampled render, the
derivative of the anti-aliased image, on scenes whose edges include self-occlusion edges: a
sphere partly in front of another, a torus seen nearly edge-on, a box with a dent seen obliquely.

How the gradients are compared: each scene is a smooth function of two parameters (a sphere's
centre or radius, ...) sampled onto a 48^3 grid; the image (32^2) is weighed by 64 Gaussian windows
(sigma 3 pixels, centres 4 pixels apart), and the 64 derivatives of the weighed sums with respect to
each parameter form a vector. The reference vector is the central difference (step 0.02) of the
same sums over the 8x8-supersampled, box-filtered render. Both renders use a fixed hit threshold
(so the 1-sample render and the supersampled one draw their edges at the same place) and the exact
intersection (so the shading inside the outline has its true derivative, not the paper's
conservative approximation, whose own error at grazing angles is tests/renderer/test_gradients.py's
subject): what differs between the two gradients is then the edges.
"""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from renderer import (Cameras, DirectionalLight, SDFGrid, Scene, TraceSettings, backend_available, render,
                      shade_trace, sphere_trace)
from renderer.fused import march_fused
from renderer.reference import march_reference
from renderer.trace import camera_grid_index

from .analytic import sphere_sdf

DT = torch.float64
RESOLUTION, SIZE, SUPERSAMPLING, STEP = 48, 32, 8, 0.02
SETTINGS = TraceSettings(threshold=0.002)
SHADING = Scene(effects=("shading",), lights=(DirectionalLight((0.6, 1.0, 0.5), 0.6),), camera_light=0.7,
                camera_light_falloff=False, ambient=0.1, albedo=(1.0,), intersection="exact")


def _ball(p: torch.Tensor, centre: torch.Tensor, radius) -> torch.Tensor:
    return (p - centre).norm(dim=-1) - radius


def two_spheres(p: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """A small sphere (centre x = theta[0], radius theta[1]) in front of a larger one, seen from +z:
    its left rim is a self-occlusion edge, its right rim part of the outline."""
    front = torch.stack([theta[0], p.new_tensor(0.1), p.new_tensor(0.6)])
    return torch.minimum(_ball(p, front, theta[1]), _ball(p, p.new_tensor([0.0, 0.0, -0.35]), 0.45))


def torus(p: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """A torus around the y axis (tube radius theta[0], raised by theta[1]), seen from 12 degrees
    above its plane: the near tube's top hides part of the far tube."""
    q = p - torch.stack([p.new_tensor(0.0), theta[1], p.new_tensor(0.0)])
    ring = torch.stack([torch.linalg.norm(q[..., [0, 2]], dim=-1) - 0.55, q[..., 1]], dim=-1)
    return torch.linalg.norm(ring, dim=-1) - theta[0]


def dented_box(p: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    """A cube of side 1 with a spherical dent in its +z face (the dent's sphere centred at
    z = theta[0], x = theta[1]), seen obliquely: the dent's near rim hides part of its wall."""
    q = p.abs() - 0.5
    box = torch.linalg.norm(q.clamp(min=0), dim=-1) + q.max(dim=-1).values.clamp(max=0)
    centre = torch.stack([theta[1], p.new_tensor(0.0), theta[0]])
    return torch.maximum(box, -_ball(p, centre, 0.38))


CASES = {
    "two_spheres": (two_spheres, (0.15, 0.3), (0.0, 0.0, 2.5)),
    "torus": (torus, (0.2, 0.0), (0.0, 0.55, 2.5)),
    "dented_box": (dented_box, (0.65, 0.0), (1.6, 0.4, 1.6)),
}


def _grid_points() -> torch.Tensor:
    axis = torch.linspace(-1.0, 1.0, RESOLUTION, dtype=DT)
    return torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), dim=-1)


def _windows(sigma: float = 3.0) -> torch.Tensor:
    """(K, H, W) Gaussian windows on a 4-pixel lattice."""
    yy, xx = torch.meshgrid(torch.arange(SIZE, dtype=DT), torch.arange(SIZE, dtype=DT), indexing="ij")
    centres = [(i, j) for i in range(2, SIZE, 4) for j in range(2, SIZE, 4)]
    return torch.stack([torch.exp(-((yy - i) ** 2 + (xx - j) ** 2) / (2 * sigma**2)) for i, j in centres])


def _supersampled(fn, theta: torch.Tensor, eye) -> torch.Tensor:
    """(H, W) the box-filtered image of an 8x8-supersampled render (no gradient)."""
    cams = Cameras.look_at([eye], fov_deg=40, image_size=SIZE * SUPERSAMPLING, dtype=DT)
    with torch.no_grad():
        image = render(SDFGrid(fn(_grid_points(), theta), -1.0, 1.0), cams, SHADING, SETTINGS).image[0, ..., 0]
    return torch.nn.functional.avg_pool2d(image[None, None], SUPERSAMPLING)[0, 0]


def finite_differences(fn, theta, eye, windows) -> torch.Tensor:
    """(P, K) d(windowed sums of the anti-aliased image) / d theta by central differences."""
    rows = []
    for k in range(theta.numel()):
        e = torch.zeros_like(theta)
        e[k] = STEP
        diff = _supersampled(fn, theta + e, eye) - _supersampled(fn, theta - e, eye)
        rows.append((windows * diff).sum((1, 2)) / (2 * STEP))
    return torch.stack(rows)


def rendered_gradient(fn, theta, eye, windows, gradient: str):
    """(P, K) the same derivatives from the renderer's gradient, and the render."""
    scene = Scene(**{**SHADING.__dict__, "gradient": gradient})
    th = theta.clone().requires_grad_(True)
    cams = Cameras.look_at([eye], fov_deg=40, image_size=SIZE, dtype=DT)
    out = render(SDFGrid(fn(_grid_points(), th), -1.0, 1.0), cams, scene, SETTINGS)
    sums = (windows * out.image[0, ..., 0]).sum((1, 2))
    cols = [torch.autograd.grad(s, th, retain_graph=True)[0] for s in sums]
    return torch.stack(cols, dim=1), out


def agreement(g: torch.Tensor, ref: torch.Tensor) -> tuple[float, float]:
    """Cosine similarity and relative error ``|g - ref| / |ref|`` of two gradient vectors."""
    return float((g * ref).sum() / (g.norm() * ref.norm())), float((g - ref).norm() / ref.norm())


def occlusion_windows(out, windows: torch.Tensor) -> torch.Tensor:
    """(K,) bool: the windows centred within 2 pixels of a self-occlusion edge's band (pixels that
    hit a surface after passing another within the band)."""
    band = out.trace.hit[0] & (out.trace.graze_gap[0] < 1.0)
    near = torch.nn.functional.max_pool2d(band[None, None].to(DT), 5, 1, 2)[0, 0] > 0
    centres = windows.flatten(1).argmax(1)
    return near.flatten()[centres]


# Measured (cosine, relative error) against the finite differences, over all windows and over the
# windows near a self-occlusion edge (``occlusion_windows``):
#   scene / parameter          paper: all      near occl.      visibility: all  near occl.
#   two_spheres / centre x     0.751 0.666    0.365 2.025     0.988 0.211    0.911 0.630
#   two_spheres / radius       0.736 0.681    0.192 2.092     0.986 0.178    0.930 0.657
#   torus / tube radius        0.925 0.467    0.937 0.397     0.976 0.296    0.980 0.474
#   torus / height             0.934 0.409    0.870 0.498     0.960 0.306    0.938 0.656
#   dented_box / dent depth    0.962 0.308    0.954 0.384     0.997 0.121    0.999 0.142
# What is left of the visibility gradient's error is where one sample per pixel puts things: the
# edge's gradient on the passing side of each edge (half a pixel out on average) and all in one
# pixel or the next where the edge runs along the pixel grid, where the anti-aliased image changes
# in the pixels the edge crosses; and, inside the outline, the derivative of the shading at the
# pixel's centre where the surface turns away (the torus's rim), not its mean over the pixel, which
# both gradients share (there the paper's is the closer of the two near the torus's occlusion
# edge). With sigma-5 windows the relative errors are about the same: visibility 0.24 / 0.14
# (spheres), 0.27 / 0.34 (torus), 0.08 (dent); paper 0.81 / 0.56, 0.40 / 0.41, 0.30. A tent kernel
# over the band instead of the box gave 0.08-0.29 over all windows (better on the torus and the
# dent) but 1.04-1.11 near the spheres' occlusion edge (box 0.63-0.66); a hat 0.13-0.54; the box
# 0.12-0.31.
# The dent's sideways shift (dented_box's second parameter) is left out: its change is mostly the
# dent's crease moving across the shading, which neither gradient follows (relative error paper
# 0.93, visibility 0.84) and which these finite differences resolve poorly (0.18 between steps
# 0.01 and 0.03).
EXPECTED = {  # scene: parameter, visibility's least cosine and most relative error (all windows),
    # the paper's least relative error (all windows), and the visibility's most and the paper's
    # least relative error near occlusion edges (None: no claim)
    "two_spheres": [(0, 0.97, 0.25, 0.6, 0.75, 1.7), (1, 0.97, 0.25, 0.6, 0.75, 1.7)],
    "torus": [(0, 0.96, 0.35, 0.4, None, None), (1, 0.95, 0.35, 0.38, None, None)],
    "dented_box": [(0, 0.99, 0.15, 0.28, 0.17, 0.33)],
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_visibility_gradient_matches_supersampled_finite_differences(case):
    fn, theta, eye = CASES[case]
    theta = torch.tensor(theta, dtype=DT)
    windows = _windows()
    fd = finite_differences(fn, theta, eye, windows)
    paper, _ = rendered_gradient(fn, theta, eye, windows, "paper")
    visibility, out = rendered_gradient(fn, theta, eye, windows, "visibility")
    occluded = occlusion_windows(out, windows)
    assert occluded.sum() >= 4
    for k, least_cos, most_rel, paper_rel, most_rel_occluded, paper_rel_occluded in EXPECTED[case]:
        cos_v, rel_v = agreement(visibility[k], fd[k])
        assert cos_v >= least_cos and rel_v <= most_rel, (k, cos_v, rel_v)
        assert agreement(paper[k], fd[k])[1] >= paper_rel  # the edges' motion is missing
        if most_rel_occluded is not None:
            assert agreement(visibility[k][occluded], fd[k][occluded])[1] <= most_rel_occluded
            assert agreement(paper[k][occluded], fd[k][occluded])[1] >= paper_rel_occluded


def test_grazing_points_of_a_sphere():
    """A ray that passes a sphere of radius r at distance b from its centre grazes it at the foot of
    the perpendicular from the centre, where the SDF is b - r. The march's grazing gap matches that
    to 0.01 pixel within the band (measured: at most 0.0096 for gaps under 1 pixel); farther out the
    march's samples, a step (the SDF) apart, straddle the minimum and overestimate it, by at most
    0.18 pixel for gaps of 2-3 pixels (never below it but for the grid's interpolation)."""
    grid = SDFGrid.from_function(sphere_sdf(0.5), 64, dtype=DT)
    cams = Cameras.look_at([[0.0, 0.0, 2.5]], fov_deg=40, image_size=33, dtype=DT)
    trace = sphere_trace(grid, cams, SETTINGS, grazing=True)
    o, d = trace.origins[0], trace.directions[0]
    t_foot = -(o * d).sum(-1)
    b = (o + t_foot[..., None] * d).norm(dim=-1)
    expected = (b - 0.5 - SETTINGS.threshold) / (t_foot * cams.pixel_angle[0])  # pixels
    gap, t = trace.graze_gap[0], trace.graze_t[0]
    band = ~trace.hit[0] & (expected < 1.0)
    near = ~trace.hit[0] & (expected < 3.0)
    assert band.sum() > 40 and near.sum() > 150
    torch.testing.assert_close(gap[band], expected[band], atol=0.01, rtol=0.0)
    torch.testing.assert_close(t[band], t_foot[band], atol=0.02, rtol=0.0)
    error = gap[near] - expected[near]
    assert error.max() < 0.2 and error.min() > -0.01
    # Rays that meet the sphere near its centre pass nothing on their way.
    centre = trace.hit[0] & (b < 0.3)
    assert centre.sum() > 0 and torch.isinf(gap[centre]).all()


def test_no_grazing_points_from_inside_or_by_default():
    grid = SDFGrid.from_function(sphere_sdf(0.9), 16, dtype=DT)
    cams = Cameras.look_at([[0.0, 0.0, 0.2]], fov_deg=60, image_size=6, dtype=DT)  # the eye is inside
    o, d = (x.reshape(-1, 3) for x in cams.rays())
    gi = torch.zeros(o.shape[0], dtype=torch.long)
    pix = cams.pixel_angle.expand(o.shape[0])
    inside = march_reference(grid, o, d, gi, pix, SETTINGS, grazing=True)
    assert torch.isinf(inside.graze_gap).all()
    plain = march_reference(grid, o, d, gi, pix, SETTINGS)
    assert plain.graze_t is None and plain.graze_gap is None


@pytest.mark.skipif(not backend_available("cpu")[0], reason="numba is unavailable")
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("settings", [TraceSettings(), SETTINGS], ids=["footprint", "fixed"])
def test_fused_march_finds_the_reference_grazing_points(dtype, settings):
    """The CPU kernel's grazing points are the reference march's, bit for bit (the same samples in
    the same order and dtype), on every scene of this file seen from two sides; without grazing it
    marches as before."""
    for fn, theta, eye in CASES.values():
        grid = SDFGrid(fn(_grid_points().to(dtype), torch.tensor(theta, dtype=dtype)))
        cams = Cameras.look_at([eye, (1.5, 1.0, -1.8)], fov_deg=40, image_size=24, dtype=dtype)
        o, d = (x.reshape(-1, 3) for x in cams.rays())
        gi = camera_grid_index(grid, cams).repeat_interleave(24 * 24)
        pix = cams.pixel_angle.repeat_interleave(24 * 24)
        ref = march_reference(grid, o, d, gi, pix, settings, grazing=True)
        fused = march_fused("cpu", grid, o, d, gi, pix, settings, grazing=True)
        assert torch.equal(fused.hit, ref.hit) and torch.isfinite(ref.graze_gap).sum() > 100
        assert torch.equal(fused.graze_gap, ref.graze_gap) and torch.equal(fused.graze_t, ref.graze_t)
        plain = march_fused("cpu", grid, o, d, gi, pix, settings)
        assert plain.graze_gap is None and torch.equal(plain.t, fused.t) and torch.equal(plain.steps, fused.steps)


def test_visibility_changes_gradients_not_values():
    """The edge term is zero in value: the same image, a different gradient, and the difference
    only at the band's pixels."""
    fn, theta, eye = CASES["two_spheres"]
    values = fn(_grid_points(), torch.tensor(theta, dtype=DT)).requires_grad_(True)
    cams = Cameras.look_at([eye], fov_deg=40, image_size=SIZE, dtype=DT)
    outs, grads = {}, {}
    for gradient in ("paper", "visibility"):
        scene = Scene(**{**SHADING.__dict__, "gradient": gradient})
        outs[gradient] = render(SDFGrid(values, -1.0, 1.0), cams, scene, SETTINGS)
        (grads[gradient],) = torch.autograd.grad(outs[gradient].image.sum(), values)
    torch.testing.assert_close(outs["visibility"].image, outs["paper"].image, atol=0.0, rtol=0.0)
    assert (grads["visibility"] - grads["paper"]).abs().max() > 1.0
    assert outs["paper"].trace.graze_gap is None


def test_visibility_on_both_paths():
    """A visibility render is the same, image and gradient, after the fused march and stage 2 (the
    kernels' paper passes plus the PyTorch edge term) as through the PyTorch specification."""
    values = SDFGrid.from_function(sphere_sdf(0.5), 16, dtype=DT).values.requires_grad_(True)
    grid = SDFGrid(values)
    cams = Cameras.look_at([[0.0, 0.0, 2.5], [2.0, 1.0, 1.0]], fov_deg=40, image_size=12, dtype=DT)
    scene = Scene(gradient="visibility", camera_light=0.5, albedo=(0.9, 0.6, 0.3))
    images, grads, traces = [], [], []
    for backend in ("reference", "auto"):
        out = render(grid, cams, scene, backend=backend)
        images.append(out.image)
        traces.append(out.trace)
        weights = torch.linspace(0.5, 1.5, out.image.numel(), dtype=DT).reshape(out.image.shape)
        grads.append(torch.autograd.grad((weights * out.image).sum(), values)[0])
    if backend_available("cpu")[0]:
        assert traces[1].backend == "cpu"
    assert torch.equal(traces[1].graze_gap, traces[0].graze_gap)
    torch.testing.assert_close(images[1], images[0], atol=1e-12, rtol=0.0)
    torch.testing.assert_close(grads[1], grads[0], atol=1e-9, rtol=0.0)
    paper = render(grid, cams, replace(scene, gradient="paper"))
    (paper_grad,) = torch.autograd.grad((weights * paper.image).sum(), values)
    assert (grads[1] - paper_grad).abs().max() > 0.1  # the edge term is there


def test_visibility_needs_grazing_points():
    grid = SDFGrid.from_function(sphere_sdf(0.5), 16)
    cams = Cameras.look_at([[0.0, 0.0, 2.5]], fov_deg=40, image_size=8)
    scene = Scene(gradient="visibility")
    with pytest.raises(ValueError, match="grazing"):
        shade_trace(grid, cams, sphere_trace(grid, cams), scene)
    # Without the image, nothing reads grazing points: render does not ask the march for them.
    assert not Scene(effects=("silhouette",), gradient="visibility").needs_grazing()
    assert render(grid, cams, Scene(effects=("silhouette",), gradient="visibility")).trace.graze_gap is None


@pytest.mark.parametrize("kwargs", [{"gradient": "exact"}, {"visibility_band": 0.0},
                                    {"visibility_band": float("inf")}])
def test_scene_rejects_bad_gradient_settings(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        Scene(**kwargs)
