"""Regularisers of an SDF grid, shared by single-view training (svr) and multi-view reconstruction
(mvr): the paper's eikonal term ``(1 - |grad f|^2)^2`` and a Laplacian smoothness term, by finite
differences at the grid's interior vertices, averaged over a narrow band ``|SDF| <= mu * voxel``
(single view, paper section 6: mu = 1.6) or over every interior vertex (``mu=None``; multi view,
section 5). Grids are (B, N, N, N) in renderer.SDFGrid's layout (``[b, i, j, k]`` at world ``(x_i, y_j, z_k)``),
world units, on a cubic lattice of spacing ``voxel_size``. On the CPU both terms and their backward
run as one numba operation (``sdfcommon.numerics.band_kernel``); the torch path here is its specification.
"""
from __future__ import annotations

import functools
from typing import Optional

import torch

from sdfcommon.numerics import band_kernel
from sdfcommon.tooling.checks import check_positive, check_tensor


def check_grid(sdf: torch.Tensor, name: str = "sdf") -> None:
    """Refuses what is not a floating-point (B, Nx, Ny, Nz) tensor with every side >= 3 (the
    interior vertices' stencils need both neighbours), by ``check_tensor``'s rules and messages."""
    check_tensor(sdf, name, "B, Nx, Ny, Nz", at_least={"Nx": 3, "Ny": 3, "Nz": 3}, floating=True)


def narrow_band(sdf: torch.Tensor, voxel_size: float, mu: float = 1.6) -> torch.Tensor:
    """The paper's mask ``M = |SDF| <= mu * voxel_size``.

    Args:
        sdf: (B, ...) SDF samples (world units). voxel_size: grid spacing (world units).
        mu: band half-width in voxels (paper: 1.6).
    Returns:
        bool tensor of sdf's shape (no gradient).
    """
    check_positive(voxel_size, "voxel_size")
    check_positive(mu, "mu")
    return sdf.detach().abs() <= mu * voxel_size


def band_vertices(sdf: torch.Tensor, voxel_size: float, mu: Optional[float]) -> tuple[Optional[torch.Tensor], float]:
    """Flat indices (K,) into ``sdf.reshape(-1)`` of the interior vertices in the band (every
    interior vertex for ``mu=None``: a cached tensor, not to be changed in place; None when there
    is none), and the checked voxel size."""
    check_grid(sdf)
    h = check_positive(voxel_size, "voxel_size")
    b, nx, ny, nz = sdf.shape
    if mu is None:
        return _interior_vertices(tuple(sdf.shape), sdf.device), h
    idx = narrow_band(sdf[:, 1:-1, 1:-1, 1:-1], h, mu).nonzero()
    if idx.shape[0] == 0:
        return None, h
    return ((idx[:, 0] * nx + idx[:, 1] + 1) * ny + idx[:, 2] + 1) * nz + idx[:, 3] + 1, h


@functools.lru_cache(maxsize=16)
def _interior_vertices(shape: tuple[int, int, int, int], device: torch.device) -> Optional[torch.Tensor]:
    """Flat indices of every interior vertex of grids of ``shape`` (None if there is none), made
    once per shape (multi-view reconstruction asks for them at every update of a level)."""
    b, nx, ny, nz = shape
    if min(nx, ny, nz) < 3:
        return None
    i, j, k = (torch.arange(1, n - 1, device=device) for n in (nx, ny, nz))
    flat = ((i[:, None, None] * ny + j[None, :, None]) * nz + k[None, None, :]).reshape(-1)
    return (torch.arange(b, device=device)[:, None] * (nx * ny * nz) + flat[None, :]).reshape(-1)


def _band_stencil(sdf: torch.Tensor, voxel_size: float, mu: Optional[float]) -> tuple[Optional[torch.Tensor], float]:
    """The 7-point stencils of the interior vertices in the band, gathered sparsely and in one
    index operation: the band holds a few percent of a grid's vertices, so this costs far less than
    whole-grid differences, and its backward is one scatter into one zero grid (seven separate
    gathers cost seven full-grid zero fills and accumulations, more than rendering the batch).

    Returns:
        ((K, 7) values: the centre, then the neighbours at i + 1, i - 1, j + 1, j - 1, k + 1, k - 1;
        or None when the band holds no interior vertex, the checked voxel size).
    """
    base, h = band_vertices(sdf, voxel_size, mu)
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


