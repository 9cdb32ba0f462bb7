"""The fused stage 2 (renderer/fused.py, kernels in renderer/kernels/raymarch.py) against the
PyTorch stage 2 (renderer/shading.py), its specification: the same outputs and the same gradients
for every effect, light and case of the march tests, in float32 and float64, on the same traces.
The CUDA kernels are checked in numba's CUDA simulator and by compiling them to PTX."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch

from renderer import (Cameras, DirectionalLight, PointLight, SDFGrid, Scene, backends, fused,
                      kernels, render, shade_trace, sphere_trace)

from .analytic import sphere_sdf, torus_sdf
from .test_kernels import CASES, DTYPES, ROOT, device_less_cuda, random_smooth_values

pytestmark = pytest.mark.skipif(not backends.march_available("cpu")[0], reason="numba is unavailable")

LIGHTS = (DirectionalLight((0.3, 1.0, 0.8), 0.7), PointLight((1.0, 2.0, 2.0), 2.0),
          PointLight((-2.0, 0.5, 1.0), 0.6, falloff=False), DirectionalLight((-1.0, -0.2, 0.4), 0.3))
RICH = Scene(lights=LIGHTS, camera_light=0.8, albedo=(0.9, 0.6, 0.3), background=(0.1, 0.2, 0.3), ambient=0.15)


def _weights(out, seed: int = 0) -> dict:
    """Random upstream gradients for every output the render made (so each entry matters)."""
    gen = torch.Generator().manual_seed(seed)
    return {name: torch.rand(x.shape, generator=gen, dtype=torch.float64).to(x.dtype) - 0.3
            for name in ("depth", "normal", "image", "silhouette") if (x := getattr(out, name)) is not None}


def _stage2(grid, cams, trace, scene, stage2, weights=None):
    values = grid.values.detach().clone().requires_grad_(True)
    out = shade_trace(SDFGrid(values, grid.bbox_min, grid.bbox_max), cams, trace, scene, stage2=stage2)
    weights = _weights(out) if weights is None else weights
    loss = sum((getattr(out, name) * w).sum() for name, w in weights.items())
    loss.backward()
    return out, values.grad, weights


def assert_same_stage2(grid, cams, trace, scene):
    ref, gref, weights = _stage2(grid, cams, trace, scene, "reference")
    fused, gfused, _ = _stage2(grid, cams, trace, scene, "fused", weights)
    double = grid.dtype == torch.float64
    for name in ("depth", "normal", "image", "silhouette"):
        a, b = getattr(ref, name), getattr(fused, name)
        assert (a is None) == (b is None), name
        if a is not None:
            scale = float(a.detach().abs().max()) + 1.0
            tol = 1e-12 * scale if double else 2e-6 * scale
            torch.testing.assert_close(b, a, rtol=0, atol=tol, msg=name)
    scale = float(gref.abs().max()) + 1e-30
    # Sums in another order: float32 gradients agree to a few units of the last place of the largest.
    torch.testing.assert_close(gfused, gref, rtol=0, atol=(1e-11 if double else 1e-5) * scale)
    return ref, gref


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("case", sorted(CASES))
def test_fused_stage2_matches_the_pytorch_stage2(case, dtype):
    grid, cams, settings = CASES[case](dtype)
    trace = sphere_trace(grid, cams, settings, backend="cpu")
    assert_same_stage2(grid, cams, trace, RICH)


@pytest.mark.parametrize("effects", [("silhouette",), ("depth",), ("normal",), ("shading",), ("depth", "shading"),
                                     ("silhouette", "normal")])
@pytest.mark.parametrize("dtype", DTYPES)
def test_each_effect_alone(effects, dtype):
    grid, cams, settings = CASES["random_smooth"](dtype)
    trace = sphere_trace(grid, cams, settings, backend="cpu")
    ref, gref = assert_same_stage2(grid, cams, trace, Scene(effects=effects, lights=LIGHTS, camera_light=0.5))
    assert gref.abs().max() > 0


@pytest.mark.parametrize("scene", [
    Scene(lights=(), camera_light=None, ambient=0.3),                         # ambient only: no normal gradient
    Scene(lights=(PointLight((0.0, 0.0, 0.0), 1.0),), camera_light=None),     # a light inside the shape
    Scene(lights=(), camera_light=2.0, camera_light_falloff=False, albedo=(1.0,), background=0.5),
    Scene(silhouette_sigma=2.0, albedo=(0.2, 0.4, 0.6, 0.8)),
], ids=["ambient", "light_inside", "camera_light", "four_channels"])
def test_lights_and_materials(scene):
    grid, cams, settings = CASES["torus"](torch.float64)
    trace = sphere_trace(grid, cams, settings, backend="cpu")
    assert_same_stage2(grid, cams, trace, scene)


def test_gradient_of_one_output_only():
    """A loss on the silhouette alone (the other outputs made but unused) gets the reference's gradient."""
    grid, cams, settings = CASES["sphere"](torch.float64)
    trace = sphere_trace(grid, cams, settings, backend="cpu")
    grads = []
    for stage2 in ("reference", "fused"):
        values = grid.values.detach().clone().requires_grad_(True)
        out = shade_trace(SDFGrid(values), cams, trace, RICH, stage2=stage2)
        (out.silhouette * out.silhouette).sum().backward()
        grads.append(values.grad)
    torch.testing.assert_close(grads[1], grads[0], rtol=0, atol=1e-12)


