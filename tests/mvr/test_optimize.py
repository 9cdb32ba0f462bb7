"""optimise_level: greedy view selection, stopping rules, reports."""
from __future__ import annotations

import pytest
import torch

from mvr import OptimSettings, ViewLosses, make_target, optimise_level
from mvr.optimize import CameraPoses
from mvr.reconstruct import RigSettings, default_scene
from renderer import SDFGrid, TraceSettings


@pytest.fixture(scope="module")
def problem():
    scene = default_scene()
    cams = RigSettings().cameras(16)
    views = make_target("sphere", extent=1.0, mesh_resolution=48).render(cams, scene)
    grid = SDFGrid.from_function(lambda p: p.norm(dim=-1) - 0.7, 8, -1.0, 1.0)

    def losses(settings: OptimSettings) -> ViewLosses:
        return ViewLosses(cams, views.images, views.masks, scene, TraceSettings(), "auto", settings)

    return grid, losses


def test_level_reduces_the_loss(problem):
    grid, losses = problem
    settings = OptimSettings(max_passes=2, hard_view_updates=6, easy_view_updates=2, lr=0.1)
    fitted, report = optimise_level(grid, losses(settings), progress=False)
    assert report.loss_end < 0.5 * report.loss_start
    assert report.passes == len(report.history) <= 2 and report.updates > 0
    assert torch.equal(grid.values, SDFGrid.from_function(lambda p: p.norm(dim=-1) - 0.7, 8).values)  # untouched
    assert not fitted.values.requires_grad
    # Greedy selection: each of the 26 views gets at least 1 and at most 6 updates per pass.
    for h in report.history:
        assert 26 <= h["updates"] <= 26 * 6


def test_batch_steps_take_adams_steps_on_the_mean_loss_of_all_views(problem):
    """``batch_steps``: a pass is that many Adam steps on the mean loss of every view, rendered in
    chunks; the first step is Adam's first step on that mean's gradient (lr g / (|g| + eps)),
    computed here in one render of all 26 views."""
    grid, losses = problem
    settings = OptimSettings(max_passes=2, batch_steps=3, lr=0.1, carve=False, fill_cavities=False)
    _, report = optimise_level(grid, losses(settings), progress=False)
    assert report.loss_end < 0.7 * report.loss_start
    assert [h["updates"] for h in report.history] == [3] * report.passes
    one, _ = optimise_level(grid, losses(OptimSettings(max_passes=1, batch_steps=1, lr=0.1, carve=False,
                                                       fill_cavities=False, min_passes=1)), progress=False)
    values = grid.values.clone().requires_grad_(True)
    whole = losses(settings)
    (whole.data_loss(SDFGrid(values), torch.arange(26))[0].mean() + whole.regulariser(SDFGrid(values))[0]).backward()
    g, step = values.grad, one.values - grid.values
    lr = 0.1 * float(grid.voxel_size.min())
    assert float(step.abs().max()) > 0.5 * lr
    assert torch.allclose(step, -lr * g / (g.abs() + settings.eps), rtol=1e-3, atol=1e-4 * lr)
    with pytest.raises(ValueError, match="batch_steps"):
        OptimSettings(batch_steps=-1)


FEW = dict(hard_view_updates=1, easy_view_updates=1)


@pytest.mark.parametrize("settings, reason", [
    (OptimSettings(max_passes=5, min_passes=1, loss_tol=1.0, **FEW), "loss_tol"),
    (OptimSettings(max_passes=5, min_passes=1, step_tol=1e9, **FEW), "step_tol"),
    (OptimSettings(max_passes=5, min_passes=1, rel_tol=10.0, patience=1, **FEW), "plateau"),
    (OptimSettings(max_passes=5, max_seconds=1e-6, **FEW), "max_seconds"),
    (OptimSettings(max_passes=1, **FEW), "max_passes"),
])
def test_stopping_rules(problem, settings, reason):
    grid, losses = problem
    _, report = optimise_level(grid, losses(settings), progress=False)
    assert report.stop_reason == reason and report.passes == 1


def test_view_losses_bad_input(problem):
    grid, losses = problem
    good = losses(OptimSettings())
    with pytest.raises(ValueError, match="do not match"):
        ViewLosses(good.cameras, good.images[:3], good.masks[:3], good.scene, good.trace, "auto", good.settings)
    with pytest.raises(ValueError, match="one grid"):
        optimise_level(SDFGrid(grid.values.expand(2, -1, -1, -1).clone()), good, progress=False)


