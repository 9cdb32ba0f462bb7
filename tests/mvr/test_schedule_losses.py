"""The coarse-to-fine schedule, the image resolution rule, the energy's terms, cavity filling."""
from __future__ import annotations

import math

import pytest
import torch

from mvr import (OptimSettings, Schedule, fill_cavities, rule_image_size, view_image_losses,
                 view_silhouette_losses)
from renderer import Cameras, SDFGrid


def test_resolutions():
    assert Schedule().grid_resolutions() == [8, 16, 32, 64]
    assert Schedule(levels=1).grid_resolutions() == [64]
    assert Schedule(start=16, end=64, levels=3).grid_resolutions() == [16, 32, 64]
    eight = Schedule(levels=8).grid_resolutions()
    assert len(eight) == 8 and eight[0] == 8 and eight[-1] == 64
    assert all(b > a for a, b in zip(eight, eight[1:]))
    assert Schedule(resolutions=[8, 20, 40]).grid_resolutions() == [8, 20, 40]


@pytest.mark.parametrize("kwargs, name", [
    ({"start": 2}, "start"), ({"end": 4, "start": 8}, "start"), ({"levels": 0}, "levels"),
    ({"start": 8, "end": 10, "levels": 5}, "levels"), ({"resolutions": [16, 8]}, "resolutions"),
    ({"image_size": 2}, "image_size"), ({"voxel_footprint_px": 0}, "voxel_footprint_px"),
])
def test_schedule_bad_input(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Schedule(**kwargs)


def test_image_rule():
    """One pixel spans a voxel at the farthest box corner (a one-voxel sphere covers 2x2 pixels)."""
    cams = Cameras.cube_rig(3.0, fov_deg=56, image_size=8)
    lo, hi = torch.full((3,), -1.0), torch.full((3,), 1.0)
    size = rule_image_size(cams, lo, hi, 64)
    far = 3.0 + math.sqrt(3.0)  # a corner view's farthest box corner
    h = 2.0 / 63
    assert size == math.ceil(2 * math.tan(math.radians(28)) * far / h)
    pixel_at_far = far * float(Cameras.cube_rig(3.0, fov_deg=56, image_size=size).pixel_angle.max())
    assert h * 0.98 <= pixel_at_far <= h
    sizes = [Schedule().image_size_for(cams, lo, hi, r) for r in (8, 16, 32, 64)]
    assert sizes == sorted(sizes) and sizes[0] >= 16
    assert Schedule(image_size=40).image_size_for(cams, lo, hi, 64) == 40


def test_losses():
    a = torch.zeros(2, 4, 4, 1)
    b = torch.ones(2, 4, 4, 1)
    b[1] = 0.5
    assert torch.allclose(view_image_losses(a, b), torch.tensor([1.0, 0.25]))
    assert torch.allclose(view_silhouette_losses(a[..., 0], b[..., 0]), torch.tensor([1.0, 0.25]))
    with pytest.raises(ValueError, match="rendered"):
        view_image_losses(a, b[:1])
    with pytest.raises(ValueError, match="silhouette"):
        view_silhouette_losses(a, b)


def test_silhouette_dead_zone_by_hand():
    """With a tolerance, coverage within it of the target costs nothing and beyond it only the
    excess counts, on either side; a thin part covered 0.8 is no longer pulled towards 1."""
    target = torch.tensor([[[1.0, 1.0, 0.0, 0.0]]])
    sil = torch.tensor([[[0.8, 0.5, 0.1, 0.6]]], requires_grad=True)
    plain = view_silhouette_losses(sil, target)
    assert torch.allclose(plain, torch.tensor([(0.04 + 0.25 + 0.01 + 0.36) / 4]))
    zone = view_silhouette_losses(sil, target, tolerance=0.25)
    assert torch.allclose(zone, torch.tensor([(0.0 + 0.0625 + 0.0 + 0.1225) / 4]))
    zone.sum().backward()
    assert torch.allclose(sil.grad, torch.tensor([[[0.0, -0.125, 0.0, 0.175]]]))
    assert torch.equal(view_silhouette_losses(sil, target, tolerance=0.0), plain)
    with pytest.raises(ValueError, match="tolerance"):
        view_silhouette_losses(sil, target, tolerance=0.5)


def test_l1_and_pyramid_image_losses_by_hand():
    """L1 against L2 on a uniform error; a pyramid level averages 2x2 blocks first: a checkerboard
    of +-1 errors costs 1 at full size and 0 once averaged, so two levels give 1/2, three 1/3."""
    a = torch.zeros(2, 4, 4, 1)
    b = torch.full((2, 4, 4, 1), 0.5)
    assert torch.allclose(view_image_losses(a, b, "l1"), torch.tensor([0.5, 0.5]))
    assert torch.allclose(view_image_losses(a, b, "l2", levels=3), torch.tensor([0.25, 0.25]))
    board = (torch.arange(4)[:, None] + torch.arange(4)[None, :]) % 2 * 2.0 - 1.0  # +-1
    checker = board[None, :, :, None].expand(1, 4, 4, 1)
    zero = torch.zeros(1, 4, 4, 1)
    assert float(view_image_losses(checker, zero, "l1")) == pytest.approx(1.0)
    assert float(view_image_losses(checker, zero, "l1", levels=2)) == pytest.approx(0.5)
    assert float(view_image_losses(checker, zero, "l2", levels=3)) == pytest.approx(1 / 3)
    with pytest.raises(ValueError, match="one of"):
        view_image_losses(a, b, "huber")
    with pytest.raises(ValueError, match="pyramid levels"):
        view_image_losses(a, b, "l1", levels=4)
    with pytest.raises(ValueError, match="image_loss"):
        OptimSettings(image_loss="l3")
    with pytest.raises(ValueError, match="image_levels"):
        OptimSettings(image_levels=0)


def test_fill_cavities():
    grid = SDFGrid.from_function(lambda p: p.norm(dim=-1) - 0.7, 24)
    values = grid.values[0].clone()
    bubble = (grid.points().norm(dim=-1) < 0.2)
    values[bubble] = 0.1  # a positive pocket inside the solid
    filled = fill_cavities(values)
    assert (filled[bubble] < 0).all()
    outside = values > 0
    assert torch.equal(filled[outside & ~bubble], values[outside & ~bubble])
    assert torch.equal(fill_cavities(grid.values[0]), grid.values[0])


def test_optim_settings_bad_input():
    with pytest.raises(ValueError, match="lr"):
        OptimSettings(lr=0)
    with pytest.raises(ValueError, match="both be 0"):
        OptimSettings(image_weight=0, silhouette_weight=0)
    with pytest.raises(ValueError, match="hard_view_updates"):
        OptimSettings(hard_view_updates=0)
    s = OptimSettings(max_passes=[3, 4], max_seconds=[None, 5.0])
    assert [s.for_level("max_passes", k) for k in range(4)] == [3, 4, 4, 4]
    assert s.for_level("max_seconds", 0) is None


def test_shrink_thins_thick_parts_and_keeps_thin_ones():
    """``shrink``: without ``keep`` every value rises by the erosion; with it a sphere's surface
    moves in by the erosion while a rod thinner than ``keep`` is left as it was, and the values
    never fall."""
    from mvr.optimize import shrink

    grid = SDFGrid.from_function(
        lambda p: torch.minimum(p.norm(dim=-1) - 0.5,
                                torch.maximum(p[..., 1:].norm(dim=-1) - 0.04, p[..., 0].abs() - 0.9)), 64, -1.0, 1.0)
    v, h = grid.values[0], float(grid.voxel_size.min())
    assert torch.allclose(shrink(v, h, 2.0, None), v + 2.0 * h)
    out = shrink(v, h, 2.0, 1.5)
    assert bool((out >= v).all())
    points = grid.points()
    rod = (points[..., 0].abs() > 0.75) & (points[..., 0].abs() < 0.85)
    assert torch.equal(out[rod], v[rod])                      # 0.04 is 0.6 voxel: under keep
    deep = points.norm(dim=-1) < 0.4
    assert torch.allclose(out[deep], v[deep] + 2.0 * h)       # inside the sphere: the full erosion
    inside_after = (out < 0) & (points.norm(dim=-1) > 0.45) & (points[..., 1:].norm(dim=-1) > 0.1)
    assert not bool(inside_after.any())                       # the sphere's skin went


def test_residual_carve_opens_a_bridged_dent_and_little_else():
    """``residual_carve``: a box whose top dent (``mvr.shapes``' dented box, scaled into the grid) is
    filled in, against the dented box's images: the samples it takes out of the shape lie in the dent,
    where the filled box is wrong, or within the rays' depth (3 samples) past it, and reach a good
    share of it."""
    from mvr.optimize import ViewLosses, residual_carve
    from mvr.shapes import dented_box_sdf, rounded_box_sdf
    from renderer import Scene, TraceSettings, render

    scale = 0.55
    truth = SDFGrid.from_function(lambda p: dented_box_sdf(p / scale) * scale, 32, -1.0, 1.0)
    filled = SDFGrid.from_function(lambda p: rounded_box_sdf(p / scale, (1.0, 0.6, 1.0), 0.1) * scale, 32, -1.0, 1.0)
    scene = Scene(effects=("silhouette", "shading"), camera_light=7.2, camera_light_falloff=True, ambient=0.2)
    cams = Cameras.cube_rig(3.0, fov_deg=56, image_size=64)
    out = render(truth, cams, scene)
    losses = ViewLosses(cams, out.image.detach(), out.silhouette.detach() >= 0.5, scene, TraceSettings(), "auto",
                        OptimSettings())
    carved = residual_carve(filled, losses, depth=3.0, views=3)
    raised = (carved.values[0] > filled.values[0]) & (filled.values[0] < 0)  # taken out of the shape
    wrong = (filled.values[0] < 0) & (truth.values[0] > 0)  # inside the filled box, outside the dented one
    from scipy import ndimage

    near = torch.from_numpy(ndimage.binary_dilation(wrong.numpy(), iterations=3))  # the rays' depth past it
    assert int(raised.sum()) > 0
    assert float((raised & near).sum()) / float(raised.sum()) > 0.9    # it carves at the filling
    assert float((raised & wrong).sum()) / float(wrong.sum()) > 0.5    # and most of it (0.80 measured)
    assert bool((carved.values[0] >= filled.values[0]).all())          # it only ever removes
    same = residual_carve(truth, losses, depth=3.0, views=3)           # the right shape: nothing to carve
    assert torch.equal(same.values[0][truth.values[0] < 0], truth.values[0][truth.values[0] < 0])
    # the silhouettes' margin (``edge_px``): every pixel within it casts no ray, a narrower one more
    assert torch.equal(residual_carve(filled, losses, depth=3.0, views=3, edge_px=64).values, filled.values)
    loose = residual_carve(filled, losses, depth=3.0, views=3, edge_px=0)
    assert bool(((loose.values[0] > filled.values[0]) | ~raised).all())  # what the 3 px margin carves, and
    assert int(((loose.values[0] > filled.values[0]) & (filled.values[0] < 0)).sum()) >= int(raised.sum())
