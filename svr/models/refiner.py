"""Refiners: coarse SDF grid -> refined SDF grid (3D conv encoder-decoders with skip connections);
SDFRefiner works at the grid's side (or half of it); BlockRefiner at a quarter of it (the default).
"""
from __future__ import annotations

from typing import Sequence

import torch
from torch import nn
from torch.nn import functional as F

from sdfcommon.tooling.checks import check_int, check_int_sequence, check_positive, check_shape
from svr.models.decoder import upsample2_centres


def _conv_block(c_in: int, c_out: int, batch_norm: bool, **conv) -> list[nn.Module]:
    layers: list[nn.Module] = [nn.Conv3d(c_in, c_out, bias=not batch_norm, **conv)]
    if batch_norm:
        layers.append(nn.BatchNorm3d(c_out))
    layers.append(nn.ReLU(inplace=True))
    return layers


def _down_path(c_in: int, channels: Sequence[int], batch_norm: bool, convs_per_level: int,
               first_conv) -> nn.ModuleList:
    """The U-Net's way down: per level a conv (``first_conv(i)``: its kernel, stride and padding)
    then ``convs_per_level - 1`` 3x3x3 convs, each with batch norm and ReLU."""
    down = nn.ModuleList()
    for i, c in enumerate(channels):
        layers = _conv_block(c_in, c, batch_norm, **first_conv(i))
        for _ in range(convs_per_level - 1):
            layers += _conv_block(c, c, batch_norm, kernel_size=3, padding=1)
        down.append(nn.Sequential(*layers))
        c_in = c
    return down


def _up_path(channels: Sequence[int], batch_norm: bool, **up_conv) -> tuple[nn.ModuleList, nn.ModuleList]:
    """The U-Net's way up: per level a transposed conv doubling the side (``up_conv``), then a 3x3x3
    conv merging it with the skip connection of the same level."""
    ups, merges = nn.ModuleList(), nn.ModuleList()
    for i in range(len(channels) - 2, -1, -1):
        up: list[nn.Module] = [nn.ConvTranspose3d(channels[i + 1], channels[i], bias=not batch_norm, **up_conv)]
        if batch_norm:
            up.append(nn.BatchNorm3d(channels[i]))
        up.append(nn.ReLU(inplace=True))
        ups.append(nn.Sequential(*up))
        merges.append(nn.Sequential(*_conv_block(2 * channels[i], channels[i], batch_norm, kernel_size=3, padding=1)))
    return ups, merges


def _run_unet(x: torch.Tensor, down: nn.ModuleList, ups: nn.ModuleList, merges: nn.ModuleList,
              bottleneck: nn.Module | None = None) -> torch.Tensor:
    skips = []
    for block in down:
        x = block(x)
        skips.append(x)
    if bottleneck is not None:
        x = x + bottleneck(x).view_as(x)
    for up, merge, skip in zip(ups, merges, reversed(skips[:-1])):
        x = merge(torch.cat([up(x), skip], dim=1))
    return x


def _check_input(sdf: torch.Tensor, n: int) -> None:
    check_shape(sdf, "sdf", f"B, {n}, {n}, {n}")


def _check_common(channels, grid_resolution, convs_per_level, half_side, residual_bound):
    channels = check_int_sequence(channels, "channels", minimum=1)
    check_int(grid_resolution, "grid_resolution", minimum=1)
    check_int(convs_per_level, "convs_per_level", minimum=1)
    return channels, check_positive(half_side, "half_side"), check_positive(residual_bound, "residual_bound")