def test_render_uses_the_fused_stage2_after_a_fused_march(monkeypatch):
    """render(backend="cpu") and the default run the fused stage 2; the reference backend, and the
    exact intersection, the PyTorch one."""
    calls = []
    real = fused._FusedStage2.apply
    monkeypatch.setattr(fused._FusedStage2, "apply", lambda *a: calls.append(1) or real(*a))
    grid = SDFGrid.from_function(sphere_sdf(0.5), 12)
    cams = Cameras.look_at([[0.0, 0.3, 2.5]], fov_deg=40, image_size=8)
    render(grid, cams, backend="cpu")
    render(grid, cams)
    assert len(calls) == 2
    render(grid, cams, backend="reference")
    render(grid, cams, Scene(intersection="exact"), backend="cpu")
    assert len(calls) == 2
    trace = sphere_trace(grid, cams, backend="cpu")
    with pytest.raises(ValueError, match="conservative"):
        shade_trace(grid, cams, trace, Scene(intersection="exact"), stage2="fused")
    with pytest.raises(ValueError, match="stage2"):
        shade_trace(grid, cams, trace, Scene(), stage2="fast")


def test_only_the_effects_the_scene_asks_for_run(monkeypatch):
    """A silhouette-only render asks the kernel for no depth, normals or shading (their outputs are
    not even allocated), and a depth-only one for no normals or shading."""
    seen = []
    real = kernels.shade_forward

    def spy(backend, values, params, iparams, sparams, sflags, lights, rays, *outputs):
        seen.append((sflags.clone(), dict(zip(("depth", "normal", "image", "silhouette"),
                                              (o.shape[0] for o in outputs)))))
        real(backend, values, params, iparams, sparams, sflags, lights, rays, *outputs)

    monkeypatch.setattr(kernels, "shade_forward", spy)
    m = kernels.load()
    grid = SDFGrid.from_function(sphere_sdf(0.5), 12)
    cams = Cameras.look_at([[0.0, 0.3, 2.5]], fov_deg=40, image_size=8)
    out = render(grid, cams, Scene(effects=("silhouette",)), backend="cpu")
    assert out.depth is None and out.normal is None and out.image is None and out.silhouette is not None
    flags, sizes = seen[-1]
    assert flags[m.SF_SILHOUETTE] == 1 and flags[m.SF_DEPTH] == flags[m.SF_NORMAL] == flags[m.SF_SHADING] == 0
    assert sizes == {"depth": 0, "normal": 0, "image": 0, "silhouette": 64}
    render(grid, cams, Scene(effects=("depth",)), backend="cpu")
    flags, sizes = seen[-1]
    assert flags[m.SF_DEPTH] == 1 and flags[m.SF_NORMAL] == flags[m.SF_SHADING] == flags[m.SF_SILHOUETTE] == 0
    assert sizes == {"depth": 64, "normal": 0, "image": 0, "silhouette": 0}


