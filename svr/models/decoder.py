"""SDFDecoder: latent code -> coarse SDF grid."""
from __future__ import annotations

from typing import Sequence

import torch
from torch import nn
from torch.nn import functional as F

from sdfcommon.tooling.checks import check_int, check_int_sequence, check_positive, check_shape


def sphere_template(resolution: int, half_side: float, radius: float, axis: torch.Tensor | None = None) -> torch.Tensor:
    """(N, N, N) SDF of a sphere of ``radius`` at the origin, sampled like renderer.SDFGrid over the
    box ``[-half_side, half_side]^3`` (samples on the faces, ``[i, j, k]`` at ``(x_i, y_j, z_k)``),
    or at the coordinates ``axis`` (N,) along each axis."""
    if axis is None:
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


class _Upsample2Centres(torch.autograd.Function):
    """``upsample2_centres`` with a hand-written backward: each pass writes the even and odd output
    samples into strided views of one new tensor (no concatenations or stacks), and the backward
    is the transposed passes: faster forward + backward than the same passes through autograd
    (docs/measurements.md)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor) -> torch.Tensor:  # noqa: D401 - autograd API
        for d in range(1, x.ndim):
            n = x.shape[d]
            shape = list(x.shape)
            shape[d] = 2 * n
            out = x.new_empty(shape)
            pairs = out.unflatten(d, (n, 2))
            even, odd = pairs.select(d + 1, 0), pairs.select(d + 1, 1)
            torch.mul(x, 0.75, out=even)  # even[i] = 0.75 x[i] + 0.25 x[max(i - 1, 0)]
            even.narrow(d, 1, n - 1).add_(x.narrow(d, 0, n - 1), alpha=0.25)
            even.narrow(d, 0, 1).add_(x.narrow(d, 0, 1), alpha=0.25)
            torch.mul(x, 0.75, out=odd)  # odd[i] = 0.75 x[i] + 0.25 x[min(i + 1, n - 1)]
            odd.narrow(d, 0, n - 1).add_(x.narrow(d, 1, n - 1), alpha=0.25)
            odd.narrow(d, n - 1, 1).add_(x.narrow(d, n - 1, 1), alpha=0.25)
            x = out
        return x

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> torch.Tensor:
        g = grad.contiguous()
        for d in range(g.ndim - 1, 0, -1):
            n = g.shape[d] // 2
            pairs = g.unflatten(d, (n, 2))
            even, odd = pairs.select(d + 1, 0), pairs.select(d + 1, 1)
            gi = torch.add(even, odd).mul_(0.75)
            gi.narrow(d, 0, n - 1).add_(even.narrow(d, 1, n - 1), alpha=0.25)
            gi.narrow(d, 0, 1).add_(even.narrow(d, 0, 1), alpha=0.25)
            gi.narrow(d, 1, n - 1).add_(odd.narrow(d, 0, n - 1), alpha=0.25)
            gi.narrow(d, n - 1, 1).add_(odd.narrow(d, n - 1, 1), alpha=0.25)
            g = gi
        return g


def upsample2_centres(values: torch.Tensor) -> torch.Tensor:
    """Linear 2x upsampling of (B, n, n, n) grids to (B, 2n, 2n, 2n) with cell-centred alignment
    (``F.interpolate(scale_factor=2, mode="trilinear", align_corners=False)``: edges clamped):
    along each axis output ``2i`` is ``0.75 x[i] + 0.25 x[i-1]`` and ``2i+1`` is ``0.75 x[i] +
    0.25 x[i+1]``. Three separable passes of elementwise work, so on a CPU its forward + backward is
    several times faster than ``upsample_grid``'s dense matrices or ``F.interpolate``
    (docs/measurements.md)."""
    check_shape(values, "values", "B, nx, ny, nz", at_least={"nx": 2, "ny": 2, "nz": 2})
    return _Upsample2Centres.apply(values)


UPSAMPLING = ("corners", "centres")


class SDFDecoder(nn.Module):
    """A fully connected layer to a small 3D feature grid, then transposed 3D convs that double its
    side, a head to one channel (a 3x3x3 conv, or a transposed conv that doubles the side once more)
    and, if still smaller than ``grid_resolution``, linear upsampling of that SDF.

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
        head_stride: 1: the head is a 3x3x3 conv at the last feature grid's side; 2: a transposed
            conv (kernel 4, stride 2) from the last features straight to one channel at twice the
            side (no wide feature grid at that side: several times cheaper at 32^3 on a CPU).
        upsampling: "corners" (trilinear, the end samples coinciding: ``upsample_grid``) or
            "centres" (cell-centred 2x steps, ``upsample2_centres``: faster; needs
            ``grid_resolution`` = the head's side times a power of two). With "centres" the bound
            (and the template, sampled where the head's samples sit) applies at the head's side,
            before the upsampling (which keeps it): the tanh then runs on 8x fewer values.
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
        head_stride: int = 1,
        upsampling: str = "corners",
    ) -> None:
        super().__init__()
        check_int(latent_dim, "latent_dim", minimum=1)
        if head_stride not in (1, 2):
            raise ValueError(f"head_stride must be 1 or 2, got {head_stride!r}")
        if upsampling not in UPSAMPLING:
            raise ValueError(f"upsampling must be one of {UPSAMPLING}, got {upsampling!r}")
        check_int(base_resolution, "base_resolution", minimum=1)
        check_int(grid_resolution, "grid_resolution", minimum=1)
        channels = check_int_sequence(channels, "channels", minimum=1)
        self.half_side = check_positive(half_side, "half_side")
        self.output_bound = check_positive(output_bound, "output_bound")
        if not 0 <= float(template_radius) < self.half_side:
            raise ValueError(f"template_radius must lie in [0, half_side={half_side}), got {template_radius!r}")
        side = base_resolution * 2 ** (len(channels) - 1) * head_stride
        if side > grid_resolution:
            raise ValueError(f"base_resolution * 2**(len(channels) - 1) * head_stride = {side} exceeds "
                             f"grid_resolution {grid_resolution}")
        if upsampling == "centres" and (grid_resolution % side or (grid_resolution // side) & (grid_resolution // side - 1)):
            raise ValueError(f"upsampling 'centres' needs grid_resolution ({grid_resolution}) = the head's side "
                             f"({side}) times a power of two")
        self.latent_dim = latent_dim
        self.base_resolution = base_resolution
        self.grid_resolution = grid_resolution
        self.channels = channels
        self.upsampling = upsampling

        self.fc = nn.Linear(latent_dim, channels[0] * base_resolution ** 3, bias=not batch_norm)
        self.fc_norm = nn.BatchNorm1d(channels[0] * base_resolution ** 3) if batch_norm else nn.Identity()
        blocks: list[nn.Module] = []
        for c_in, c_out in zip(channels[:-1], channels[1:]):
            blocks.append(nn.ConvTranspose3d(c_in, c_out, 4, stride=2, padding=1, bias=not batch_norm))
            if batch_norm:
                blocks.append(nn.BatchNorm3d(c_out))
            blocks.append(nn.ReLU(inplace=True))
        self.blocks = nn.Sequential(*blocks)
        if head_stride == 2:
            self.head: nn.Module = nn.ConvTranspose3d(channels[-1], 1, 4, stride=2, padding=1)
        else:
            self.head = nn.Conv3d(channels[-1], 1, 3, padding=1)
        nn.init.normal_(self.head.weight, std=1e-3)
        nn.init.zeros_(self.head.bias)
        # "corners": the template at the output samples; "centres": at the head's samples, which sit
        # where upsample2_centres puts them (output index 2j + 1/2 per doubling, in the output's units).
        t_side, t_axis = grid_resolution, None
        if upsampling == "centres":
            t_side, step = side, 2.0 * self.half_side / (grid_resolution - 1)
            factor = grid_resolution // side
            t_axis = -self.half_side + (torch.arange(side, dtype=torch.float64) * factor + (factor - 1) / 2) * step
            t_axis = t_axis.float()
        self.register_buffer(
            "template", sphere_template(t_side, self.half_side, float(template_radius), t_axis)
            if template_radius > 0 else torch.zeros(t_side, t_side, t_side), persistent=False)
        if upsampling == "corners":
            self.register_buffer("upsample", linear_upsample_matrix(side, grid_resolution), persistent=False)
        # 3D convs are faster on a CPU in channels-last layout (docs/measurements.md).
        self.to(memory_format=torch.channels_last_3d)
        # World positions (S, S, S, 3) of the head's samples, where a pixel-aligned head reads the image
        # ("corners": the end samples on the box's faces; "centres": where the template is sampled).
        h_axis = t_axis if t_axis is not None else torch.linspace(-self.half_side, self.half_side, side)
        self.register_buffer("head_points", torch.stack(torch.meshgrid(h_axis, h_axis, h_axis, indexing="ij"), -1),
                             persistent=False)

    def features(self, latent: torch.Tensor) -> torch.Tensor:
        """latent: (B, latent_dim) -> (B, C, s, s, s) the last feature grid (before the head)."""
        check_shape(latent, "latent", f"B, {self.latent_dim}")
        r = self.base_resolution
        x = F.relu(self.fc_norm(self.fc(latent)))
        x = x.view(latent.shape[0], self.channels[0], r, r, r).contiguous(memory_format=torch.channels_last_3d)
        return self.blocks(x)

    def finish(self, raw: torch.Tensor) -> torch.Tensor:
        """The head's raw output (B, S, S, S) -> the bounded SDF (B, N, N, N) (template, bound, upsampling)."""
        b = self.output_bound
        if self.upsampling == "centres":
            sdf = b * torch.tanh((self.template + raw) / b)
            while sdf.shape[-1] != self.grid_resolution:
                sdf = upsample2_centres(sdf)
            return sdf
        if raw.shape[-1] != self.grid_resolution:
            raw = upsample_grid(raw, self.upsample)
        return b * torch.tanh((self.template + raw) / b)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        """latent: (B, latent_dim) -> (B, N, N, N) SDF (world units) in renderer.SDFGrid's layout."""
        return self.finish(self.head(self.features(latent))[:, 0])
