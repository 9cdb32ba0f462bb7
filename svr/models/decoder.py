"""SDFDecoder: latent code -> coarse SDF grid."""
from __future__ import annotations

from typing import Sequence

import torch
from torch import nn
from torch.nn import functional as F

from ._checks import check_channels, check_positive, check_positive_int


def sphere_template(resolution: int, half_side: float, radius: float) -> torch.Tensor:
    """(N, N, N) SDF of a sphere of ``radius`` at the origin, sampled like renderer.SDFGrid over the
    box ``[-half_side, half_side]^3`` (samples on the faces, ``[i, j, k]`` at ``(x_i, y_j, z_k)``)."""
    axis = torch.linspace(-half_side, half_side, resolution)
    pts = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), dim=-1)
    return pts.norm(dim=-1) - radius


def linear_upsample_matrix(n_in: int, n_out: int) -> torch.Tensor:
    """(n_out, n_in) matrix of 1D linear interpolation between grids whose first and last samples
    coincide (``align_corners=True``)."""
    pos = torch.linspace(0, n_in - 1, n_out, dtype=torch.float64)
    lo = pos.floor().long().clamp(max=n_in - 2)
    w = pos - lo
    m = torch.zeros(n_out, n_in, dtype=torch.float64)
    m[torch.arange(n_out), lo] = 1 - w
    m[torch.arange(n_out), lo + 1] += w
    return m.float()


def upsample_grid(values: torch.Tensor, matrix: torch.Tensor) -> torch.Tensor:
    """Trilinear upsampling of (B, n, n, n) grids to (B, m, m, m) as three matrix products with the
    (m, n) ``linear_upsample_matrix`` (much faster to differentiate on a CPU than
    ``F.interpolate(mode="trilinear")``, same values)."""
    x = torch.einsum("ai,bijk->bajk", matrix, values)
    x = torch.einsum("bj,iajk->iabk", matrix, x)
    return torch.einsum("ck,iabk->iabc", matrix, x)


class SDFDecoder(nn.Module):
    """A fully connected layer to a small 3D feature grid, then transposed 3D convs that double its
    side, a final conv to one channel and, if still smaller than ``grid_resolution``, trilinear
    upsampling of that SDF.

    The output is ``bound * tanh((template + raw) / bound)``: bounded (so a bad step cannot blow the
    grid up), and equal to ``template`` (a sphere SDF, or 0 with ``template_radius`` = 0) for a
    zero raw output, which the last conv starts near: the first renders already show a blob whose
    silhouette gives gradients everywhere around the object.

    Args:
        latent_dim: size of the code.
        base_resolution: side of the first 3D feature grid.
        channels: channels of the first grid, then of each doubling block; the side after them is
            ``base_resolution * 2**(len(channels) - 1)`` and must not exceed ``grid_resolution``.
        grid_resolution: N, the side of the output SDF grid.
        half_side: the grid box is ``[-half_side, half_side]^3`` (world units).
        output_bound: |SDF| < output_bound (world units).
        template_radius: radius of the initial sphere (world units); 0 for none.
        batch_norm: batch norm after the FC layer and each transposed conv.
    """

    def __init__(
        self,
        latent_dim: int = 256,
        base_resolution: int = 4,
        channels: Sequence[int] = (64, 32, 16, 8),
        grid_resolution: int = 64,
        half_side: float = 0.6,
        output_bound: float = 1.0,
        template_radius: float = 0.3,
        batch_norm: bool = True,
    ) -> None:
        super().__init__()
        check_positive_int(latent_dim, "latent_dim")
        check_positive_int(base_resolution, "base_resolution")
        check_positive_int(grid_resolution, "grid_resolution")
        channels = check_channels(channels, "channels")
        self.half_side = check_positive(half_side, "half_side")
        self.output_bound = check_positive(output_bound, "output_bound")
        if not 0 <= float(template_radius) < self.half_side:
            raise ValueError(f"template_radius must lie in [0, half_side={half_side}), got {template_radius!r}")
        side = base_resolution * 2 ** (len(channels) - 1)
        if side > grid_resolution:
            raise ValueError(
                f"base_resolution * 2**(len(channels) - 1) = {side} exceeds grid_resolution {grid_resolution}")
        self.latent_dim = latent_dim
        self.base_resolution = base_resolution
        self.grid_resolution = grid_resolution
        self.channels = channels

        self.fc = nn.Linear(latent_dim, channels[0] * base_resolution ** 3, bias=not batch_norm)
        self.fc_norm = nn.BatchNorm1d(channels[0] * base_resolution ** 3) if batch_norm else nn.Identity()
        blocks: list[nn.Module] = []
        for c_in, c_out in zip(channels[:-1], channels[1:]):
            blocks.append(nn.ConvTranspose3d(c_in, c_out, 4, stride=2, padding=1, bias=not batch_norm))
            if batch_norm:
                blocks.append(nn.BatchNorm3d(c_out))
            blocks.append(nn.ReLU(inplace=True))
        self.blocks = nn.Sequential(*blocks)
        self.head = nn.Conv3d(channels[-1], 1, 3, padding=1)
        nn.init.normal_(self.head.weight, std=1e-3)
        nn.init.zeros_(self.head.bias)
        self.register_buffer(
            "template", sphere_template(grid_resolution, self.half_side, float(template_radius))
            if template_radius > 0 else torch.zeros(grid_resolution, grid_resolution, grid_resolution),
            persistent=False)
        self.register_buffer("upsample", linear_upsample_matrix(side, grid_resolution), persistent=False)
        # 3D convs on a CPU are several times faster (backward up to ~6x) in channels-last layout.
        self.to(memory_format=torch.channels_last_3d)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        """latent: (B, latent_dim) -> (B, N, N, N) SDF (world units) in renderer.SDFGrid's layout."""
        if latent.ndim != 2 or latent.shape[1] != self.latent_dim:
            raise ValueError(f"latent must have shape (B, {self.latent_dim}), got {tuple(latent.shape)}")
        r = self.base_resolution
        x = F.relu(self.fc_norm(self.fc(latent)))
        x = x.view(latent.shape[0], self.channels[0], r, r, r).contiguous(memory_format=torch.channels_last_3d)
        x = self.blocks(x)
        raw = self.head(x)[:, 0]
        if raw.shape[-1] != self.grid_resolution:
            raw = upsample_grid(raw, self.upsample)
        b = self.output_bound
        return b * torch.tanh((self.template + raw) / b)
