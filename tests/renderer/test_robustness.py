"""Hard numerical cases stay finite, bad input is refused clearly, only requested passes run, and
the march keeps no autograd graph."""
from __future__ import annotations

import pytest
import torch

import importlib

shading_module = importlib.import_module("renderer.shading")
from renderer import Cameras, SDFGrid, Scene, TraceSettings, render

from .analytic import sphere_sdf, torus_sdf

ALL = Scene(effects=("silhouette", "depth", "normal", "shading"), camera_light=1.0)


def _render_and_backward(grid_values, cams, bbox=(-1.0, 1.0), settings=TraceSettings()):
    values = grid_values.clone().requires_grad_(True)
    out = render(SDFGrid(values, *bbox), cams, ALL, settings)
    loss = out.depth.sum() + out.normal.sum() + out.image.sum() + out.silhouette.sum()
    loss.backward()
    for name in ("depth", "normal", "image", "silhouette"):
        assert torch.isfinite(getattr(out, name)).all(), name
    assert torch.isfinite(values.grad).all()
    return out, values.grad


def _grid(fn, n=16, dtype=torch.float32, bbox=(-1.0, 1.0)):
    return SDFGrid.from_function(fn, n, *bbox, dtype=dtype).values


def _one_ray(eye, at):
    return Cameras.look_at([eye], at=[at], fov_deg=1e-3, image_size=1)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_grazing_ray_tangent_to_sphere(dtype):
    values = _grid(sphere_sdf(0.5), 32, dtype)
    cams = Cameras.look_at([[0.5, 0.0, 3.0], [0.0, 0.5, 3.0]], at=[[0.5, 0.0, 0.0], [0.0, 0.5, 0.0]],
                           fov_deg=2.0, image_size=9, dtype=dtype)
    _render_and_backward(values, cams)


def test_rays_parallel_to_box_faces_and_in_face_planes():
    values = _grid(sphere_sdf(0.5), 16)
    # Axis-aligned rays (two zero direction components), one of them lying in the box face x = 1.
    for eye, at in [([0.0, 0.0, 3.0], [0.0, 0.0, 0.0]), ([1.0, 0.0, 3.0], [1.0, 0.0, 0.0]),
                    ([3.0, 1.0, 1.0], [0.0, 1.0, 1.0]), ([0.25, 3.0, 0.0], [0.25, 0.0, 0.0])]:
        up = [0.0, 0.0, 1.0] if eye[1] == 3.0 else [0.0, 1.0, 0.0]
        cams = Cameras.look_at([eye], at=[at], up=[up], fov_deg=1e-3, image_size=1)
        _render_and_backward(values, cams)
    out = render(SDFGrid(values), Cameras.look_at([[0.0, 0.0, 3.0]], fov_deg=1e-3, image_size=1), ALL)
    assert out.hit.all() and abs(out.depth.item() - 2.5) < 0.15 * (2.0 / 15)  # trilinear error of a 16^3 grid


def test_eye_inside_box_and_inside_shape():
    values = _grid(sphere_sdf(0.6), 24)
    inside_box = Cameras.look_at([[0.0, 0.0, 0.9]], fov_deg=60, image_size=16)
    out, _ = _render_and_backward(values, inside_box)
    assert out.hit.any()
    inside_shape = Cameras.look_at([[0.0, 0.1, 0.0]], at=[[0.3, 0.1, 1.0]], fov_deg=60, image_size=16)
    out, _ = _render_and_backward(values, inside_shape)
    # Seen from inside, the sphere's surface surrounds the eye: every ray meets it.
    assert out.hit.all()
    assert (out.silhouette > 0.5).all()