class SDFRefiner(nn.Module):
    """A 3D U-Net that predicts a bounded residual added to the coarse SDF.

    Level 0 works at side ``N / input_stride`` with ``channels[0]``; each further level halves the
    side (strided conv) with ``channels[i]``. With ``input_stride`` 2 no convolution runs at the full
    side N except the first (strided) one and the transposed-conv head: several times cheaper on a
    CPU, at the price of a residual that is smooth at the scale of two voxels. An optional fully
    connected bottleneck (Pix2Vox style, the paper's refiner) mixes the whole coarsest grid. The way up doubles the side with transposed
    convs and concatenates the encoder features of the same level (skip connections).

    The head is zero-initialised, so an untrained refiner returns its input: the refine stage
    starts exactly at the coarse stage's result.

    Args:
        channels: channels per level (level 0 first); N must be divisible by
            ``input_stride * 2**(len(channels)-1)``.
        grid_resolution: N.
        input_stride: 1 (level 0 at side N) or 2 (level 0 at N/2).
        half_side: the box half side; the input SDF is divided by it (values of order one).
        residual_bound: |refined - coarse| < residual_bound (world units).
        fc_dim: width of the fully connected bottleneck; 0 for none.
        convs_per_level: 3x3x3 convs per level on the way down (>= 1).
        batch_norm: batch norm after each conv.
    """

    def __init__(
        self,
        channels: Sequence[int] = (4, 8, 16, 32),
        grid_resolution: int = 64,
        input_stride: int = 1,
        half_side: float = 0.6,
        residual_bound: float = 0.2,
        fc_dim: int = 0,
        convs_per_level: int = 1,
        batch_norm: bool = True,
    ) -> None:
        super().__init__()
        channels, self.half_side, self.residual_bound = _check_common(
            channels, grid_resolution, convs_per_level, half_side, residual_bound)
        check_int(fc_dim, "fc_dim", minimum=0)
        if input_stride not in (1, 2):
            raise ValueError(f"input_stride must be 1 or 2, got {input_stride!r}")
        levels = len(channels)
        divisor = input_stride * 2 ** (levels - 1)
        if grid_resolution % divisor:
            raise ValueError(f"grid_resolution {grid_resolution} must be divisible by "
                             f"input_stride * 2**(len(channels)-1) = {divisor}")
        self.grid_resolution = grid_resolution
        self.channels = channels
        self.input_stride = input_stride

        self.down = _down_path(1, channels, batch_norm, convs_per_level,
                               lambda i: dict(kernel_size=4, stride=2, padding=1) if i > 0 or input_stride == 2
                               else dict(kernel_size=3, padding=1))
        self.fc: nn.Module | None = None
        if fc_dim:
            side = grid_resolution // divisor
            flat = channels[-1] * side ** 3
            self.fc = nn.Sequential(nn.Flatten(), nn.Linear(flat, fc_dim), nn.ReLU(inplace=True),
                                    nn.Linear(fc_dim, flat))
            nn.init.zeros_(self.fc[-1].weight)
            nn.init.zeros_(self.fc[-1].bias)
        self.up, self.merge = _up_path(channels, batch_norm, kernel_size=4, stride=2, padding=1)
        if input_stride == 2:
            self.head: nn.Module = nn.ConvTranspose3d(channels[0], 1, 4, stride=2, padding=1)
        else:
            self.head = nn.Conv3d(channels[0], 1, 3, padding=1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        # 3D convs are faster on a CPU in channels-last layout (docs/measurements.md).
        self.to(memory_format=torch.channels_last_3d)

    def forward(self, sdf: torch.Tensor) -> torch.Tensor:
        """sdf: (B, N, N, N) coarse SDF (world units) -> (B, N, N, N) refined SDF (world units)."""
        _check_input(sdf, self.grid_resolution)
        x = (sdf / self.half_side).unsqueeze(1).contiguous(memory_format=torch.channels_last_3d)
        x = _run_unet(x, self.down, self.up, self.merge, self.fc)
        residual = self.residual_bound * torch.tanh(self.head(x)[:, 0])
        return sdf + residual


def fold_blocks(grid: torch.Tensor) -> torch.Tensor:
    """Space to depth: (B, 2q, 2q, 2q) -> (B, 8, q, q, q), the voxel ``(2i+a, 2j+c, 2k+e)`` going to
    channel ``4a + 2c + e`` of site ``(i, j, k)``."""
    sizes = check_shape(grid, "grid", "B, M, M, M")
    if sizes["M"] % 2:
        raise ValueError(f"grid must have shape (B, M, M, M) with M even, got {tuple(grid.shape)}")
    b, q = sizes["B"], sizes["M"] // 2
    return grid.reshape(b, q, 2, q, 2, q, 2).permute(0, 2, 4, 6, 1, 3, 5).reshape(b, 8, q, q, q)


def unfold_blocks(blocks: torch.Tensor) -> torch.Tensor:
    """Depth to space, the inverse of ``fold_blocks``: (B, 8, q, q, q) -> (B, 2q, 2q, 2q)."""
    sizes = check_shape(blocks, "blocks", "B, 8, q, q, q")
    b, q = sizes["B"], sizes["q"]
    return blocks.reshape(b, 2, 2, 2, q, q, q).permute(0, 4, 1, 5, 2, 6, 3).reshape(b, 2 * q, 2 * q, 2 * q)


class BlockRefiner(nn.Module):
    """A refiner that predicts the bounded residual at side N/2, with all its convolutions at N/4
    and below: the coarse SDF is average-pooled to N/2 and folded into 2x2x2 blocks (space to
    depth: 8 channels at N/4), a small U-Net with skip connections runs on that, its head gives 8
    channels that unfold back into the N/2 residual, and the residual is upsampled linearly to N
    (``upsample2_centres``) and added to the coarse SDF.

    Why: on a CPU a 3D conv with a handful of channels on a 32^3 grid runs far below the machine's
    arithmetic speed, and the batch norm and ReLU around it cost as much again; the same voxels
    as fewer, wider sites at 16^3 run several times faster (``benchmarks/train_step_speed.py``). What
    it gives up is detail finer than two voxels of a 64^3 grid, which the benchmark's 32^3 voxel
    IoU does not see; the coarse decoder's own output is no finer (``SDFDecoder.head_stride``).

    The head is zero-initialised, so an untrained refiner returns its input, and the residual
    stays within ``residual_bound``: ``|refined - coarse| < residual_bound`` everywhere.

    Args:
        channels: channels per level (level 0 at N/4 first); N must be divisible by
            ``4 * 2**(len(channels)-1)``.
        grid_resolution: N.
        half_side: the box half side; the input SDF is divided by it (values of order one).
        residual_bound: |refined - coarse| < residual_bound (world units).
        convs_per_level: 3x3x3 convs per level on the way down (>= 1).
        batch_norm: batch norm after each conv.
    """

    def __init__(
        self,
        channels: Sequence[int] = (16, 32, 64, 128),
        grid_resolution: int = 64,
        half_side: float = 0.6,
        residual_bound: float = 0.2,
        convs_per_level: int = 1,
        batch_norm: bool = True,
    ) -> None:
        super().__init__()
        channels, self.half_side, self.residual_bound = _check_common(
            channels, grid_resolution, convs_per_level, half_side, residual_bound)
        divisor = 4 * 2 ** (len(channels) - 1)
        if grid_resolution % divisor:
            raise ValueError(f"grid_resolution {grid_resolution} must be divisible by "
                             f"4 * 2**(len(channels)-1) = {divisor}")
        self.grid_resolution = grid_resolution
        self.channels = channels

        # 8 input channels: one 2x2x2 block of the N/2 grid per site
        self.down = _down_path(8, channels, batch_norm, convs_per_level,
                               lambda i: dict(kernel_size=3, stride=2 if i > 0 else 1, padding=1))
        self.up, self.merge = _up_path(channels, batch_norm, kernel_size=2, stride=2)
        self.head = nn.Conv3d(channels[0], 8, 3, padding=1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        self.to(memory_format=torch.channels_last_3d)

    def forward(self, sdf: torch.Tensor) -> torch.Tensor:
        """sdf: (B, N, N, N) coarse SDF (world units) -> (B, N, N, N) refined SDF (world units)."""
        _check_input(sdf, self.grid_resolution)
        half = F.avg_pool3d((sdf / self.half_side).unsqueeze(1), 2)[:, 0]  # (B, N/2, N/2, N/2)
        x = fold_blocks(half).contiguous(memory_format=torch.channels_last_3d)
        x = _run_unet(x, self.down, self.up, self.merge)
        residual = unfold_blocks(self.residual_bound * torch.tanh(self.head(x)))  # (B, N/2, N/2, N/2)
        return sdf + upsample2_centres(residual)
