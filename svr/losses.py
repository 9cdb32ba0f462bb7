"""The single-view training losses (paper section 6), as pure functions:
``L = L_img + M * (lambda_1 L_eikonal + lambda_2 L_laplacian)`` with ``M`` the narrow band
``|SDF| <= mu * voxel`` (paper: lambda_1 = lambda_2 = 0.02, mu = 1.6). ``image_loss`` renders the
predicted SDF grids from the sampled dataset views (``renderer.render``, the NMR cameras) and
compares them with the dataset images: the silhouette against the alpha channel always, the
shaded colour against RGB only when the scene asks for shading (datasets whose shading model is
known); which passes run follows the scene, so silhouette-only data never pays for shading.
``hull_loss`` holds the prediction inside the cones of rays through its supervised views'
silhouettes (their visual hull), so that what those views show as background is empty inside the
shape too, not only at its outline. ``voxel_loss`` is 3D supervision by the dataset's training
voxels (a diagnostic of what the network can read from one image; the paper's recipe leaves its
weight at 0 and renders only).
``eikonal_loss`` and ``laplacian_loss`` (``sdfcommon.numerics.regularisers``, shared with mvr) are
finite differences on the grid, averaged over the narrow band's vertices. Grids are (B, N, N, N)
in renderer.SDFGrid's layout (``[b, i, j, k]`` at world ``(x_i, y_j, z_k)``), in world units, over
a cube whose sample spacing is ``voxel_size``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch
from torch.nn import functional as F

import renderer
from sdfcommon.numerics.regularisers import band_regularisers, eikonal_loss, laplacian_loss, narrow_band
from sdfcommon.tooling.checks import check_float, check_int, check_positive, check_shape

from svr.nmr.cones import silhouette_cone_sdf
from svr.nmr.metrics import PROTOCOL_LIKE_LEVEL
from svr.nmr.views import render_views
from svr.nmr.voxels import sdf_at_voxel_centres

SILHOUETTE_KINDS = ("mse", "iou")
VOXEL_KINDS = ("iou", "distance", "bce")


# ------------------------------------------------------------------------------------------------
# Image losses


def silhouette_loss(pred: torch.Tensor, target: torch.Tensor, kind: str = "mse") -> torch.Tensor:
    """Silhouette loss between rendered coverage and the dataset's alpha.

    Args:
        pred, target: (..., H, W) in [0, 1].
        kind: "mse" (the paper's L2, mean over pixels) or "iou" (``1 - soft IoU`` per image, averaged;
            insensitive to how much of the image the object fills).
    Returns:
        scalar tensor.
    """
    if pred.shape != target.shape:
        raise ValueError(f"pred {tuple(pred.shape)} and target {tuple(target.shape)} must have the same shape")
    if kind == "mse":
        return F.mse_loss(pred, target)
    if kind == "iou":
        p = pred.flatten(-2)
        t = target.flatten(-2)
        inter = (p * t).sum(-1)
        union = (p + t - p * t).sum(-1)
        return (1.0 - inter / union.clamp(min=1e-6)).mean()
    raise ValueError(f"kind must be one of {SILHOUETTE_KINDS}, got {kind!r}")


def shading_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The paper's L2 image loss on colour: mean squared difference.

    Args:
        pred, target: (..., C, H, W) colours in [0, 1] (same background).
    Returns:
        scalar tensor.
    """
    if pred.shape != target.shape:
        raise ValueError(f"pred {tuple(pred.shape)} and target {tuple(target.shape)} must have the same shape")
    return F.mse_loss(pred, target)