def test_hits_on_voxel_corners_edges_and_box_boundary():
    # 9 samples over [-1, 1]: vertices every 0.25. The plane z = 0.25 passes through vertices.
    plane = _grid(lambda p: p[..., 2] - 0.25, 9)
    for eye in ([0.0, 0.0, 3.0], [0.25, 0.5, 3.0], [0.125, 0.25, 3.0]):
        out, _ = _render_and_backward(plane, _one_ray(eye, [eye[0], eye[1], 0.0]))
        assert out.hit.all() and abs(out.depth.item() - 2.75) < 1e-4
    # Surfaces on the box: a sphere touching every face, and the plane z = 1 (the face itself).
    _render_and_backward(_grid(sphere_sdf(1.0), 16), Cameras.look_at([[0.3, 0.2, 3.0]], fov_deg=50, image_size=12))
    out, _ = _render_and_backward(_grid(lambda p: p[..., 2] - 1.0, 9), _one_ray([0.1, 0.2, 3.0], [0.1, 0.2, 0.0]))
    assert out.hit.all() and abs(out.depth.item() - 2.0) < 1e-4


@pytest.mark.parametrize("fill", [0.0, 0.5, -0.5])
def test_flat_empty_and_full_grids(fill):
    values = torch.full((8, 8, 8), fill)
    cams = Cameras.look_at([[0.3, 0.2, 3.0]], fov_deg=50, image_size=8)
    out, _ = _render_and_backward(values, cams)
    if fill > 0:
        assert not out.hit.any() and (out.silhouette < 0.01).all()
    else:
        # Flat regions have no gradient: the normal falls back to facing the camera.
        assert torch.isfinite(out.normal).all()


@pytest.mark.parametrize("scale", [1e-6, 1e6])
def test_extreme_sdf_scales(scale):
    values = _grid(sphere_sdf(0.5), 16) * scale
    out, _ = _render_and_backward(values, Cameras.look_at([[0.2, 0.3, 3.0]], fov_deg=40, image_size=12))
    # 1e6 is no distance field (its first step leaves the box: no hits); 1e-6 crawls and runs out
    # of steps. Either way the outputs and gradients above are finite, and normals where there are
    # hits have unit length whatever the scale.
    n = out.normal[out.hit]
    torch.testing.assert_close(n.norm(dim=-1), torch.ones(len(n)), atol=1e-5, rtol=0)


def test_feature_thinner_than_a_voxel():
    h = 2.0 / 15
    slab = _grid(lambda p: p[..., 2].abs() - 0.2 * h, 16)
    _render_and_backward(slab, Cameras.look_at([[0.4, 2.0, 2.0]], fov_deg=50, image_size=12))
    needle = _grid(lambda p: torch.linalg.norm(p[..., :2], dim=-1) - 0.3 * h, 16)
    _render_and_backward(needle, Cameras.look_at([[2.0, 0.5, 1.0]], fov_deg=50, image_size=12))


def test_grid_of_size_two():
    torch.manual_seed(1)
    values = torch.randn(2, 2, 2)
    _render_and_backward(values, Cameras.look_at([[0.5, 0.7, 3.0]], fov_deg=50, image_size=8))
    _render_and_backward(torch.randn(2, 3, 4), Cameras.look_at([[0.5, 0.7, 3.0]], fov_deg=50, image_size=8))


