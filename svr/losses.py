"""The single-view training losses (paper section 6), as pure functions.

``L = L_img + M * (lambda_1 L_eikonal + lambda_2 L_laplacian)`` with ``M`` the narrow band
``|SDF| <= mu * voxel`` (paper: lambda_1 = lambda_2 = 0.02, mu = 1.6).

* ``image_loss`` renders the predicted SDF grids from the sampled dataset views (renderer.render,
  the NMR cameras) and compares them with the dataset images: the silhouette against the alpha
  channel always, the shaded colour against RGB only when the scene asks for shading (datasets
  whose shading model is known). Which passes run follows the scene, so silhouette-only data never
  pays for shading.
* ``eikonal_loss`` and ``laplacian_loss`` are finite differences on the grid, averaged over the
  narrow band's vertices.

Grids are (B, N, N, N) in renderer.SDFGrid's layout (``[b, i, j, k]`` at world ``(x_i, y_j, z_k)``),
world units, over a cube whose sample spacing is ``voxel_size``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
from torch.nn import functional as F

import renderer

SILHOUETTE_KINDS = ("mse", "iou")


def _check_grid(sdf: torch.Tensor, name: str = "sdf") -> None:
    if not isinstance(sdf, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(sdf).__name__}")
    if sdf.ndim != 4 or min(sdf.shape[1:]) < 3:
        raise ValueError(f"{name} must have shape (B, N, N, N) with N >= 3, got {tuple(sdf.shape)}")
    if not sdf.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got {sdf.dtype}")


def _check_positive(value: float, name: str) -> float:
    v = float(value)
    if not v > 0 or v == float("inf"):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return v


# ------------------------------------------------------------------------------------------------
# Narrow-band regularisers


def narrow_band(sdf: torch.Tensor, voxel_size: float, mu: float = 1.6) -> torch.Tensor:
    """The paper's mask ``M = |SDF| <= mu * voxel_size``.

    Args:
        sdf: (B, ...) SDF samples (world units). voxel_size: grid spacing (world units).
        mu: band half-width in voxels (paper: 1.6).
    Returns:
        bool tensor of sdf's shape (no gradient).
    """
    _check_positive(voxel_size, "voxel_size")
    _check_positive(mu, "mu")
    return sdf.detach().abs() <= mu * voxel_size


def _band_vertices(sdf: torch.Tensor, voxel_size: float, mu: float) -> tuple[Optional[torch.Tensor], float]:
    """Flat indices (K,) into ``sdf.reshape(-1)`` of the interior vertices in the band (None when
    there is none), and the checked voxel size."""
    _check_grid(sdf)
    h = _check_positive(voxel_size, "voxel_size")
    b, nx, ny, nz = sdf.shape
    idx = narrow_band(sdf[:, 1:-1, 1:-1, 1:-1], h, mu).nonzero()
    if idx.shape[0] == 0:
        return None, h
    return ((idx[:, 0] * nx + idx[:, 1] + 1) * ny + idx[:, 2] + 1) * nz + idx[:, 3] + 1, h


def _band_stencil(sdf: torch.Tensor, voxel_size: float, mu: float) -> tuple[Optional[torch.Tensor], float]:
    """The 7-point stencils of the interior vertices in the band, gathered sparsely and in one
    index operation: the band holds a few percent of a grid's vertices, so this costs far less than
    whole-grid differences, and its backward is one scatter into one zero grid (seven separate
    gathers cost seven full-grid zero fills and accumulations, more than rendering the batch).

    Returns:
        ((K, 7) values: the centre, then the neighbours at i + 1, i - 1, j + 1, j - 1, k + 1, k - 1;
        or None when the band holds no interior vertex, the checked voxel size).
    """
    base, h = _band_vertices(sdf, voxel_size, mu)
    if base is None:
        return None, h
    ny, nz = sdf.shape[2], sdf.shape[3]
    offsets = torch.tensor([0, ny * nz, -ny * nz, nz, -nz, 1, -1], dtype=base.dtype, device=base.device)
    return sdf.reshape(-1)[base[:, None] + offsets], h


def _zero(sdf: torch.Tensor) -> torch.Tensor:
    """A zero still attached to the graph (backward runs and gives zero gradients)."""
    return sdf.reshape(-1)[:1].sum() * 0.0


def _stencil_weights(st: torch.Tensor, h: float) -> torch.Tensor:
    """(7, 4) weights turning a stencil row into (grad x, grad y, grad z, h * Laplacian): one
    matrix product, whose backward is another (slicing the rows' columns instead costs a zero-filled
    copy per slice in the backward)."""
    w = torch.zeros(7, 4, dtype=st.dtype, device=st.device)
    for axis in range(3):
        w[1 + 2 * axis, axis] = 1.0 / (2 * h)
        w[2 + 2 * axis, axis] = -1.0 / (2 * h)
    w[1:, 3] = 1.0 / h
    w[0, 3] = -6.0 / h
    return w


def _eikonal(d: torch.Tensor) -> torch.Tensor:
    return ((1.0 - d[:, :3].square().sum(1)) ** 2).mean()


def _laplacian(d: torch.Tensor) -> torch.Tensor:
    return d[:, 3].square().mean()


def band_regularisers(sdf: torch.Tensor, voxel_size: float, mu: float = 1.6,
                      fused: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """``(eikonal_loss, laplacian_loss)`` of the same grids from one band (what the training loss
    uses; each alone below). On the CPU with ``fused`` (and numba present) both terms and their
    backward run as one operation (``svr.band_kernel``, 2-3x faster forward + backward); otherwise,
    and as the specification it is tested against, one gather of the stencils and a matrix product."""
    if fused and sdf.device.type == "cpu" and sdf.dtype in (torch.float32, torch.float64):
        from . import band_kernel

        if band_kernel.available():
            base, h = _band_vertices(sdf, voxel_size, mu)
            if base is None:
                return _zero(sdf), _zero(sdf)
            return band_kernel.BandRegularisers.apply(sdf.contiguous(), base, h)
    st, h = _band_stencil(sdf, voxel_size, mu)
    if st is None:
        return _zero(sdf), _zero(sdf)
    d = st @ _stencil_weights(st, h)
    return _eikonal(d), _laplacian(d)


def eikonal_loss(sdf: torch.Tensor, voxel_size: float, mu: float = 1.6) -> torch.Tensor:
    """Narrow-band eikonal loss: the mean of ``(1 - |grad f|^2)^2`` over the interior vertices in the
    band (the paper's L_reg), with central differences ``(f[i+1] - f[i-1]) / (2 voxel_size)``.

    Args:
        sdf: (B, N, N, N) SDF (world units). voxel_size: spacing (world units). mu: band width in voxels.
    Returns:
        scalar tensor; 0 when no interior vertex lies in the band.
    """
    st, h = _band_stencil(sdf, voxel_size, mu)
    return _zero(sdf) if st is None else _eikonal(st @ _stencil_weights(st, h))


def laplacian_loss(sdf: torch.Tensor, voxel_size: float, mu: float = 1.6) -> torch.Tensor:
    """Narrow-band Laplacian loss (the paper's L_geo): the mean over the interior vertices in the
    band of ``(voxel_size * lap f)^2``, with the 7-point Laplacian
    ``lap f = sum_axes (f[i+1] - 2 f[i] + f[i-1]) / voxel_size^2``.

    Scaling by the voxel size makes the term dimensionless (an SDF's Laplacian is its mean
    curvature, 1/length): a sphere of radius r gives about ``(2 voxel_size / r)^2``, a one-voxel
    bump a term of order one, so a weight means the same at any grid resolution.

    Args:
        sdf: (B, N, N, N) SDF (world units). voxel_size: spacing (world units). mu: band width in voxels.
    Returns:
        scalar tensor; 0 when no interior vertex lies in the band.
    """
    st, h = _band_stencil(sdf, voxel_size, mu)
    return _zero(sdf) if st is None else _laplacian(st @ _stencil_weights(st, h))


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
    if images.ndim != 5 or images.shape[-1] != images.shape[-2]:
        raise ValueError(f"images must have shape (B, V, C, H, H), got {tuple(images.shape)}")
    h = images.shape[-1]
    if isinstance(size, bool) or not isinstance(size, int) or size <= 0 or h % size:
        raise ValueError(f"size must be a positive divisor of the image side {h}, got {size!r}")
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


def render_views(
    sdf: torch.Tensor,
    half_side: float,
    view_ids: torch.Tensor,
    scene: renderer.Scene,
    image_size: int = 64,
    trace_settings: renderer.TraceSettings = renderer.TraceSettings(),
    backend: str = "auto",
) -> tuple[torch.Tensor, Optional[torch.Tensor]]:
    """Renders each of B SDF grids from its V NMR views.

    Args:
        sdf: (B, N, N, N) SDF over ``[-half_side, half_side]^3`` (world units).
        view_ids: (B, V) NMR view indices (``renderer.Cameras.nmr``).
        scene: renderer.Scene (its effects decide which passes run).
        image_size: render side H = W.
    Returns:
        silhouettes (B, V, H, W) and colours (B, V, C, H, W) (None unless the scene shades).
    """
    _check_grid(sdf)
    if view_ids.ndim != 2 or view_ids.shape[0] != sdf.shape[0]:
        raise ValueError(f"view_ids must have shape (B={sdf.shape[0]}, V), got {tuple(view_ids.shape)}")
    if not scene.wants("silhouette"):
        raise ValueError(f"scene.effects must include 'silhouette', got {scene.effects}")
    b, v = view_ids.shape
    grid = renderer.SDFGrid(sdf, -float(half_side), float(half_side))
    cams = renderer.Cameras.nmr(view_ids.reshape(-1).cpu(), image_size=image_size, dtype=sdf.dtype,
                                device=sdf.device)
    out = renderer.render(grid, cams, scene, trace_settings, backend)
    sil = out.silhouette.reshape(b, v, image_size, image_size)
    colours = None
    if out.image is not None:
        colours = out.image.reshape(b, v, image_size, image_size, -1).permute(0, 1, 4, 2, 3)
    return sil, colours


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
        view_ids: (B, V) the NMR view of each image.
        scene: what to render; with "shading" in its effects the RGB is compared too.
        render_size: render side; the images are area-downsampled to it (a divisor of H).
        silhouette_kind: see ``silhouette_loss``.
    Returns:
        ImageLoss.
    """
    if images.ndim != 5 or images.shape[2] != 4:
        raise ValueError(f"images must have shape (B, V, 4, H, W), got {tuple(images.shape)}")
    if images.shape[:2] != view_ids.shape:
        raise ValueError(f"images {tuple(images.shape[:2])} and view_ids {tuple(view_ids.shape)} "
                         f"must agree on (B, V)")
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
# The total


@dataclass(frozen=True)
class LossWeights:
    """Weights of the single-view loss (built from configs/loss/*.yaml).

    Attributes:
        silhouette: weight of the silhouette term.
        shading: weight of the colour term (used only where the dataset's shading model is known).
        eikonal: lambda_1 (paper 0.02). laplacian: lambda_2 (paper 0.02).
        band_mu: narrow band half-width in voxels (paper 1.6).
        silhouette_kind: "mse" (paper: L2) or "iou".
    """

    silhouette: float = 1.0
    shading: float = 1.0
    eikonal: float = 0.02
    laplacian: float = 0.02
    band_mu: float = 1.6
    silhouette_kind: str = "mse"

    def __post_init__(self) -> None:
        for name in ("silhouette", "shading", "eikonal", "laplacian"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v >= 0 and v != float("inf")):
                raise ValueError(f"loss weight {name} must be a finite number >= 0, got {v!r}")
        _check_positive(self.band_mu, "band_mu")
        if self.silhouette_kind not in SILHOUETTE_KINDS:
            raise ValueError(f"silhouette_kind must be one of {SILHOUETTE_KINDS}, got {self.silhouette_kind!r}")


@dataclass(frozen=True)
class LossTerms:
    """The weighted total and its (unweighted) parts, all scalar tensors (shading None if unused)."""

    total: torch.Tensor
    silhouette: torch.Tensor
    shading: Optional[torch.Tensor]
    eikonal: torch.Tensor
    laplacian: torch.Tensor

    def as_dict(self) -> dict[str, torch.Tensor]:
        d = {"total": self.total, "silhouette": self.silhouette, "eikonal": self.eikonal,
             "laplacian": self.laplacian}
        if self.shading is not None:
            d["shading"] = self.shading
        return d


def total_loss(image: ImageLoss, sdf: torch.Tensor, voxel_size: float, weights: LossWeights) -> LossTerms:
    """``w_s L_sil + w_c L_shade + w_e L_eikonal + w_l L_laplacian`` (the last two in the band).

    Args:
        image: the image terms of ``sdf`` (``image_loss``).
        sdf: (B, N, N, N) the same predicted grids. voxel_size: their spacing.
        weights: LossWeights.
    Returns:
        LossTerms.
    """
    eik, lap = band_regularisers(sdf, voxel_size, weights.band_mu)
    total = weights.silhouette * image.silhouette + weights.eikonal * eik + weights.laplacian * lap
    if image.shading is not None:
        total = total + weights.shading * image.shading
    return LossTerms(total=total, silhouette=image.silhouette, shading=image.shading, eikonal=eik, laplacian=lap)


__all__ = [
    "narrow_band", "band_regularisers", "eikonal_loss", "laplacian_loss", "silhouette_loss", "shading_loss", "resize_images",
    "render_views", "image_loss", "ImageLoss", "LossWeights", "LossTerms", "total_loss", "SILHOUETTE_KINDS",
]
