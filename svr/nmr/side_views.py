"""How the prediction looks from the side: the silhouette IoU of a predicted SDF rendered from the
two NMR views 90 degrees either side of the input view, against those views' stored alpha. Voxel
IoU rewards a prediction that fills the input view's silhouette cone, which holds most of an
object's voxels whatever its depth; from 90 degrees away the same prediction shows its depth
profile, so a shape right only in outline (wings missing from the side, a chair as a mound) scores
low here. The NMR views are 15 degrees apart in azimuth at one elevation, so the side views of view
``v`` are ``v + 6`` and ``v - 6`` (mod 24), whose images every NMR-format split holds. Silhouettes
are binary: the prediction's is the renderer's soft silhouette (``renderer.Scene``, whose sigma
gives about an anti-aliased edge) at 0.5, the target's the stored alpha at 0.5; an image's score
is the mean IoU of its two side views, and a view where both silhouettes are empty scores 1.
"""
from __future__ import annotations

import numpy as np
import torch

import renderer
from sdfcommon.tooling.checks import check_shape
from svr.nmr.format import NUM_VIEWS
from svr.nmr.views import render_views

SIDE_VIEW_OFFSET = 6  # NMR views are 15 degrees apart: 6 views = 90 degrees
SILHOUETTE_SCENE = renderer.Scene(effects=("silhouette",))


def side_views(view: torch.Tensor) -> torch.Tensor:
    """(B,) NMR view indices -> (B, 2) the views 90 degrees to either side: ``v + 6``, ``v - 6`` (mod 24)."""
    view = torch.as_tensor(view, dtype=torch.long).reshape(-1)
    return torch.stack([(view + SIDE_VIEW_OFFSET) % NUM_VIEWS, (view - SIDE_VIEW_OFFSET) % NUM_VIEWS], dim=1)


def silhouette_iou(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """IoU of binary silhouettes over their last two dimensions (1 where both are empty).

    Args:
        pred, target: (..., H, W) bool, the same shape.
    Returns:
        (...) float64.
    """
    if pred.shape != target.shape:
        raise ValueError(f"pred and target silhouettes differ in shape: {tuple(pred.shape)} and {tuple(target.shape)}")
    pred, target = pred.bool(), target.bool()
    inter = (pred & target).flatten(-2).sum(-1).double()
    union = (pred | target).flatten(-2).sum(-1).double()
    return torch.where(union > 0, inter / union.clamp(min=1), torch.ones_like(union))


@torch.no_grad()
def render_silhouettes(sdf: torch.Tensor, half_side: float, view_ids: torch.Tensor, image_size: int = 64) -> torch.Tensor:
    """(B, N, N, N) SDF grids over ``[-half_side, half_side]^3`` seen from (B, V) NMR views ->
    (B, V, S, S) bool silhouettes on the CPU (the soft silhouette at 0.5)."""
    sil, _ = render_views(sdf, half_side, view_ids.to(sdf.device), SILHOUETTE_SCENE, image_size)
    return (sil >= 0.5).cpu()


def side_view_iou(sdf: torch.Tensor, half_side: float, view: torch.Tensor, side_alpha: np.ndarray | torch.Tensor) -> torch.Tensor:
    """Per image, the mean silhouette IoU of the prediction from its two side views.

    Args:
        sdf: (B, N, N, N) predicted SDF grids over ``[-half_side, half_side]^3`` (any device).
        view: (B,) the input views.
        side_alpha: (B, 2, S, S) the stored alpha (uint8, 0..255) of the views ``side_views(view)``,
            in that order.
    Returns:
        (B,) float64 on the CPU.
    """
    alpha = torch.as_tensor(side_alpha)
    check_shape(alpha, "side_alpha", f"{sdf.shape[0]}, 2, S, S")
    pred = render_silhouettes(sdf, half_side, side_views(view), image_size=int(alpha.shape[-1]))
    return silhouette_iou(pred, alpha >= 128).mean(dim=1)


__all__ = ["SIDE_VIEW_OFFSET", "side_views", "silhouette_iou", "render_silhouettes", "side_view_iou"]
