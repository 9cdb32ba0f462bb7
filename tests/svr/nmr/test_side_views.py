"""svr.nmr.side_views: the side views of an input view, the silhouette IoU on masks with known
answers, and the whole metric on box SDFs: an exact prediction scores 1, an empty one 0, and a
pair of boxes matches the IoU of their exact silhouettes found by slab tests of the pixel rays."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import renderer
from renderer.reference import box_interval
from svr.nmr.side_views import render_silhouettes, side_view_iou, side_views, silhouette_iou

HALF = 0.5  # the grids' box: [-0.5, 0.5]^3, the network's
N = 64  # the network's grid resolution


def box_sdf(lo, hi) -> torch.Tensor:
    """(1, N, N, N) SDF of the axis-aligned box [lo, hi] sampled over the grids' box."""
    pts = renderer.SDFGrid(torch.zeros(1, N, N, N), -HALF, HALF).points()
    lo, hi = torch.tensor(lo), torch.tensor(hi)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    q = (pts - centre).abs() - half
    outside = q.clamp(min=0).norm(dim=-1)
    inside = q.amax(dim=-1).clamp(max=0)
    return (outside + inside)[None]


def exact_silhouettes(lo, hi, views: torch.Tensor, size: int = 64) -> torch.Tensor:
    """(B, 2, S, S) bool: pixel-centre rays of the NMR cameras that pass through the box [lo, hi]."""
    cams = renderer.Cameras.nmr(views.reshape(-1), image_size=size)
    origins, directions = cams.rays()
    near, far = box_interval(origins.reshape(-1, 3), directions.reshape(-1, 3), torch.tensor(lo), torch.tensor(hi))
    return ((near <= far) & (far > 0)).reshape(*views.shape, size, size)


def as_alpha(masks: torch.Tensor) -> np.ndarray:
    return masks.numpy().astype(np.uint8) * 255


def test_side_views_are_90_degrees_either_side():
    assert side_views(torch.tensor([0, 3, 20])).tolist() == [[6, 18], [9, 21], [2, 14]]


def test_silhouette_iou_of_masks_with_known_answers():
    a = torch.zeros(2, 20, 20, dtype=torch.bool)
    a[:, 0:10, 0:10] = True  # 100 pixels
    b = torch.zeros_like(a)
    b[:, 5:15, 0:10] = True  # 100 pixels, 50 shared
    assert silhouette_iou(a, a).tolist() == [1.0, 1.0]
    assert silhouette_iou(torch.zeros_like(a), a).tolist() == [0.0, 0.0]
    assert silhouette_iou(a, b).tolist() == pytest.approx([50 / 150, 50 / 150])
    assert silhouette_iou(torch.zeros_like(a), torch.zeros_like(a)).tolist() == [1.0, 1.0]  # nothing to see
    with pytest.raises(ValueError, match="differ in shape"):
        silhouette_iou(a, b[:, :10])


def test_an_exact_prediction_scores_1_and_an_empty_one_0():
    lo, hi = (-0.3, -0.2, -0.15), (0.25, 0.2, 0.3)
    sdf = box_sdf(lo, hi)
    view = torch.tensor([4])
    target = as_alpha(render_silhouettes(sdf, HALF, side_views(view)))
    assert target.any(axis=(-2, -1)).all()
    assert side_view_iou(sdf, HALF, view, target).tolist() == [1.0]
    empty = torch.ones_like(sdf)  # positive everywhere: no surface
    assert side_view_iou(empty, HALF, view, target).tolist() == [0.0]


@pytest.mark.parametrize("view", [0, 5, 13])
def test_a_pair_of_boxes_matches_their_exact_silhouettes(view):
    """The prediction a thin slab, the truth a deep box of the same outline from the input's
    axis: the side views see the difference in depth, and the score matches the IoU of the two
    boxes' exact pixel-centre silhouettes (slab tests of the camera rays) within the edge pixels."""
    truth_lo, truth_hi = (-0.3, -0.25, -0.3), (0.3, 0.25, 0.3)
    slab_lo, slab_hi = (-0.3, -0.25, -0.05), (0.3, 0.25, 0.05)
    v = torch.tensor([view])
    sides = side_views(v)
    truth = exact_silhouettes(truth_lo, truth_hi, sides)
    slab = exact_silhouettes(slab_lo, slab_hi, sides)
    hand = float(silhouette_iou(slab, truth).mean())
    assert 0.15 < hand < 0.9  # the pair differs from the side
    got = float(side_view_iou(box_sdf(slab_lo, slab_hi), HALF, v, as_alpha(truth))[0])
    assert got == pytest.approx(hand, abs=0.03)
    # The renderer's silhouette of the true box is its exact silhouette but for pixels at the
    # corners, which the sampled SDF rounds (fewer with a finer grid).
    rendered = render_silhouettes(box_sdf(truth_lo, truth_hi), HALF, sides)
    assert not (rendered & ~truth).any() and float(silhouette_iou(rendered, truth).mean()) > 0.97
