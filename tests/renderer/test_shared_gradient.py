"""The PyTorch stage 2 in plain autograd (renderer/shading.py's ``shade_reference`` on an SDFGrid)
is the specification: its gradients are checked against finite differences in float64
(``torch.autograd.gradcheck``), and the shared gradient buffer that makes the fallback fast
(renderer/shared_gradient.py, the one hand-written backward kept) against it: the same values and
the same gradients, for samplings, for every stage-2 effect and light, and by gradcheck itself."""
from __future__ import annotations

import pytest
import torch

from renderer import Cameras, DirectionalLight, PointLight, SDFGrid, Scene, TraceSettings, sphere_trace
from renderer.shared_gradient import with_shared_gradient
from renderer.shading import shade_reference
from renderer.stage2 import shading_rays

from .test_kernels import DTYPES, random_smooth_values

LIGHTS = (DirectionalLight((0.3, 1.0, 0.8), 0.7), PointLight((1.0, 2.0, 2.0), 2.0),
          PointLight((-2.0, 0.5, 1.0), 0.6, falloff=False))
SCENES = {
    "all": Scene(effects=("silhouette", "depth", "normal", "shading"), lights=LIGHTS, camera_light=0.8,
                 albedo=(0.9, 0.6), background=(0.1, 0.2)),
    "silhouette": Scene(effects=("silhouette",)),
    "depth_normal": Scene(effects=("depth", "normal")),
}
OUTPUTS = ("depth", "normal", "silhouette", "image")


def _small_render(n: int = 7, size: int = 5):
    """A float64 random smooth grid (1 or 2 grids) seen by two cameras, marched once: (values, rays)."""
    values = random_smooth_values(2, n, seed=21, dtype=torch.float64)
    cams = Cameras.look_at([[0.4, 0.9, 2.5], [2.2, 0.3, -1.0]], fov_deg=55, image_size=size, dtype=torch.float64)
    trace = sphere_trace(SDFGrid(values), cams, TraceSettings(), backend="reference")
    assert int(trace.hit.sum()) >= 6 and int((~trace.hit).sum()) >= 6
    return values, shading_rays(trace, cams, torch.float64, torch.device("cpu"))


def _outputs(values, rays, scene, shared: bool) -> tuple[torch.Tensor, ...]:
    grid = SDFGrid(values)
    if shared:
        grid = with_shared_gradient(grid)
    out = shade_reference(grid, rays, scene)
    return tuple(x for name in OUTPUTS if (x := getattr(out, name)) is not None)


@pytest.mark.parametrize("shared", [False, True], ids=["plain_autograd", "shared_gradient"])
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_stage2_gradcheck(scene, shared):
    """Finite differences of every output (float64) against the backward of the plain
    specification, and of the fast fallback."""
    values, rays = _small_render()
    v = values.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: _outputs(x, rays, SCENES[scene], shared), (v,),
                                    eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_shared_gradient_gives_the_plain_gradients(scene, dtype):
    """The fallback's stage 2 against the specification on a larger render: the same outputs bit
    for bit (same forward arithmetic) and the same gradient to rounding, for random upstream weights."""
    values = random_smooth_values(3, 16, seed=5, dtype=dtype)
    cams = Cameras.look_at([[0.4, 0.9, 2.5], [2.2, 0.3, -1.0], [-1.5, 2.0, 1.0]], fov_deg=50, image_size=20,
                           dtype=dtype)
    rays = shading_rays(sphere_trace(SDFGrid(values), cams, backend="cpu"), cams, dtype, torch.device("cpu"))
    gen = torch.Generator().manual_seed(3)
    results = []
    for shared in (False, True):
        v = values.clone().requires_grad_(True)
        outs = _outputs(v, rays, SCENES[scene], shared)
        if not results:
            weights = [torch.rand(o.shape, generator=gen, dtype=torch.float64).to(dtype) - 0.3 for o in outs]
        sum((o * w).sum() for o, w in zip(outs, weights)).backward()
        results.append(([o.detach() for o in outs], v.grad))
    (plain, g_plain), (fast, g_fast) = results
    for a, b in zip(plain, fast):
        assert torch.equal(a, b)
    scale = float(g_plain.abs().max())
    torch.testing.assert_close(g_fast, g_plain, rtol=0, atol=(1e-12 if dtype == torch.float64 else 1e-5) * scale)


def test_shared_gradient_buffer_with_retain_graph_and_two_backward_passes():
    """The samplings add into one buffer: the plain gradients, also with retain_graph and
    two backward passes; values that do not require grad, or no grad mode, keep the grid as it is."""
    values = random_smooth_values(2, 12, seed=3, dtype=torch.float64)
    gen = torch.Generator().manual_seed(0)
    pts = torch.rand(300, 3, generator=gen, dtype=torch.float64) * 2 - 1
    b = torch.randint(0, 2, (300,), generator=gen)

    def loss(grid):
        return (grid.sample(pts, b).sin().sum() + grid.sample_gradient(pts[:100], b[:100]).pow(2).sum()
                + grid.sample(pts[50:] * 0.5, b[50:]).sum())

    v = values.clone().requires_grad_(True)
    (plain,) = torch.autograd.grad(loss(SDFGrid(v)), v)
    shared = with_shared_gradient(SDFGrid(v))
    assert type(shared) is not SDFGrid
    total = loss(shared)
    total.backward(retain_graph=True)
    first = v.grad.clone()
    total.backward()
    torch.testing.assert_close(first, plain, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(v.grad, 2 * plain, rtol=1e-12, atol=1e-12)
    frozen = SDFGrid(values)
    assert with_shared_gradient(frozen) is frozen
    with torch.no_grad():
        grid = SDFGrid(v)
        assert with_shared_gradient(grid) is grid


@pytest.mark.parametrize("dtype", DTYPES)
def test_samplings_with_moving_and_fixed_points(dtype):
    """``sample`` at points with and without gradient, and ``sample_gradient`` (whose backward also
    reaches the points): through the shared buffer, autograd's values and gradients."""
    values = random_smooth_values(2, (6, 9, 7), seed=4, dtype=dtype)
    gen = torch.Generator().manual_seed(1)
    pts = (torch.rand(500, 3, generator=gen, dtype=torch.float64) * 2.4 - 1.2).to(dtype)
    b = torch.randint(0, 2, (500,), generator=gen)
    w = torch.linspace(-1.0, 2.0, 500, dtype=dtype)
    tol = dict(rtol=1e-5, atol=1e-5) if dtype == torch.float32 else dict(rtol=1e-12, atol=1e-12)
    for track_points in (False, True):
        results = []
        for shared in (False, True):
            v = values.clone().requires_grad_(True)
            p = pts.clone().requires_grad_(track_points)
            grid = with_shared_gradient(SDFGrid(v)) if shared else SDFGrid(v)
            f, g = grid.sample(p, b), grid.sample_gradient(p, b)
            ((f * w).sum() + (g * torch.tensor([0.3, -1.0, 2.0], dtype=dtype)).sin().sum()).backward()
            results.append((f.detach(), g.detach(), v.grad, p.grad))
        (f0, g0, dv0, dp0), (f1, g1, dv1, dp1) = results
        assert torch.equal(f0, f1) and torch.equal(g0, g1)
        torch.testing.assert_close(dv1, dv0, **tol)
        if track_points:
            scale = float(dp0.abs().max())
            torch.testing.assert_close(dp1, dp0, rtol=tol["rtol"], atol=tol["atol"] * max(1.0, scale / 10))
