"""Voxel IoU (svr/nmr/metrics.py): analytic spheres, the gap between the fast direct variant and the
protocol, the per-category table, bad input, and clipping to the object box (the voxelisation rules,
the NMR frame and the fill: test_voxels.py)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

import renderer
from svr.data.procedural.generator import make_shape, voxelize_shape
from svr.nmr.metrics import (PAPER_SDFDIFF_IOU, PROTOCOL_LIKE_LEVEL, iou_direct, iou_protocol, iou_table, voxel_iou,
                             voxels_protocol)
from svr.nmr.voxels import (nmr_voxel_centres, voxelize_mesh_nmr, voxelize_sdf_direct, voxelize_sdf_protocol,
                            voxels_to_sdf)

R = 32
BOX = (-0.6, 0.6)


def sphere_grid(radius: float, centre=(0.0, 0.0, 0.0), n: int = 64) -> torch.Tensor:
    c = torch.tensor(centre, dtype=torch.float64)
    return renderer.SDFGrid.from_function(lambda p: (p - c).norm(dim=-1) - radius, n, *BOX,
                                          dtype=torch.float64).values


def analytic_grid(shape, n: int = 64) -> torch.Tensor:
    """(1, n, n, n) samples of a shape's analytic SDF over BOX (renderer.SDFGrid layout)."""
    return renderer.SDFGrid.from_function(lambda p: torch.from_numpy(shape.sdf_numpy(p.numpy())), n, *BOX,
                                          dtype=torch.float64).values


def centre_voxels(fn) -> np.ndarray:
    """Ground truth by the SPEC's definition: occupied iff the voxel centre is inside."""
    return (fn(nmr_voxel_centres(dtype=torch.float64)) < 0).numpy()


# ------------------------------------------------------------------------------------ IoU


def test_iou_basics():
    a = np.zeros((2, R, R, R), bool)
    a[:, :4] = True
    b = np.zeros_like(a)
    b[0, :2] = True
    np.testing.assert_allclose(voxel_iou(a, a).numpy(), [1.0, 1.0])
    np.testing.assert_allclose(voxel_iou(a, b).numpy(), [0.5, 0.0])
    assert voxel_iou(np.zeros((R, R, R), bool), np.zeros((R, R, R), bool)).item() == 1.0
    assert voxel_iou(torch.from_numpy(a).int(), a).tolist() == [1.0, 1.0]


def test_ground_truth_against_itself_is_one():
    gt = voxelize_shape(make_shape("chair", [0, 3]))
    assert voxel_iou(gt, gt).item() == 1.0
    values, lo, hi = voxels_to_sdf(gt)
    grid = torch.from_numpy(values)[None]
    assert iou_direct(grid, gt[None], lo, hi).item() == 1.0
    # The protocol's voxels of the same surface contain the ground truth (it only adds voxels).
    prot = voxels_protocol(grid, lo, hi)[0].numpy()
    assert prot[gt].all()


def _lens_volume(r1: float, r2: float, d: float) -> float:
    return math.pi * (r1 + r2 - d) ** 2 * (d * d + 2 * d * r2 - 3 * r2 * r2 + 2 * d * r1 + 6 * r1 * r2 - 3 * r1 * r1) / (12 * d)


def test_two_overlapping_spheres_give_the_analytic_iou():
    """Direct IoU of sphere A (prediction, an SDF grid) against sphere B (centre-sampled voxels),
    against the lens formula; the discretisation error of 1/31 voxels is about 0.02 here."""
    ra, rb, d = 0.3, 0.25, 0.2
    ca, cb = np.array([-0.08, 0.02, 0.05]), np.array([0.12, 0.02, 0.05])
    inter = _lens_volume(ra, rb, d)
    analytic = inter / (4 / 3 * math.pi * (ra ** 3 + rb ** 3) - inter)
    gt = centre_voxels(lambda p: (p - torch.from_numpy(cb)).norm(dim=-1) - rb)
    got = iou_direct(sphere_grid(ra, ca), gt[None], *BOX).item()
    assert abs(got - analytic) < 0.02, (got, analytic)