def test_non_cubic_grid_and_box_match_the_analytic_sphere():
    grid = SDFGrid.from_function(sphere_sdf(0.4), (24, 32, 40), bbox_min=(-0.5, -0.6, -0.7),
                                 bbox_max=(0.5, 0.6, 0.7), dtype=torch.float64)
    out = render(grid, Cameras.look_at([[0.0, 0.0, 3.0]], fov_deg=1e-3, image_size=1, dtype=torch.float64),
                 ALL, TraceSettings(threshold=1e-6))
    assert abs(out.depth.item() - 2.6) < 0.05 * 1.4 / 39


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize("values, word", [
    (torch.tensor([[[float("nan"), 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]]), "NaN"),
    (torch.full((3, 3, 3), float("inf")), "Inf"),
    (torch.zeros(4, 4), "shape"),
    (torch.zeros(1, 1, 4, 4, 4), "shape"),
    (torch.zeros(4, 1, 4), "2 samples"),
])
def test_bad_grid_values_raise(values, word):
    with pytest.raises(ValueError, match=word):
        SDFGrid(values)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
@pytest.mark.parametrize("backend", ["reference", "cpu"])
def test_values_made_non_finite_after_construction_raise_at_render(bad, backend):
    # SDFGrid keeps its tensor without a copy, so an optimiser step or a caller can spoil it later.
    grid = SDFGrid.from_function(sphere_sdf(0.5), 8)
    cams = Cameras.look_at([[0.0, 0.0, 3.0]], image_size=4)
    grid.values[0, 3, 4, 2] = bad
    with pytest.raises(ValueError, match="grid.values contains NaN or Inf"):
        render(grid, cams, ALL, backend=backend)


def test_bad_grid_arguments_raise():
    with pytest.raises(TypeError, match="values"):
        SDFGrid(torch.zeros(4, 4, 4, dtype=torch.int32))
    with pytest.raises(ValueError, match="bbox_max"):
        SDFGrid(torch.zeros(4, 4, 4), bbox_min=1.0, bbox_max=-1.0)
    with pytest.raises(ValueError, match="bbox_min"):
        SDFGrid(torch.zeros(4, 4, 4), bbox_min=(0.0, 1.0))


def test_mismatched_batches_raise():
    grid = SDFGrid(torch.zeros(2, 4, 4, 4))
    cams = Cameras.look_at([[0.0, 0.0, 3.0]] * 3, image_size=4)
    with pytest.raises(ValueError, match="multiple of the grid batch"):
        render(grid, cams)


def test_bad_settings_and_scene_raise():
    with pytest.raises(ValueError, match="max_steps"):
        TraceSettings(max_steps=0)
    with pytest.raises(ValueError, match="threshold"):
        TraceSettings(threshold=-1.0)
    with pytest.raises(ValueError, match="effect"):
        Scene(effects=("silhouette", "glitter"))
    with pytest.raises(ValueError, match="backend"):
        render(SDFGrid(torch.zeros(4, 4, 4)), Cameras.look_at([[0.0, 0.0, 3.0]], image_size=4), backend="gpu9")


# ---------------------------------------------------------------- passes
def test_silhouette_only_builds_no_hit_points_normals_or_lights(monkeypatch):
    """The PyTorch stage 2 (the fused one: tests/renderer/test_stage2.py)."""
    calls = {"hit": 0, "normal": 0, "light": 0}

    def counting(name, fn):
        def wrapper(*a, **k):
            calls[name] += 1
            return fn(*a, **k)
        return wrapper

    monkeypatch.setattr(shading_module, "hit_points_conservative",
                        counting("hit", shading_module.hit_points_conservative))
    monkeypatch.setattr(shading_module, "surface_normals", counting("normal", shading_module.surface_normals))
    monkeypatch.setattr(shading_module, "shade_lambert", counting("light", shading_module.shade_lambert))
    grid = SDFGrid.from_function(sphere_sdf(0.5), 16)
    cams = Cameras.look_at([[0.0, 0.0, 3.0]], image_size=16)
    out = render(grid, cams, Scene(effects=("silhouette",)), backend="reference")
    assert calls == {"hit": 0, "normal": 0, "light": 0}
    assert out.depth is None and out.normal is None and out.image is None
    render(grid, cams, Scene(effects=("depth",)), backend="reference")
    assert calls == {"hit": 1, "normal": 0, "light": 0}
    render(grid, cams, Scene(effects=("normal",)), backend="reference")
    assert calls == {"hit": 2, "normal": 1, "light": 0}
    render(grid, cams, ALL, backend="reference")
    assert calls == {"hit": 3, "normal": 2, "light": 1}


def test_silhouette_only_graph_reads_only_the_sdf():
    values = SDFGrid.from_function(torus_sdf, 16).values.requires_grad_(True)
    sil = render(SDFGrid(values), Cameras.look_at([[0.0, 1.0, 3.0]], image_size=16),
                 Scene(effects=("silhouette",))).silhouette
    seen, stack = set(), [sil.grad_fn]
    while stack:
        fn = stack.pop()
        if fn is None or fn in seen:
            continue
        seen.add(fn)
        stack.extend(f for f, _ in fn.next_functions)
    names = {type(f).__name__ for f in seen}
    assert not any("Norm" in n or "Sqrt" in n or "Clamp" in n for n in names), names


def test_each_effect_identical_alone_and_together():
    grid = SDFGrid.from_function(torus_sdf, 24)
    cams = Cameras.look_at([[0.5, 1.0, 2.5], [2.0, 0.3, -1.0]], fov_deg=45, image_size=20)
    full = render(grid, cams, ALL)
    for effect, field in [("silhouette", "silhouette"), ("depth", "depth"), ("normal", "normal"), ("shading", "image")]:
        alone = render(grid, cams, Scene(effects=(effect,), camera_light=1.0))
        assert torch.equal(getattr(alone, field), getattr(full, field)), effect


def test_one_grid_many_cameras_equals_one_camera_per_grid():
    grid = SDFGrid.from_function(torus_sdf, 24)
    cams = Cameras.look_at([[0.5, 1.0, 2.5], [2.0, 0.3, -1.0], [-2.0, 1.5, 0.5]], fov_deg=45, image_size=16)
    shared = render(grid, cams, ALL)
    copied = render(SDFGrid(grid.values.expand(3, -1, -1, -1).clone()), cams, ALL)
    for field in ("silhouette", "depth", "normal", "image"):
        assert torch.equal(getattr(shared, field), getattr(copied, field)), field
    # Two grids, two views each: camera c sees grid c // 2.
    two = SDFGrid(torch.stack([grid.values[0], SDFGrid.from_function(sphere_sdf(0.4), 24).values[0]]))
    cams4 = Cameras.look_at([[0.5, 1.0, 2.5]] * 4, fov_deg=45, image_size=16)
    out = render(two, cams4, ALL)
    assert torch.equal(out.depth[0], out.depth[1]) and torch.equal(out.depth[2], out.depth[3])
    assert not torch.equal(out.depth[1], out.depth[2])


# ---------------------------------------------------------------- memory
def _saved_bytes(max_steps: int) -> int:
    total = 0

    def pack(t):
        nonlocal total
        total += t.numel() * t.element_size()
        return t

    values = SDFGrid.from_function(sphere_sdf(0.5), 32).values.requires_grad_(True)
    cams = Cameras.look_at([[0.0, 0.0, 2.5]], fov_deg=30, image_size=32)
    with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
        out = render(SDFGrid(values), cams, ALL, TraceSettings(max_steps=max_steps))
    (out.image.sum() + out.silhouette.sum()).backward()
    assert int(out.trace.steps.max()) < 32  # every ray converged: the same hits both times
    return total


def test_backward_memory_does_not_grow_with_max_steps():
    """The march runs without autograd: the tensors the graph keeps for backward are the same
    whether the march may take 32 or 256 steps."""
    small, large = _saved_bytes(32), _saved_bytes(256)
    assert small > 0
    assert large == small


def test_an_unchanged_grid_is_not_checked_again_at_render(monkeypatch):
    """SDFGrid checks its values once when built; the render checks them again only after an
    in-place change (one pass over the grid saved per call)."""
    import renderer.trace as trace_module

    checked = []
    real = trace_module.require_finite
    monkeypatch.setattr(trace_module, "require_finite", lambda v, name: checked.append(name) or real(v, name))
    grid = SDFGrid.from_function(sphere_sdf(0.5), 8)
    cams = Cameras.look_at([[0.0, 0.0, 3.0]], image_size=4)
    render(grid, cams, ALL)
    assert checked == []
    grid.values.mul_(1.0)
    render(grid, cams, ALL)
    assert checked == ["grid.values"]
    grid.values = torch.full_like(grid.values, float("nan"))  # another tensor, never checked
    with pytest.raises(ValueError, match="grid.values contains NaN or Inf"):
        render(grid, cams, ALL)


def test_grids_of_inference_tensors_are_checked_at_every_render():
    """Inference tensors keep no count of in-place changes, so their grids are checked each time."""
    cams = Cameras.look_at([[0.0, 0.0, 3.0]], image_size=4)
    with torch.inference_mode():
        grid = SDFGrid.from_function(sphere_sdf(0.5), 8)
        assert not grid.unchanged_since_checked()
        render(grid, cams, ALL)
        grid.values[0, 3, 4, 2] = float("nan")
        with pytest.raises(ValueError, match="grid.values contains NaN or Inf"):
            render(grid, cams, ALL)