def test_many_grids_and_views_scatter_into_their_own_grid():
    """Four grids seen by three cameras each (the backward adds each grid's rays in its own thread):
    each grid's gradient is what rendering it alone gives."""
    values = torch.cat([random_smooth_values(2, 16, seed=11, dtype=torch.float64),
                        SDFGrid.from_function(torus_sdf, 16, dtype=torch.float64).values,
                        SDFGrid.from_function(sphere_sdf(0.4), 16, dtype=torch.float64).values])
    eyes = [[0.5, 1.0, 2.5], [2.0, 0.3, -1.0], [-2.0, 1.5, 0.5]] * 4
    cams = Cameras.look_at(eyes, fov_deg=45, image_size=10, dtype=torch.float64)
    grid = SDFGrid(values)
    trace = sphere_trace(grid, cams, backend="cpu")
    assert_same_stage2(grid, cams, trace, RICH)
    _, together, weights = _stage2(grid, cams, trace, RICH, "fused")
    for g in range(4):
        views = cams[3 * g:3 * g + 3]
        one = SDFGrid(values[g:g + 1])
        mine = {name: w[3 * g:3 * g + 3] for name, w in weights.items()}
        _, alone, _ = _stage2(one, views, sphere_trace(one, views, backend="cpu"), RICH, "fused", mine)
        torch.testing.assert_close(alone[0], together[g], rtol=0, atol=1e-12)


def test_double_backward_is_refused():
    grid = SDFGrid.from_function(sphere_sdf(0.5), 10, dtype=torch.float64)
    values = grid.values.clone().requires_grad_(True)
    cams = Cameras.look_at([[0.0, 0.3, 2.5]], fov_deg=40, image_size=6, dtype=torch.float64)
    out = render(SDFGrid(values), cams, backend="cpu")
    (g,) = torch.autograd.grad(out.image.sum(), values, create_graph=True)
    with pytest.raises(RuntimeError):
        g.sum().backward()


