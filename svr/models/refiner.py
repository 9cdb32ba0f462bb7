"""SDFRefiner: coarse SDF grid -> refined SDF grid (a 3D conv encoder-decoder with skip connections)."""
from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from ._checks import check_channels, check_positive, check_positive_int


def _conv_block(c_in: int, c_out: int, batch_norm: bool, **conv) -> list[nn.Module]:
    layers: list[nn.Module] = [nn.Conv3d(c_in, c_out, bias=not batch_norm, **conv)]
    if batch_norm:
        layers.append(nn.BatchNorm3d(c_out))
    layers.append(nn.ReLU(inplace=True))
    return layers


class SDFRefiner(nn.Module):
    """A 3D U-Net that predicts a bounded residual added to the coarse SDF.

    Level 0 works at side ``N / input_stride`` with ``channels[0]``; each further level halves the
    side (strided conv) with ``channels[i]``. With ``input_stride`` 2 no convolution runs at the full
    side N except the first (strided) one and the transposed-conv head: several times cheaper on a
    CPU, at the price of a residual that is smooth at the scale of two voxels. An optional fully connected bottleneck (Pix2Vox style, the
    paper's refiner) mixes the whole coarsest grid. The way up doubles the side with transposed
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
        channels = check_channels(channels, "channels")
        check_positive_int(grid_resolution, "grid_resolution")
        check_positive_int(convs_per_level, "convs_per_level")
        self.half_side = check_positive(half_side, "half_side")
        self.residual_bound = check_positive(residual_bound, "residual_bound")
        if isinstance(fc_dim, bool) or not isinstance(fc_dim, int) or fc_dim < 0:
            raise ValueError(f"fc_dim must be a non-negative int, got {fc_dim!r}")
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

        self.down = nn.ModuleList()
        prev = 1
        for i, c in enumerate(channels):
            strided = i > 0 or input_stride == 2
            first = dict(kernel_size=4, stride=2, padding=1) if strided else dict(kernel_size=3, padding=1)
            layers = _conv_block(prev, c, batch_norm, **first)
            for _ in range(convs_per_level - 1):
                layers += _conv_block(c, c, batch_norm, kernel_size=3, padding=1)
            self.down.append(nn.Sequential(*layers))
            prev = c
        self.fc: nn.Module | None = None
        if fc_dim:
            side = grid_resolution // divisor
            flat = channels[-1] * side ** 3
            self.fc = nn.Sequential(nn.Flatten(), nn.Linear(flat, fc_dim), nn.ReLU(inplace=True),
                                    nn.Linear(fc_dim, flat))
            nn.init.zeros_(self.fc[-1].weight)
            nn.init.zeros_(self.fc[-1].bias)
        self.up = nn.ModuleList()
        self.merge = nn.ModuleList()
        for i in range(levels - 2, -1, -1):
            up: list[nn.Module] = [nn.ConvTranspose3d(channels[i + 1], channels[i], 4, stride=2, padding=1,
                                                      bias=not batch_norm)]
            if batch_norm:
                up.append(nn.BatchNorm3d(channels[i]))
            up.append(nn.ReLU(inplace=True))
            self.up.append(nn.Sequential(*up))
            self.merge.append(nn.Sequential(*_conv_block(2 * channels[i], channels[i], batch_norm,
                                                         kernel_size=3, padding=1)))
        if input_stride == 2:
            self.head: nn.Module = nn.ConvTranspose3d(channels[0], 1, 4, stride=2, padding=1)
        else:
            self.head = nn.Conv3d(channels[0], 1, 3, padding=1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        # 3D convs on a CPU are several times faster (backward up to ~6x) in channels-last layout.
        self.to(memory_format=torch.channels_last_3d)

    def forward(self, sdf: torch.Tensor) -> torch.Tensor:
        """sdf: (B, N, N, N) coarse SDF (world units) -> (B, N, N, N) refined SDF (world units)."""
        n = self.grid_resolution
        if sdf.ndim != 4 or sdf.shape[1:] != (n, n, n):
            raise ValueError(f"sdf must have shape (B, {n}, {n}, {n}), got {tuple(sdf.shape)}")
        x = (sdf / self.half_side).unsqueeze(1).contiguous(memory_format=torch.channels_last_3d)
        skips = []
        for block in self.down:
            x = block(x)
            skips.append(x)
        if self.fc is not None:
            x = x + self.fc(x).view_as(x)
        for up, merge, skip in zip(self.up, self.merge, reversed(skips[:-1])):
            x = merge(torch.cat([up(x), skip], dim=1))
        residual = self.residual_bound * torch.tanh(self.head(x)[:, 0])
        return sdf + residual
