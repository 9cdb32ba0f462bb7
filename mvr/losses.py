"""The data terms of multi-view reconstruction (paper section 5.1), as pure functions; the eikonal
and Laplacian regularisers are shared with single-view training
(``sdfcommon.numerics.regularisers``). Every term is a mean (over pixels; the regularisers over grid
vertices), so that their balance does not change with the image or grid resolution; the paper's
sums differ from them by constant factors that the weights absorb.
"""
from __future__ import annotations

import torch
from torch.nn import functional as F


IMAGE_LOSSES = ("l2", "l1")


def view_image_losses(rendered: torch.Tensor, target: torch.Tensor, kind: str = "l2", levels: int = 1) -> torch.Tensor:
    """Each view's image loss, as a mean over its pixels and channels: the paper's L2 (``kind="l2"``)
    or L1 (the authors' code's); with ``levels`` > 1 the mean of the loss over an image pyramid (the
    images and their 2x2, 4x4, ... box means), which compares blurred images too, so that an error
    also pulls on surface a few pixels away.

    Args:
        rendered, target: (V, H, W, C) float images (the same shape).
    Returns:
        (V,) per-view losses.
    """
    if rendered.shape != target.shape or rendered.ndim != 4:
        raise ValueError(f"rendered {tuple(rendered.shape)} and target {tuple(target.shape)} must both be "
                         f"(V, H, W, C)")
    if kind not in IMAGE_LOSSES:
        raise ValueError(f"image loss must be one of {IMAGE_LOSSES}, got {kind!r}")
    diff = (rendered - target.to(rendered.dtype)).permute(0, 3, 1, 2)  # (V, C, H, W)
    total = diff.new_zeros(diff.shape[0])
    for level in range(levels):
        if level > 0:
            if min(diff.shape[-2:]) < 2:
                raise ValueError(f"{levels} pyramid levels need images of at least {2 ** (levels - 1)} pixels, "
                                 f"got {tuple(rendered.shape[1:3])}")
            diff = F.avg_pool2d(diff, 2, ceil_mode=True)
        total = total + (diff.abs() if kind == "l1" else diff.square()).mean(dim=(1, 2, 3))
    return total / levels


def view_silhouette_losses(silhouette: torch.Tensor, target: torch.Tensor, tolerance: float = 0.0) -> torch.Tensor:
    """Mean squared difference, per view, between soft silhouettes (V, H, W) in [0, 1] and target
    coverage (V, H, W) (a float mask, possibly noisy), less a dead zone: a pixel within ``tolerance``
    of its target costs nothing (0: the plain squared difference). Returns (V,). Not in the paper:
    it gives the grid gradients where rays miss the surface.

    With a tolerance a ray that hits a thin part well enough (coverage ``1 - tolerance``) is no
    longer pulled further in: the plain difference asks for full coverage, which a part a pixel
    wide reaches only by growing (docs/mvr_method.md, "A silhouette term with a dead zone").
    """
    if silhouette.shape != target.shape or silhouette.ndim != 3:
        raise ValueError(f"silhouette {tuple(silhouette.shape)} and target {tuple(target.shape)} must both be "
                         f"(V, H, W)")
    if not 0 <= tolerance < 0.5:
        raise ValueError(f"silhouette tolerance must be in [0, 0.5), got {tolerance!r}")
    target = target.to(silhouette.dtype)
    diff = silhouette - target
    if tolerance > 0:
        diff = diff - diff.clamp(-tolerance, tolerance)
    return (diff ** 2).mean(dim=(1, 2))