def test_camera_poses_move_only_the_rendered_cameras_and_keep_no_common_motion():
    """CameraPoses: zero corrections give the cameras back; an update moves the cameras whose
    views had a gradient, then the common orbit and distance of all are removed; its state
    restores, and a state of the earlier parameterisation is refused."""
    cams = RigSettings().cameras(8).to(dtype=torch.float64)
    poses = CameraPoses(26, lr=0.01)
    same = poses.apply(cams, torch.arange(26))
    torch.testing.assert_close(same.eye, cams.eye, atol=0, rtol=0)
    torch.testing.assert_close(same.forward, cams.forward, atol=1e-15, rtol=0)
    moved = poses.apply(cams, torch.tensor([3, 7]))
    (moved.eye[:, 0].sum() + moved.forward[:, 1].sum()).backward()
    poses.step()
    changed = (poses.orbit.norm(dim=1) + poses.distance.abs() + poses.aim.norm(dim=1)) > 0
    assert changed[[3, 7]].all()
    torch.testing.assert_close(poses.orbit.mean(0), torch.zeros(3, dtype=torch.float64), atol=1e-15, rtol=0)
    torch.testing.assert_close(poses.distance.mean(0), torch.zeros((), dtype=torch.float64), atol=1e-15, rtol=0)
    # the others moved only by the common part removed: all alike, and none of them was aimed
    others = [v for v in range(26) if v not in (3, 7)]
    assert torch.equal(poses.orbit[others], poses.orbit[others[:1]].expand(len(others), 3))
    assert torch.equal(poses.aim[others], torch.zeros(len(others), 3, dtype=torch.float64))
    assert poses.aim[[3, 7]].norm(dim=1).min() > 0
    state = poses.state()
    again = CameraPoses(26, lr=0.01)
    again.load(state)
    assert torch.equal(again.orbit, poses.orbit) and torch.equal(again.distance, poses.distance)
    assert torch.equal(again.aim, poses.aim)
    with pytest.raises(ValueError, match="earlier version"):
        again.load({"rotation": state["orbit"], "translation": state["orbit"], "adam": state["adam"]})
    with pytest.raises(ValueError, match="26 cameras for 4 pose corrections"):
        CameraPoses(4, lr=0.01).apply(cams, torch.arange(4))
    with pytest.raises(ValueError, match="camera_levels must be"):
        OptimSettings(cameras=True, camera_levels=0)
    with pytest.raises(TypeError, match="cameras must be true or false"):
        OptimSettings(cameras="yes")


def test_camera_corrections_are_an_orbit_a_distance_and_an_aim():
    """Each correction moves the camera as its name says: an orbit turns the eye about the origin
    with the camera's axes (still looking at the origin), a distance moves the eye along its line to
    the origin, an aim turns the axes about a fixed eye."""
    import math

    cams = RigSettings().cameras(8).to(dtype=torch.float64)
    v = torch.tensor([0])
    base = cams[v]
    look = -base.eye[0] / base.eye[0].norm()
    torch.testing.assert_close(base.forward[0], look, atol=1e-12, rtol=0)  # the rig looks at the origin

    poses = CameraPoses(26, lr=0.01)
    axis = torch.linalg.cross(base.eye[0], base.up[0])
    with torch.no_grad():
        poses.orbits[0].copy_(0.3 * axis / axis.norm())  # an axis through the origin, across the view
    c = poses.apply(cams, v)
    torch.testing.assert_close(c.eye[0].norm(), base.eye[0].norm(), atol=1e-12, rtol=0)
    torch.testing.assert_close(c.forward[0], -c.eye[0] / c.eye[0].norm(), atol=1e-12, rtol=0)
    cos = float((c.eye[0] * base.eye[0]).sum().detach() / base.eye[0].norm() ** 2)
    assert cos == pytest.approx(math.cos(0.3), abs=1e-12)  # the eye went 0.3 radians round the origin

    poses = CameraPoses(26, lr=0.01)
    with torch.no_grad():
        poses.distances[0].fill_(math.log(1.5))
    c = poses.apply(cams, v)
    torch.testing.assert_close(c.eye[0], 1.5 * base.eye[0], atol=1e-12, rtol=0)
    torch.testing.assert_close(c.forward[0], base.forward[0], atol=1e-12, rtol=0)

    poses = CameraPoses(26, lr=0.01)
    with torch.no_grad():
        poses.aims[0].copy_(0.2 * base.up[0])  # a turn about the camera's up axis
    c = poses.apply(cams, v)
    torch.testing.assert_close(c.eye[0], base.eye[0], atol=0, rtol=0)
    torch.testing.assert_close(c.up[0], base.up[0], atol=1e-12, rtol=0)
    assert float((c.forward[0] * base.forward[0]).sum().detach()) == pytest.approx(math.cos(0.2), abs=1e-12)