SIMULATOR_SCRIPT = r"""
import json, numpy as np, torch
from renderer import Cameras, SDFGrid, Scene, DirectionalLight, PointLight, sphere_trace
from renderer import kernels
from renderer.fused import shade_fused
from renderer.kernels import raymarch
from renderer.stage2 import shading_rays
from tests.renderer.analytic import torus_sdf

grid = SDFGrid.from_function(torus_sdf, 12, dtype=torch.float64)
cams = Cameras.look_at([[0.5, 1.0, 2.5], [2.0, 0.3, -1.0]], fov_deg=50, image_size=(5, 6), dtype=torch.float64)
scene = Scene(lights=(DirectionalLight((0.3, 1.0, 0.8), 0.7), PointLight((1.0, 2.0, 2.0), 2.0)), camera_light=0.5,
              albedo=(0.9, 0.5))
trace = sphere_trace(grid, cams, backend="reference")
rays = shading_rays(trace, cams, grid.dtype, grid.device)
# The CPU path (plain Python here: the JIT is off) gives the expected values and gradient.
values = grid.values.clone().requires_grad_(True)
out = shade_fused("cpu", SDFGrid(values), rays, scene)
d, n, s, im = out.depth, out.normal, out.silhouette, out.image
(d.sum() + (n * 0.3).sum() + s.sum() + (im * 0.7).sum()).backward()
# The same through the CUDA kernel bodies, launched in the simulator on numpy arrays.
m = raymarch
captured = {}
real_f, real_b = kernels.shade_forward, kernels.shade_backward
def fwd(backend, *a):
    captured["f"] = a
    return real_f("cpu", *a)
kernels.shade_forward = fwd
shade_fused("cpu", SDFGrid(grid.values), rays, scene)
values_, params, iparams, sparams, sflags, lights, rays_, *outputs = captured["f"]
forward, backward = m.make_cuda_shade_kernels()
r = rays_.count
outs = {k: np.zeros_like(v.numpy()) for k, v in zip(("depth", "normal", "image", "silhouette"), outputs)}
arr = lambda x: x.numpy()
common = [arr(values_), arr(params), arr(iparams), arr(sparams), arr(sflags), arr(lights)]
forward[(r + 31) // 32, 32](*common, arr(rays_.hit.view(torch.uint8)), arr(rays_.t), arr(rays_.points),
                           arr(rays_.directions), arr(rays_.extreme), arr(rays_.t_extreme), arr(rays_.steps),
                           arr(rays_.camera_grid), arr(rays_.pixel_angle), arr(rays_.eyes), outs["depth"],
                           outs["normal"], outs["image"], outs["silhouette"])
flags = sflags.numpy().copy()
flags[m.SF_GRAD_DEPTH] = flags[m.SF_GRAD_NORMAL] = flags[m.SF_GRAD_IMAGE] = flags[m.SF_GRAD_SILHOUETTE] = 1
grad = np.zeros_like(values_.numpy())
ones = lambda k, c: np.full((r,) if c is None else (r, c), 1.0)
backward[(r + 31) // 32, 32](arr(values_), arr(params), arr(iparams), arr(sparams), flags, arr(lights),
                            arr(rays_.hit.view(torch.uint8)), arr(rays_.points), arr(rays_.directions),
                            arr(rays_.extreme), arr(rays_.t_extreme), arr(rays_.steps), arr(rays_.camera_grid),
                            arr(rays_.pixel_angle), arr(rays_.eyes), ones("d", None), ones("n", 3) * 0.3,
                            ones("i", 2) * 0.7, ones("s", None), outs["silhouette"], grad)
print(json.dumps({
    "hits": int(trace.hit.sum()),
    "depth": float(np.abs(outs["depth"] - d.detach().numpy().reshape(-1)).max()),
    "normal": float(np.abs(outs["normal"] - n.detach().numpy().reshape(-1, 3)).max()),
    "image": float(np.abs(outs["image"] - im.detach().numpy().reshape(-1, 2)).max()),
    "silhouette": float(np.abs(outs["silhouette"] - s.detach().numpy().reshape(-1)).max()),
    "grad": float(np.abs(grad - values.grad.numpy().reshape(-1)).max()),
    "grad_scale": float(np.abs(grad).max()),
}))
"""