def resize_images(images: torch.Tensor, size: int) -> torch.Tensor:
    """Area-averaged downsampling of dataset images (the alpha of an anti-aliased image stays the
    pixel coverage).

    Args:
        images: (B, V, C, H, W) in [0, 1]. size: target side; H must be a multiple of it.
    Returns:
        (B, V, C, size, size).
    """
    h = check_shape(images, "images", "B, V, C, H, H")["H"]
    if check_int(size, "size", minimum=1) and h % size:
        raise ValueError(f"size must be a divisor of the image side {h}, got {size!r}")
    if size == h:
        return images
    b, v, c = images.shape[:3]
    return F.avg_pool2d(images.reshape(b * v, c, h, h), h // size).reshape(b, v, c, size, size)


@dataclass(frozen=True)
class ImageLoss:
    """Image loss terms and the renders they came from.

    Attributes:
        silhouette: scalar silhouette loss.
        shading: scalar colour loss, or None when the scene renders no shading.
        silhouettes: (B, V, H, W) rendered soft silhouettes.
        colours: (B, V, C, H, W) rendered colours, or None.
        target: (B, V, 4, H, W) the dataset images at the render size.
    """

    silhouette: torch.Tensor
    shading: Optional[torch.Tensor]
    silhouettes: torch.Tensor
    colours: Optional[torch.Tensor]
    target: torch.Tensor


def image_loss(
    sdf: torch.Tensor,
    half_side: float,
    images: torch.Tensor,
    view_ids: torch.Tensor,
    scene: renderer.Scene,
    render_size: int = 64,
    silhouette_kind: str = "mse",
    trace_settings: renderer.TraceSettings = renderer.TraceSettings(),
    backend: str = "auto",
) -> ImageLoss:
    """Renders the predicted grids from the sampled views and compares them with the images.

    Args:
        sdf: (B, N, N, N) predicted SDF over ``[-half_side, half_side]^3``.
        images: (B, V, 4, H, W) dataset RGBA in [0, 1] (RGB on the scene's background).
        view_ids: (B, V) the NMR view of each image, or (B, V, 2) rows of (view, elevation in degrees)
            (``svr.data.types.SVRBatch.views``).
        scene: what to render; with "shading" in its effects the RGB is compared too.
        render_size: render side; the images are area-downsampled to it (a divisor of H).
        silhouette_kind: see ``silhouette_loss``.
    Returns:
        ImageLoss.
    """
    check_shape(images, "images", "B, V, 4, H, W")
    if images.shape[:2] != view_ids.shape[:2]:
        raise ValueError(f"images {tuple(images.shape[:2])} and view_ids {tuple(view_ids.shape)} "
                         f"must agree on (B, V)")
    if not scene.wants("silhouette"):
        raise ValueError(f"scene.effects must include 'silhouette', got {scene.effects}")
    target = resize_images(images.to(sdf.dtype), render_size)
    sil, colours = render_views(sdf, half_side, view_ids, scene, render_size, trace_settings, backend)
    l_sil = silhouette_loss(sil, target[:, :, 3], silhouette_kind)
    l_shade = None
    if colours is not None:
        if colours.shape[2] != 3:
            raise ValueError(f"the scene renders {colours.shape[2]} colour channels; the images have 3")
        l_shade = shading_loss(colours, target[:, :, :3])
    return ImageLoss(silhouette=l_sil, shading=l_shade, silhouettes=sil, colours=colours, target=target)


# ------------------------------------------------------------------------------------------------
# 3D supervision


def voxel_distances(voxels: torch.Tensor, truncation: float = 3.0) -> torch.Tensor:
    """Signed distances at the voxel centres, in voxels, from solid voxels alone: an empty centre's
    distance to the nearest solid centre minus 1/2, a solid centre's distance to the nearest empty
    one minus 1/2, negated (so the zero level lies half-way between neighbours that differ),
    truncated to ``[-truncation, truncation]``.

    Args:
        voxels: (B, R, R, R) bool.
    Returns:
        (B, R, R, R) float32 on voxels' device.
    """
    from scipy import ndimage  # only the 3D-supervised loss needs it

    v = voxels.detach().cpu().numpy().astype(bool)
    out = np.full(v.shape, truncation, dtype=np.float32)
    for b in range(len(v)):
        if v[b].all():
            out[b] = -truncation
        elif v[b].any():
            out[b] = np.where(v[b], 0.5 - ndimage.distance_transform_edt(v[b]),
                              ndimage.distance_transform_edt(~v[b]) - 0.5)
    return torch.from_numpy(np.clip(out, -truncation, truncation)).to(voxels.device)


def hull_loss(sdf: torch.Tensor, half_side: float, alpha: torch.Tensor, view_ids: torch.Tensor,
              margin: float = 2.0, tolerance: float = 1.0, stride: int = 2) -> torch.Tensor:
    """How far each predicted shape leaves the visual hull of its supervised views, in voxels.

    Why: the soft silhouette's gradient reaches only the samples near each ray's closest approach
    to the surface; this term reaches every sample the views show as background. On the demo with
    the shape prior it raised the test IoU by 0.014 and 0.007 (two seeds) and the side views by
    0.010, and the calibration's level fell from 1.25 to 0.75 voxels (docs/training_recipe.md); the
    demo uses it. A shape seen with a silhouette lies inside that view's cone of rays, whose field
    (``silhouette_cone_sdf``) therefore bounds its signed distance from below, ``sdf >= cone``,
    everywhere; the largest of the V views' cones
    (their visual hull) is the tightest such bound. The loss is the mean over the grid samples of
    ``max(0, min(hull, margin) - tolerance - sdf)``: every sample the views show as background by
    more than the tolerance is pushed out of the shape at once; nothing is asked of the field
    farther out than ``margin`` voxels, which the image terms never see, nor within the tolerance
    of the hull, which the silhouettes' pixels (about a voxel at the object) do not resolve. Only
    images and their cameras are read.

    Args:
        sdf: (B, N, N, N) predicted SDF over ``[-half_side, half_side]^3``.
        alpha: (B, V, S, S) the supervised views' alpha; view_ids: (B, V) their NMR view indices,
            or (B, V, 2) rows of (view, elevation in degrees).
        margin, tolerance: in voxels (the grid's spacing).
        stride: the bound is checked at every ``stride``-th sample along each axis (2: an eighth
            of the samples; at the demo's 16 objects x 8 views, about 70 ms forward and backward
            on 2 CPU cores, 40% of it the pixel distance transforms).
    Returns:
        scalar tensor (voxels).
    """
    check_int(stride, "stride", minimum=1)
    check_positive(margin, "margin")
    check_float(tolerance, "tolerance", minimum=0)
    b, v = check_shape(alpha, "alpha", "B, V, S, S")["B"], alpha.shape[1]
    check_shape(view_ids, "view_ids", f"{b}, {v}" if view_ids.ndim < 3 else f"{b}, {v}, 2")
    if sdf.shape[0] != b:
        raise ValueError(f"alpha has {b} objects but sdf has {sdf.shape[0]}")
    n = sdf.shape[-1]
    voxel = 2.0 * float(half_side) / (n - 1)
    cones = silhouette_cone_sdf(alpha.reshape(b * v, *alpha.shape[2:]), view_ids.reshape(b * v, *view_ids.shape[2:]),
                                n, float(half_side), stride=stride)
    hull = cones.reshape(b, v, -1).amax(dim=1).clamp(max=margin * voxel).to(sdf)
    samples = sdf[:, ::stride, ::stride, ::stride].reshape(b, -1)
    return (hull - tolerance * voxel - samples).clamp(min=0).mean() / voxel


def voxel_loss(sdf: torch.Tensor, half_side: float, voxels: torch.Tensor, kind: str = "iou",
               level: float = PROTOCOL_LIKE_LEVEL, softness: float = 0.5 / 31, truncation: float = 3.0) -> torch.Tensor:
    """3D supervision by the dataset's voxels, from the predicted SDF at the NMR voxel centres
    shifted by ``level`` (the offset at which an SDF's direct voxels best match the benchmark
    protocol's fatter ones).

    Args:
        sdf: (B, N, N, N) predicted SDF over ``[-half_side, half_side]^3``.
        voxels: (B, R, R, R) bool solid voxels in the NMR frame.
        kind: with the occupancy ``sigmoid((level - sdf) / softness)`` at the centres: "iou":
            ``1 - soft IoU`` of it with the voxels per object, averaged over the objects (each
            object counts alike whatever its volume, as the benchmark's per-image IoU does: the
            3D counterpart of the silhouette loss's "iou"); "bce": its binary cross-entropy
            against the voxels, the mean over voxels. "distance": the mean absolute difference, in
            voxels, between the shifted SDF and ``voxel_distances`` of the voxels, where a
            prediction past the truncation on the target's own side costs nothing but one on the
            other side keeps its gradient (clamping both sides would leave a wrong prediction
            more than ``truncation`` deep, e.g. the inside of the initial sphere where the object
            is thin, with no gradient at all).
        level, softness: world units (default: 0.55 and 0.5 of the voxel, 1 / (R - 1)).
        truncation: in voxels ("distance").
    Returns:
        scalar tensor.
    """
    r = check_shape(voxels, "voxels", "B, R, R, R")["R"]
    check_positive(softness, "softness")
    if voxels.shape[0] != sdf.shape[0]:
        raise ValueError(f"voxels has {voxels.shape[0]} grids but sdf has {sdf.shape[0]}")
    if kind not in VOXEL_KINDS:
        raise ValueError(f"kind must be one of {VOXEL_KINDS}, got {kind!r}")
    at, _ = sdf_at_voxel_centres(sdf, -half_side, half_side, r)
    target = voxels.to(at.dtype)
    if kind == "bce":
        return F.binary_cross_entropy_with_logits((level - at) / softness, target)
    if kind == "iou":
        occ = torch.sigmoid((level - at) / softness).flatten(1)
        t = target.flatten(1)
        inter = (occ * t).sum(1)
        union = (occ + t - occ * t).sum(1)
        return (1.0 - inter / union.clamp(min=1e-6)).mean()
    t = voxel_distances(voxels, truncation).to(at.dtype)
    pred = (at - level) * (r - 1)
    pred = torch.where(t >= truncation, pred.clamp(max=truncation),
                       torch.where(t <= -truncation, pred.clamp(min=-truncation), pred))
    return (pred - t).abs().mean()


# ------------------------------------------------------------------------------------------------
# The total


@dataclass(frozen=True)
class LossWeights:
    """Weights of the single-view loss (built from configs/loss/*.yaml).

    Attributes:
        silhouette: weight of the silhouette term.
        shading: weight of the colour term (used only where the dataset's shading model is known).
        voxel: weight of the 3D term (``voxel_loss``; 0 in the paper's recipe). With the silhouette
            and shading weights 0 nothing is rendered.
        eikonal: lambda_1 (paper 0.02). laplacian: lambda_2 (paper 0.02).
        band_mu: narrow band half-width in voxels (paper 1.6).
        silhouette_kind: "mse" (paper: L2) or "iou".
        voxel_kind: the 3D term's form (``voxel_loss``'s ``kind``).
        hull: weight of ``hull_loss`` (0: the paper's recipe); hull_margin, hull_tolerance: its
            margin and tolerance in voxels; hull_stride: its ``stride``.
    """

    silhouette: float = 1.0
    shading: float = 1.0
    voxel: float = 0.0
    eikonal: float = 0.02
    laplacian: float = 0.02
    band_mu: float = 1.6
    silhouette_kind: str = "mse"
    voxel_kind: str = "iou"
    hull: float = 0.0
    hull_margin: float = 2.0
    hull_tolerance: float = 1.0
    hull_stride: int = 2

    def __post_init__(self) -> None:
        for name in ("silhouette", "shading", "voxel", "eikonal", "laplacian", "hull"):
            check_float(getattr(self, name), f"loss weight {name}", minimum=0)
        check_positive(self.band_mu, "band_mu")
        check_positive(self.hull_margin, "hull_margin")
        check_float(self.hull_tolerance, "hull_tolerance", minimum=0)
        check_int(self.hull_stride, "hull_stride", minimum=1)
        if self.silhouette_kind not in SILHOUETTE_KINDS:
            raise ValueError(f"silhouette_kind must be one of {SILHOUETTE_KINDS}, got {self.silhouette_kind!r}")
        if self.voxel_kind not in VOXEL_KINDS:
            raise ValueError(f"voxel_kind must be one of {VOXEL_KINDS}, got {self.voxel_kind!r}")
        if self.silhouette == 0 and self.shading == 0 and self.voxel == 0:
            raise ValueError("the silhouette, shading and voxel loss weights are all 0: nothing supervises the shape")

    def renders(self, shading: bool) -> bool:
        """Whether the loss needs renders (a non-zero image term; ``shading``: the scene shades)."""
        return self.silhouette > 0 or (shading and self.shading > 0)


@dataclass(frozen=True)
class LossTerms:
    """The weighted total and its (unweighted) parts, all scalar tensors (None where not computed:
    the image terms when nothing is rendered, shading when the scene does not shade, voxel and hull
    when their weight is 0)."""

    total: torch.Tensor
    silhouette: Optional[torch.Tensor]
    shading: Optional[torch.Tensor]
    eikonal: torch.Tensor
    laplacian: torch.Tensor
    voxel: Optional[torch.Tensor] = None
    hull: Optional[torch.Tensor] = None

    def as_dict(self) -> dict[str, torch.Tensor]:
        d = {"total": self.total, "silhouette": self.silhouette, "shading": self.shading, "voxel": self.voxel,
             "hull": self.hull, "eikonal": self.eikonal, "laplacian": self.laplacian}
        return {k: v for k, v in d.items() if v is not None}


def total_loss(image: Optional[ImageLoss], sdf: torch.Tensor, voxel_size: float, weights: LossWeights,
               voxel: Optional[torch.Tensor] = None, hull: Optional[torch.Tensor] = None) -> LossTerms:
    """``w_s L_sil + w_c L_shade + w_v L_voxel + w_h L_hull + w_e L_eikonal + w_l L_laplacian`` (the
    regularisers in the band).

    Args:
        image: the image terms of ``sdf`` (``image_loss``), or None where nothing was rendered.
        sdf: (B, N, N, N) the same predicted grids. voxel_size: their spacing.
        weights: LossWeights.
        voxel: ``voxel_loss`` of ``sdf``, needed when ``weights.voxel`` is not 0.
        hull: ``hull_loss`` of ``sdf``, needed when ``weights.hull`` is not 0.
    Returns:
        LossTerms.
    """
    if weights.renders(image is not None and image.shading is not None) and image is None:
        raise ValueError("the loss weights ask for image terms but image is None")
    if weights.voxel > 0 and voxel is None:
        raise ValueError(f"loss weight voxel is {weights.voxel} but voxel is None")
    if weights.hull > 0 and hull is None:
        raise ValueError(f"loss weight hull is {weights.hull} but hull is None")
    eik, lap = band_regularisers(sdf, voxel_size, weights.band_mu)
    total = weights.eikonal * eik + weights.laplacian * lap
    if image is not None:
        total = total + weights.silhouette * image.silhouette
        if image.shading is not None:
            total = total + weights.shading * image.shading
    if weights.voxel > 0:
        total = total + weights.voxel * voxel
    if weights.hull > 0:
        total = total + weights.hull * hull
    return LossTerms(total=total, silhouette=image.silhouette if image is not None else None,
                     shading=image.shading if image is not None else None, eikonal=eik, laplacian=lap,
                     voxel=voxel if weights.voxel > 0 else None, hull=hull if weights.hull > 0 else None)


__all__ = [
    "narrow_band", "band_regularisers", "eikonal_loss", "laplacian_loss", "silhouette_loss", "shading_loss", "resize_images",
    "image_loss", "ImageLoss", "hull_loss", "voxel_loss", "voxel_distances", "LossWeights", "LossTerms", "total_loss",
    "SILHOUETTE_KINDS", "VOXEL_KINDS",
]