def test_carving_removes_what_lies_outside_the_visual_hull():
    """A blob beside the target sphere, outside every view's silhouette cone, is cut away by the
    visual hull while the sphere's inside is kept; with ``carve`` the level's passes do the same,
    without it the blob survives a pass that can barely move the grid."""
    scene = default_scene()
    cams = RigSettings().cameras(48)  # a pixel ~0.07 at the sphere: half of it within the tolerance
    views = make_target("sphere", extent=1.0, mesh_resolution=48).render(cams, scene)

    def losses(settings: OptimSettings) -> ViewLosses:
        return ViewLosses(cams, views.images, views.masks, scene, TraceSettings(), "auto", settings)

    sphere_and_blob = SDFGrid.from_function(
        lambda p: torch.minimum(p.norm(dim=-1) - 0.5, (p - torch.tensor([0.85, 0.0, 0.0])).norm(dim=-1) - 0.12),
        32, -1.0, 1.0)
    points = sphere_and_blob.points()
    blob = (points - torch.tensor([0.85, 0.0, 0.0])).norm(dim=-1) < 0.1
    core = points.norm(dim=-1) < 0.35
    assert bool((sphere_and_blob.values[0][blob] < 0).all())
    tolerance = 2.0 / 31
    carved = losses(OptimSettings()).carve(sphere_and_blob.values[0], sphere_and_blob.bbox_min,
                                           sphere_and_blob.bbox_max, tolerance)
    assert bool((carved[blob] > 0).all())
    assert torch.equal(carved[core], sphere_and_blob.values[0][core])
    assert bool((carved >= sphere_and_blob.values[0]).all())  # carving only raises values
    with pytest.raises(TypeError, match="carve must be true or false"):
        OptimSettings(carve=1)
    with pytest.raises(ValueError, match="carve_tolerance"):
        OptimSettings(carve_tolerance=-1.0)
    for carve, blob_left in ((True, False), (False, True)):
        settings = OptimSettings(max_passes=1, lr=1e-4, carve=carve, **FEW)
        fitted, _ = optimise_level(sphere_and_blob, losses(settings), progress=False)
        assert bool((fitted.values[0][blob] < 0).any()) == blob_left


def test_redistancing_after_a_pass_keeps_the_surface_and_mends_the_far_values(problem):
    """With ``redistance`` a pass leaves the values away from the surface at their distance to it
    (here a grid three times too steep beyond a sphere, which a pass barely moves), the surface where
    the pass put it; ``regulariser_band`` needs it and weighs each vertex as the full sum does."""
    from sdfcommon.numerics.redistance import interface_mask

    grid, losses = problem
    steep = SDFGrid.from_function(lambda p: 3 * (p.norm(dim=-1) - 0.5), 16, -1.0, 1.0)
    out = {}
    for on in (False, True):
        settings = OptimSettings(max_passes=1, lr=1e-4, redistance=on, **FEW)
        out[on], _ = optimise_level(steep, losses(settings), progress=False)
    plain, mended = out[False].values[0], out[True].values[0]
    interface = torch.from_numpy(interface_mask((mended < 0).numpy()))
    assert torch.equal(mended < 0, plain < 0)
    assert torch.allclose(mended[interface], plain[interface])
    radius = steep.points().norm(dim=-1)
    far = ~interface & (radius > 0.8)
    assert float((plain[far] - (radius[far] - 0.5)).abs().min()) > 0.5      # still three times too steep
    assert float((mended[far] - (radius[far] - 0.5)).abs().max()) < 0.1     # a distance again (voxel 0.13)
    with pytest.raises(ValueError, match="regulariser_band=2.0 needs redistance=true"):
        OptimSettings(regulariser_band=2.0)
    sphere = SDFGrid.from_function(lambda p: p.norm(dim=-1) - 0.5, 16, -1.0, 1.0)
    wide = losses(OptimSettings(redistance=True, regulariser_band=100.0)).regulariser(sphere)
    full = losses(OptimSettings()).regulariser(sphere)
    assert float(wide[2]) == pytest.approx(float(full[2]) * 14 ** 3 / 16 ** 3, rel=1e-5)  # the Laplacian