def test_nested_spheres_direct_and_protocol():
    """Sphere r1 predicted inside ground-truth sphere r2: the direct IoU is (r1/r2)^3 within the
    discretisation error; the protocol's surface voxels make the prediction one dilation layer
    larger, so its IoU lies between (r1/r2)^3 and ((r1 + sqrt(3)/31)/r2)^3."""
    r1, r2 = 0.25, 0.4
    gt = centre_voxels(lambda p: p.norm(dim=-1) - r2)
    grid = sphere_grid(r1)
    direct = iou_direct(grid, gt[None], *BOX).item()
    assert abs(direct - (r1 / r2) ** 3) < 0.02
    prot = iou_protocol(grid, gt[None], *BOX).item()
    assert (r1 / r2) ** 3 < prot < ((r1 + math.sqrt(3) / 31) / r2) ** 3
    # Against protocol-made ground truth of the same sphere, the protocol is exact.
    same = voxelize_sdf_protocol(sphere_grid(r1, n=96)[0], *BOX)
    assert iou_protocol(grid, same[None], *BOX).item() > 0.97


def test_direct_voxels_are_empty_outside_the_grid_box():
    grid = torch.full((1, 8, 8, 8), -1.0)  # everything inside, but the box is small
    vox = voxelize_sdf_direct(grid, -0.2, 0.2)[0].numpy()
    centres = nmr_voxel_centres().numpy()
    np.testing.assert_array_equal(vox, (np.abs(centres) <= 0.2).all(-1))


def test_gap_between_direct_and_protocol_iou_on_procedural_shapes(capsys):
    """How far the fast validation IoU is from the benchmark's, for perfect predictions (the
    analytic SDF sampled on a 64^3 grid) against centre-sampled ground truth. The protocol adds a
    dilated surface layer: thin parts (1-3 voxels) double in volume, so it sits far below. The
    direct IoU at PROTOCOL_LIKE_LEVEL tracks the protocol's instead."""
    rows = []
    for name, seed in (("chair", 1), ("mug", 2), ("sofa", 3), ("airplane", 4)):
        shape = make_shape(name, [8, seed])
        gt = voxelize_shape(shape)[None]
        grid = analytic_grid(shape)
        rows.append((name, iou_direct(grid, gt, *BOX).item(), iou_protocol(grid, gt, *BOX).item(),
                     iou_direct(grid, gt, *BOX, level=PROTOCOL_LIKE_LEVEL).item()))
    with capsys.disabled():
        print("\n  IoU of exact predictions, direct / protocol / direct at PROTOCOL_LIKE_LEVEL: "
              + ", ".join(f"{n} {d:.3f}/{p:.3f}/{q:.3f}" for n, d, p, q in rows))
    direct, prot, like = (np.array([r[k] for r in rows]) for k in (1, 2, 3))
    assert direct.min() > 0.85  # a 64^3 grid (0.6 voxel) blurs parts 1.5 voxels thick
    assert np.all(prot < direct) and np.all(prot > 0.35)
    assert 0.1 < (direct - prot).mean() < 0.6
    assert np.abs(like - prot).mean() < 0.05


@pytest.mark.slow
def test_gap_between_direct_and_protocol_iou_all_categories(capsys):
    from svr.data.procedural.generator import ALL_CATEGORIES

    gaps = {}
    for cat in ALL_CATEGORIES:
        vals = []
        for seed in range(4):
            shape = make_shape(cat.name, [8, 100 + seed])
            gt = voxelize_shape(shape)[None]
            grid = analytic_grid(shape)
            vals.append((iou_direct(grid, gt, *BOX).item(), iou_protocol(grid, gt, *BOX).item()))
        gaps[cat.name] = np.mean(vals, axis=0)
    with capsys.disabled():
        for name, (d, p) in gaps.items():
            print(f"  {name:9s} direct {d:.3f} protocol {p:.3f} gap {d - p:.3f}")
    assert all(d > 0.9 for d, _ in gaps.values())


