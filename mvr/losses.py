"""The data terms of multi-view reconstruction (paper section 5.1), as pure functions; the eikonal
and Laplacian regularisers are shared with single-view training
(``sdfcommon.numerics.regularisers``). Every term is a mean (over pixels; the regularisers over grid
vertices), so that their balance does not change with the image or grid resolution; the paper's
sums differ from them by constant factors that the weights absorb.
"""
from __future__ import annotations

import torch


def view_image_losses(rendered: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The paper's L2 image loss of each view, as a mean over its pixels and channels.

    Args:
        rendered, target: (V, H, W, C) float images (the same shape).
    Returns:
        (V,) per-view losses.
    """
    if rendered.shape != target.shape or rendered.ndim != 4:
        raise ValueError(f"rendered {tuple(rendered.shape)} and target {tuple(target.shape)} must both be "
                         f"(V, H, W, C)")
    return ((rendered - target.to(rendered.dtype)) ** 2).mean(dim=(1, 2, 3))


def view_silhouette_losses(silhouette: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared difference, per view, between soft silhouettes (V, H, W) in [0, 1] and target
    coverage (V, H, W) (a float mask, possibly noisy). Returns (V,). Not in the paper: it gives the
    grid gradients where rays miss the surface."""
    if silhouette.shape != target.shape or silhouette.ndim != 3:
        raise ValueError(f"silhouette {tuple(silhouette.shape)} and target {tuple(target.shape)} must both be "
                         f"(V, H, W)")
    return ((silhouette - target.to(silhouette.dtype)) ** 2).mean(dim=(1, 2))