def band_regularisers(sdf: torch.Tensor, voxel_size: float, mu: Optional[float] = 1.6,
                      fused: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """``(eikonal_loss, laplacian_loss)`` of the same grids from one band (``mu=None``: every
    interior vertex); each alone below. On the CPU with ``fused`` (and numba present) both terms
    and their backward run as one operation (``sdfcommon.numerics.band_kernel``); otherwise, and as the
    specification it is tested against, one gather of the stencils and a matrix product."""
    if fused and sdf.device.type == "cpu" and sdf.dtype in (torch.float32, torch.float64):
        if band_kernel.available():
            base, h = band_vertices(sdf, voxel_size, mu)
            if base is None:
                return _zero(sdf), _zero(sdf)
            return band_kernel.BandRegularisers.apply(sdf.contiguous(), base, h)
    st, h = _band_stencil(sdf, voxel_size, mu)
    if st is None:
        return _zero(sdf), _zero(sdf)
    d = st @ _stencil_weights(st, h)
    return _eikonal(d), _laplacian(d)


def eikonal_loss(sdf: torch.Tensor, voxel_size: float, mu: Optional[float] = 1.6) -> torch.Tensor:
    """Narrow-band eikonal loss: the mean of ``(1 - |grad f|^2)^2`` over the interior vertices in the
    band (the paper's L_reg), with central differences ``(f[i+1] - f[i-1]) / (2 voxel_size)``.

    Arguments and result as ``laplacian_loss``'s.
    """
    return _one_term(sdf, voxel_size, mu, _eikonal)


def laplacian_loss(sdf: torch.Tensor, voxel_size: float, mu: Optional[float] = 1.6) -> torch.Tensor:
    """Narrow-band Laplacian loss (the paper's L_geo): the mean over the interior vertices in the
    band of ``(voxel_size * lap f)^2``, with the 7-point Laplacian
    ``lap f = sum_axes (f[i+1] - 2 f[i] + f[i-1]) / voxel_size^2``.

    Scaling by the voxel size makes the term dimensionless (an SDF's Laplacian is its mean
    curvature, 1/length): a sphere of radius r gives about ``(2 voxel_size / r)^2``, a one-voxel
    bump a term of order one, so a weight means the same at any grid resolution.

    Args:
        sdf: (B, N, N, N) SDF (world units).
        voxel_size: spacing (world units).
        mu: band half-width in voxels; None: every interior vertex.
    Returns:
        scalar tensor; 0 when no interior vertex lies in the band.
    """
    return _one_term(sdf, voxel_size, mu, _laplacian)


def box_face_eikonal_sum(sdf: torch.Tensor, voxel_size: float) -> torch.Tensor:
    """The eikonal residual ``(1 - |grad f|^2)^2`` summed over the vertices on the grid's box faces
    (each once), with one-sided differences across the face and central ones along it (one-sided
    at its edges), as ``renderer.SDFGrid.vertex_gradient`` takes them there. With
    ``band_regularisers(mu=None)``, which covers the interior, it makes the eikonal term of every
    vertex: multi-view reconstruction needs the faces (without them the values there drift, and a
    large shape near them grows pits: docs/mvr.md).

    Args:
        sdf: (B, N, N, N), N >= 3. voxel_size: the spacing.
    Returns:
        scalar tensor (a sum: divide by the vertex count for a mean).
    """
    check_grid(sdf)
    h = float(voxel_size)

    def along(layer: torch.Tensor, dim: int) -> torch.Tensor:
        return torch.gradient(layer, spacing=(h,), dim=dim, edge_order=1)[0]

    def residual(gx: torch.Tensor, gy: torch.Tensor, gz: torch.Tensor) -> torch.Tensor:
        return ((1.0 - (gx * gx + gy * gy + gz * gz)) ** 2).sum()

    v = sdf
    total = v.new_zeros(())
    for lo in (True, False):  # x faces, whole
        layer, normal = (v[:, 0], (v[:, 1] - v[:, 0]) / h) if lo else (v[:, -1], (v[:, -1] - v[:, -2]) / h)
        total = total + residual(normal, along(layer, 1), along(layer, 2))
    for lo in (True, False):  # y faces, without the x faces' edges
        layer, normal = (v[:, :, 0], (v[:, :, 1] - v[:, :, 0]) / h) if lo else (v[:, :, -1], (v[:, :, -1] - v[:, :, -2]) / h)
        total = total + residual(along(layer, 1)[:, 1:-1], normal[:, 1:-1], along(layer, 2)[:, 1:-1])
    for lo in (True, False):  # z faces, without the x and y faces' edges
        layer, normal = (v[..., 0], (v[..., 1] - v[..., 0]) / h) if lo else (v[..., -1], (v[..., -1] - v[..., -2]) / h)
        total = total + residual(along(layer, 1)[:, 1:-1, 1:-1], along(layer, 2)[:, 1:-1, 1:-1], normal[:, 1:-1, 1:-1])
    return total


def _one_term(sdf: torch.Tensor, voxel_size: float, mu: Optional[float], term) -> torch.Tensor:
    st, h = _band_stencil(sdf, voxel_size, mu)
    return _zero(sdf) if st is None else term(st @ _stencil_weights(st, h))


__all__ = ["narrow_band", "band_vertices", "band_regularisers", "box_face_eikonal_sum", "eikonal_loss", "laplacian_loss", "check_grid"]