# ------------------------------------------------------------------------------------ tables


def test_table_means_per_category_then_over_categories():
    cats = [("02691156", "airplane"), ("03001627", "chair"), ("04379243", "table")]
    iou = np.array([0.5, 0.7, 0.9, 0.2])
    index = np.array([0, 0, 0, 1])
    table = iou_table(iou, index, cats)
    assert [r.images for r in table.rows] == [3, 1, 0]
    assert table.rows[0].iou == pytest.approx(0.7) and table.rows[1].iou == pytest.approx(0.2)
    assert math.isnan(table.rows[2].iou)
    assert table.mean == pytest.approx((0.7 + 0.2) / 2)  # unweighted, empty category left out
    d = table.to_dict()
    json.dumps(d)
    assert d["categories"][1] == {"id": "03001627", "name": "chair", "iou": 0.2, "images": 1}
    md = table.to_markdown(PAPER_SDFDIFF_IOU)
    assert "| chair | 03001627 | 1 | 0.2000 | 0.6436 |" in md
    assert md.splitlines()[-1].startswith("| **mean** |")


def test_bad_input_is_refused():
    v = np.zeros((R, R, R), bool)
    with pytest.raises(ValueError, match="shapes differ"):
        voxel_iou(v, np.zeros((16, 16, 16), bool))
    with pytest.raises(TypeError, match="pred must be bool"):
        voxel_iou(v.astype(np.float32), v)
    with pytest.raises(ValueError, match="gt must have shape"):
        voxel_iou(v, np.zeros((R, R), bool))
    with pytest.raises(ValueError, match="values has 2 grids but gt has 1"):
        iou_direct(torch.zeros(2, 8, 8, 8), v[None])
    with pytest.raises(TypeError, match="floating-point"):
        iou_protocol(torch.zeros(1, 8, 8, 8, dtype=torch.long), v[None])
    with pytest.raises(ValueError, match=r"category_index must lie in \[0, 1\)"):
        iou_table([0.5], [1], [("1", "a")])
    with pytest.raises(ValueError, match="faces index vertices out of range"):
        voxelize_mesh_nmr(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(ValueError, match="vertices must have shape"):
        voxelize_mesh_nmr(np.zeros((3, 2)), np.array([[0, 1, 2]]))


def _cuboid_sdf(p: torch.Tensor, half) -> torch.Tensor:
    q = p.abs() - torch.tensor(half, dtype=p.dtype)
    return q.clamp(min=0).norm(dim=-1) + q.amax(-1).clamp(max=0)


def test_clipping_to_the_object_box_keeps_shapes_that_reach_past_the_benchmark_grid_solid():
    from svr.nmr.voxels import clip_to_box, nmr_voxel_centres

    n, hs = 64, 0.6
    axis = torch.linspace(-hs, hs, n, dtype=torch.float64)
    p = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)
    bar = _cuboid_sdf(p, (0.57, 0.2, 0.25))  # longer than the benchmark grid along x
    gt = _cuboid_sdf(nmr_voxel_centres(dtype=torch.float64), (0.57, 0.2, 0.25)) < 0
    open_shell = voxels_protocol(bar, -hs, hs)[0]
    closed = voxels_protocol(clip_to_box(bar, -hs, hs), -hs, hs)[0]
    # Unclipped, the voxeliser drops the ends outside its grid and the fill leaks inside.
    assert float(voxel_iou(open_shell, gt)) < 0.2 < 0.8 < float(voxel_iou(closed, gt))
    # A shape inside the box is untouched: same values near and inside it, same voxels.
    ball = p.norm(dim=-1) - 0.3
    clipped = clip_to_box(ball, -hs, hs)
    near = (p.abs() <= 0.5).all(-1) & (ball > -0.2)
    assert torch.equal(clipped[near], ball[near])
    assert torch.equal(voxels_protocol(clipped, -hs, hs), voxels_protocol(ball, -hs, hs))
    with pytest.raises(ValueError, match="values"):
        clip_to_box(torch.zeros(4, 4), -hs, hs)
