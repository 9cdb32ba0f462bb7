"""The energy of multi-view reconstruction (paper section 5.1): pure functions.

All terms are means (over pixels, or over grid vertices), so their balance does not change with the
image or grid resolution; the paper's sums differ from them by constant factors that the weights
absorb.
"""
from __future__ import annotations

import torch

from renderer import SDFGrid


def image_loss(rendered: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
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


def silhouette_loss(silhouette: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared difference, per view, between soft silhouettes (V, H, W) in [0, 1] and target
    coverage (V, H, W) (a float mask, possibly noisy). Returns (V,). Not in the paper: it gives the
    grid gradients where rays miss the surface."""
    if silhouette.shape != target.shape or silhouette.ndim != 3:
        raise ValueError(f"silhouette {tuple(silhouette.shape)} and target {tuple(target.shape)} must both be "
                         f"(V, H, W)")
    return ((silhouette - target.to(silhouette.dtype)) ** 2).mean(dim=(1, 2))


def eikonal_loss(grid: SDFGrid) -> torch.Tensor:
    """The paper's regulariser ``(1 - |grad f|^2)^2``, with central finite differences at every grid
    vertex (one-sided on the box faces), averaged over the vertices. Returns a scalar."""
    g = grid.vertex_gradient()
    return ((1.0 - (g * g).sum(-1)) ** 2).mean()


def laplacian_loss(grid: SDFGrid) -> torch.Tensor:
    """Mean squared discrete Laplacian over the interior vertices, in units of one voxel:
    ``(sum of the 6 neighbours - 6 f) / h`` (about ``h`` times the Laplacian, so it fades as the grid
    refines). The authors' code adds such a smoothness term; the paper does not mention it."""
    v = grid.values
    if min(v.shape[1:]) < 3:
        return v.new_zeros(())
    h = grid.voxel_size.to(v.dtype)
    centre = v[:, 1:-1, 1:-1, 1:-1]
    lap = ((v[:, 2:, 1:-1, 1:-1] + v[:, :-2, 1:-1, 1:-1] - 2 * centre) / h[0]
           + (v[:, 1:-1, 2:, 1:-1] + v[:, 1:-1, :-2, 1:-1] - 2 * centre) / h[1]
           + (v[:, 1:-1, 1:-1, 2:] + v[:, 1:-1, 1:-1, :-2] - 2 * centre) / h[2])
    return (lap**2).mean()
