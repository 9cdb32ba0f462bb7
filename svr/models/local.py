"""PixelAlignedHead: the decoder's last feature grid corrected by image features read where each cell
projects into the input view (as PIFu and DISN do, with the dataset's known camera instead of an
estimated one). A global code alone must recall a whole shape from memory, which with few training
objects per category drifts towards a remembered shape; a cell that sees whether its rays hit the
silhouette, and what the image looks like around it, can follow this object's outline. It works on
the decoder's feature grid (16^3 in model=small), where a sample costs 8x less than on the head's
32^3 grid; the input image is still read at each of the head's samples inside a cell (its 2x2x2
sub-samples become channels of the cell), so the silhouette reaches the head at full resolution."""
from __future__ import annotations

from typing import Optional, Sequence

import torch
from torch import nn
from torch.nn import functional as F

from sdfcommon.tooling.checks import check_int, check_int_sequence, check_shape
from svr.nmr.views import sample_grid, view_cameras


class PixelAlignedHead(nn.Module):
    """A residual update of the decoder's last feature grid from pixel-aligned image features.

    For each cell of the feature grid (side s), its centre's projection into the input view's NMR
    camera picks bilinear samples of the encoder's maps, and the head's samples inside the cell
    (side S = s or 2s, world positions ``points``) pick samples of the input image. With the cell's
    features, its centre's position and its depth along the view they feed a two-layer MLP whose
    output is added to the cell's features; the decoder's head then makes the SDF from them.

    Args:
        image_channels: channels of each image map the head reads (``ImageEncoder.forward_maps``
            order: the input image first, then each conv block's output), e.g. (4, 16, 32).
        volume_channels: channels of the decoder's last feature grid.
        hidden: width of the MLP.
        image_size: side of the input images (the camera's image size).
        head_stride: the decoder's ``head_stride``: 2 when the head's grid has twice the feature
            grid's side (8 input-image samples per cell), 1 when they match (one).
        mirror_axis: None, or the world axis (0 = x, 1 = y, 2 = z) across whose plane through the
            origin the objects are mirror-symmetric: each cell then also reads the image where its
            mirror image projects, a second look at its side of the object (as Ladybird does).
    """

    def __init__(self, image_channels: Sequence[int] = (4, 16, 32), volume_channels: int = 16, hidden: int = 64,
                 image_size: int = 64, head_stride: int = 2, mirror_axis: Optional[int] = None,
                 prior: bool = False) -> None:
        super().__init__()
        self.image_channels = check_int_sequence(image_channels, "image_channels", minimum=1)
        check_int(volume_channels, "volume_channels", minimum=1)
        check_int(hidden, "hidden", minimum=1)
        check_int(image_size, "image_size", minimum=1)
        self.volume_channels = volume_channels
        self.image_size = image_size
        self.hidden = hidden
        if head_stride not in (1, 2):
            raise ValueError(f"head_stride must be 1 or 2, got {head_stride!r}")
        self.head_stride = head_stride
        if mirror_axis == "auto":
            raise ValueError("mirror_axis 'auto' is resolved by the training command from the training voxels "
                             "(svr.data.symmetry); a network built directly needs None, 0 (x), 1 (y) or 2 (z)")
        if mirror_axis is not None and mirror_axis not in (0, 1, 2):
            raise ValueError(f"mirror_axis must be None, 0 (x), 1 (y) or 2 (z), got {mirror_axis!r}")
        self.mirror_axis = mirror_axis
        if not isinstance(prior, bool):
            raise ValueError(f"prior must be true or false, got {prior!r}")
        self.prior = prior
        looks = 2 if mirror_axis is not None else 1
        width = volume_channels + 3 + looks * (1 + head_stride ** 3 * self.image_channels[0]
                                               + sum(self.image_channels[1:])) + (head_stride ** 3 if prior else 0)
        self.first = nn.Linear(width, hidden)
        self.out = nn.Linear(hidden, volume_channels)
        nn.init.zeros_(self.out.weight)  # the untrained head leaves the features as they are
        nn.init.zeros_(self.out.bias)

    def forward(self, volume: torch.Tensor, maps: Sequence[torch.Tensor], views: torch.Tensor,
                points: torch.Tensor, prior: Optional[torch.Tensor] = None) -> torch.Tensor:
        """The corrected feature grid: (B, C, s, s, s) ``volume`` plus the MLP's update of each cell
        from ``cell_inputs`` (same arguments)."""
        b, s = volume.shape[0], volume.shape[-1]
        h = F.relu(self._first(self._cell_parts(volume, maps, views, points, prior)))
        return volume + self.out(h).reshape(b, s, s, s, self.volume_channels).permute(0, 4, 1, 2, 3)

    def _first(self, parts: Sequence[torch.Tensor]) -> torch.Tensor:
        """``self.first`` of the parts' concatenation, as two products: the parts that need a
        gradient (the features, the encoder's maps) and those that do not (positions, depths, the
        input image), so that the backward pass makes the input gradient of the former only (the
        widest tensor of the step's backward: 65536 x 181 floats in the demo, 38% of which the
        inputs never used)."""
        weight, offset = self.first.weight, 0
        groups: dict[bool, tuple[list, list]] = {True: ([], []), False: ([], [])}
        for part in parts:
            width = part.shape[-1]
            xs, ws = groups[part.requires_grad]
            xs.append(part)
            ws.append(weight[:, offset:offset + width])
            offset += width
        out = self.first.bias
        for xs, ws in groups.values():
            if xs:
                out = out + F.linear(torch.cat(xs, dim=-1), torch.cat(ws, dim=1))
        return out

    def cell_inputs(self, volume: torch.Tensor, maps: Sequence[torch.Tensor], views: torch.Tensor,
                    points: torch.Tensor, prior: Optional[torch.Tensor] = None) -> torch.Tensor:
        """What the MLP reads for each cell.

        Args:
            volume: (B, C, s, s, s) the decoder's last feature grid.
            maps: the image maps, (B, C_l, H_l, W_l) each, channels as ``image_channels``.
            views: (B,) NMR view indices of the input images (fractional allowed), or (B, 2) rows of
                (view, elevation in degrees) (``svr.nmr.views.view_cameras``).
            points: (S, S, S, 3) world positions of the head's samples (renderer.SDFGrid layout),
                S = s or 2s.
            prior: (B, S, S, S) the shape prior at the head's samples; needed when built with ``prior``.
        Returns:
            (B, s^3, width): per cell (cells in renderer.SDFGrid order) its C features and its
            centre's position (3), then per look (the cell, and with ``mirror_axis`` its mirror
            image) the input image at its sub-samples (sub-sample major, ``head_stride**3`` x C_0),
            the other maps at its centre and the centre's depth along the view minus the camera's
            distance to the origin (1); with ``prior``, last, the prior at its sub-samples (``head_stride**3``).
        """
        return torch.cat(self._cell_parts(volume, maps, views, points, prior), dim=-1)

    def _cell_parts(self, volume: torch.Tensor, maps: Sequence[torch.Tensor], views: torch.Tensor,
                    points: torch.Tensor, prior: Optional[torch.Tensor] = None) -> list[torch.Tensor]:
        """``cell_inputs`` before the concatenation: (B, s^3, width_k) parts."""
        b, s = volume.shape[0], volume.shape[-1]
        check_shape(volume, "volume", f"{b}, {self.volume_channels}, s, s, s")
        if len(maps) != len(self.image_channels):
            raise ValueError(f"maps: expected {len(self.image_channels)} image maps, got {len(maps)}")
        views = torch.as_tensor(views, device=volume.device)
        views = views.reshape(-1, 2) if views.ndim == 2 else views.reshape(-1)
        if views.shape[0] != b:
            raise ValueError(f"views must hold one NMR view index per image ({b}), got {views.shape[0]}")
        side = points.shape[0]
        f = self.head_stride
        if f * s != side:
            raise ValueError(f"the head's side ({side}) must be head_stride ({f}) times the feature grid's ({s})")
        # (s^3, f^3, 3): the head's samples grouped by the cell they fall in.
        sub = points.reshape(s, f, s, f, s, f, 3).permute(0, 2, 4, 1, 3, 5, 6).reshape(s ** 3, f ** 3, 3)
        centres = sub.mean(1)
        cams = view_cameras(views, self.image_size).to(volume.device, volume.dtype)

        def grid_of(pts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            pix, depth = cams.project(pts)  # (B, P, 2), (B, P)
            return sample_grid(pix, self.image_size).unsqueeze(1), depth

        def sample(m: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:  # -> (B, P, C)
            return F.grid_sample(m, grid, mode="bilinear", padding_mode="border", align_corners=False)[:, :, 0] \
                .transpose(1, 2)

        dist = cams.eye.norm(dim=-1)[:, None]  # depth relative to the origin's

        def look(sub_pts: torch.Tensor) -> list[torch.Tensor]:
            grid_c, depth_c = grid_of(sub_pts.mean(1))
            grid_s, _ = grid_of(sub_pts.reshape(-1, 3))
            image = sample(maps[0], grid_s).reshape(b, s ** 3, f ** 3 * self.image_channels[0])
            return [image, *(sample(m, grid_c) for m in maps[1:]), (depth_c - dist).unsqueeze(-1)]

        feats = volume.permute(0, 2, 3, 4, 1).reshape(b, s ** 3, self.volume_channels)
        parts = [feats, centres.expand(b, -1, -1), *look(sub)]
        if self.mirror_axis is not None:
            flip = torch.ones(3, dtype=sub.dtype, device=sub.device)
            flip[self.mirror_axis] = -1.0
            parts += look(sub * flip)
        if self.prior:
            if prior is None:
                raise ValueError("prior: this head reads a shape prior at its samples (svr.models.ShapePrior); got none")
            check_shape(prior, "prior", f"{b}, {side}, {side}, {side}")
            parts.append(prior.reshape(b, s, f, s, f, s, f).permute(0, 1, 3, 5, 2, 4, 6).reshape(b, s ** 3, f ** 3))
        return parts


__all__ = ["PixelAlignedHead"]
