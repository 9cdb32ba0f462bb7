"""ImageEncoder: one RGBA view -> a latent code."""
from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from sdfcommon.tooling.checks import check_int, check_int_sequence, check_shape


class ImageEncoder(nn.Module):
    """A strided 2D conv stack followed by fully connected layers.

    Each conv block halves the image side (kernel 3 or ``kernel_size``, stride 2), with batch norm
    and ReLU; the flattened features go through ``fc_dims`` hidden layers to ``latent_dim``.

    Args:
        in_channels: image channels (4 for RGBA).
        image_size: input side H = W (64 for the NMR data).
        channels: output channels of each conv block; the final feature map has side
            ``image_size / 2**len(channels)``.
        fc_dims: widths of the hidden fully connected layers (may be empty).
        latent_dim: size of the code.
        kernel_size: conv kernel side (odd).
        batch_norm: batch norm after each conv / hidden FC layer.
    """

    def __init__(
        self,
        in_channels: int = 4,
        image_size: int = 64,
        channels: Sequence[int] = (16, 32, 64, 128),
        fc_dims: Sequence[int] = (),
        latent_dim: int = 256,
        kernel_size: int = 3,
        batch_norm: bool = True,
    ) -> None:
        super().__init__()
        check_int(in_channels, "in_channels", minimum=1)
        check_int(image_size, "image_size", minimum=1)
        check_int(latent_dim, "latent_dim", minimum=1)
        check_int(kernel_size, "kernel_size", minimum=1)
        channels = check_int_sequence(channels, "channels", minimum=1)
        fc_dims = check_int_sequence(fc_dims, "fc_dims", minimum=1, allow_empty=True)
        if kernel_size % 2 == 0:
            raise ValueError(f"kernel_size must be odd, got {kernel_size}")
        side = image_size
        for _ in channels:
            if side % 2:
                raise ValueError(
                    f"image_size {image_size} cannot be halved {len(channels)} times (len(channels))")
            side //= 2
        self.in_channels = in_channels
        self.image_size = image_size
        self.latent_dim = latent_dim

        layers: list[nn.Module] = []
        prev = in_channels
        for c in channels:
            layers += [nn.Conv2d(prev, c, kernel_size, stride=2, padding=kernel_size // 2, bias=not batch_norm)]
            if batch_norm:
                layers.append(nn.BatchNorm2d(c))
            layers.append(nn.ReLU(inplace=True))
            prev = c
        self.convs = nn.Sequential(*layers)
        fcs: list[nn.Module] = [nn.Flatten()]
        prev = prev * side * side
        for d in fc_dims:
            fcs.append(nn.Linear(prev, d, bias=not batch_norm))
            if batch_norm:
                fcs.append(nn.BatchNorm1d(d))
            fcs.append(nn.ReLU(inplace=True))
            prev = d
        fcs.append(nn.Linear(prev, latent_dim))
        self.fc = nn.Sequential(*fcs)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """images: (B, C, H, W) float in [0, 1] -> (B, latent_dim) codes."""
        check_shape(images, "images", f"B, {self.in_channels}, {self.image_size}, {self.image_size}")
        return self.fc(self.convs(images))

    @property
    def map_channels(self) -> list[int]:
        """Channels of the maps ``forward_maps`` returns: the input's, then each conv block's."""
        return [self.in_channels] + [m.out_channels for m in self.convs if isinstance(m, nn.Conv2d)]

    def forward_maps(self, images: torch.Tensor, levels: int) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """The codes and the first ``levels`` image maps: the input itself, then the output of each
        conv block (after its ReLU), each half the side of the one before."""
        check_shape(images, "images", f"B, {self.in_channels}, {self.image_size}, {self.image_size}")
        maps, x = [images], images
        for m in self.convs:
            x = m(x)
            if isinstance(m, nn.ReLU):
                maps.append(x)
        return self.fc(x), maps[:levels]