def test_cuda_stage2_bodies_in_the_cuda_simulator():
    """The CUDA kernels of stage 2 (one ray per thread, atomic adds) run by numba's CUDA simulator
    on the CPU give the CPU path's outputs and gradient."""
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "NUMBA_DISABLE_JIT": "1"}
    out = subprocess.run([sys.executable, "-c", SIMULATOR_SCRIPT], cwd=ROOT, env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["hits"] > 5 and res["grad_scale"] > 0, res
    for name in ("depth", "normal", "image", "silhouette"):
        assert res[name] < 1e-12, res
    assert res["grad"] < 1e-12 * res["grad_scale"] + 1e-15, res


@pytest.mark.slow
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_cuda_stage2_kernels_compile_to_ptx(dtype, monkeypatch):
    """Compiles both stage-2 CUDA kernels for sm_80 without a GPU (needs libNVVM; 25 s to a minute
    per dtype on 2 cores, so `slow`: the default suite runs the same kernel bodies in numba's CUDA
    simulator, test_cuda_stage2_bodies_in_the_cuda_simulator)."""
    from numba import types

    cuda = device_less_cuda(monkeypatch)
    from renderer.kernels import raymarch

    raymarch.make_cuda_shade_kernels()  # binds `cuda` and the atomic scatter_add
    f = getattr(types, dtype)
    a = lambda ty, nd: types.Array(ty, nd, "C")  # noqa: E731
    i64 = types.int64
    common = (a(f, 1), a(f, 1), a(i64, 1), a(f, 1), a(i64, 1), a(f, 2))
    rays_fwd = (a(types.uint8, 1), a(f, 1), a(f, 2), a(f, 2), a(f, 2), a(f, 1), a(types.int32, 1), a(i64, 1), a(f, 1),
                a(f, 2))
    fwd_sig = common + rays_fwd + (a(f, 1), a(f, 2), a(f, 2), a(f, 1))
    rays_bwd = (a(types.uint8, 1), a(f, 2), a(f, 2), a(f, 2), a(f, 1), a(types.int32, 1), a(i64, 1), a(f, 1), a(f, 2))
    bwd_sig = common + rays_bwd + (a(f, 1), a(f, 2), a(f, 2), a(f, 1), a(f, 1), a(f, 1))
    for body, sig in ((raymarch.cuda_shade_body, fwd_sig), (raymarch.cuda_shade_backward_body, bwd_sig)):
        ptx, _ = cuda.compile_ptx(body, sig, cc=(8, 0))
        assert ".entry" in ptx
        if body is raymarch.cuda_shade_backward_body:
            assert "atom" in ptx  # the scatter is atomic


def test_without_the_fused_stage2_the_render_warns_and_uses_the_pytorch_one(monkeypatch, caplog):
    """Where the stage-2 kernels cannot run (on a GPU: a numba-cuda that cannot build them), a
    fused march is followed by the PyTorch stage 2, with one warning (also logged)."""
    monkeypatch.setattr(backends, "stage2_available", lambda backend: (False, "testing the stage-2 fallback"))
    monkeypatch.setattr(backends, "_warned", set())
    grid = SDFGrid.from_function(sphere_sdf(0.5), 12, dtype=torch.float64)
    cams = Cameras.look_at([[0.0, 0.3, 2.5]], fov_deg=40, image_size=8, dtype=torch.float64)
    with pytest.warns(RuntimeWarning, match="testing the stage-2 fallback"), \
            caplog.at_level("WARNING", logger="renderer"):
        out = render(grid, cams, RICH, backend="cpu")
        render(grid, cams, RICH, backend="cpu")
    assert out.trace.backend == "cpu" and out.image is not None
    assert sum("testing the stage-2 fallback" in r.getMessage() for r in caplog.records) == 1
    with pytest.raises(RuntimeError, match="testing the stage-2 fallback"):
        shade_trace(grid, cams, out.trace, RICH, stage2="fused")


def test_the_gpu_probe_runs_its_backward_even_when_the_first_render_is_under_no_grad(monkeypatch):
    """The GPU's stage-2 probe renders one ray forward and backward. A process's first render is
    often inference (under no_grad): the probe must still take its gradient, or the fused stage 2
    is wrongly reported unavailable for the whole process (seen on an H200). The probe's body is run
    here on the CPU kernels."""
    monkeypatch.setattr(backends, "_sphere_grid_on_gpu",
                        lambda: SDFGrid.from_function(sphere_sdf(0.5), 8, bbox_min=-1.0, bbox_max=1.0))
    monkeypatch.setattr(backends, "march_fused", lambda backend, *a, **k: fused.march_fused("cpu", *a, **k))
    monkeypatch.setattr(backends, "shade_fused", lambda backend, *a, **k: fused.shade_fused("cpu", *a, **k))
    with torch.no_grad():
        backends._shade_one_ray_on_gpu()
