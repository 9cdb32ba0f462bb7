"""ViewHead: the input camera from the image alone. A network with a pixel-aligned head needs the
input's NMR view, which a photo does not have; this small CNN, trained beside the network on the
training split's known views (NMR-format data holds them), classifies the view among the 24 and
regresses where the object's silhouette sits in such a render (its framing: the bounding box's
longest side and centre), from the image cropped to its silhouette's bounding box
(``normalise_crops``), so that where and how large the object is in a photo does not matter. Its
weights are apart from the rest of the network's, so its loss leaves their training as it was."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from sdfcommon.tooling.checks import check_float, check_int
from svr.models.checkpoint_layout import check_stage
from svr.nmr.format import NUM_VIEWS
# The crop's longest side fills this share of the square (a margin for the anti-aliased edge).
CROP_FILL = 0.9


def normalise_crops(images: torch.Tensor, size: int = 32) -> tuple[torch.Tensor, torch.Tensor]:
    """Each image resampled so that its silhouette's bounding box (alpha >= 0.5) is centred and its
    longest side fills ``CROP_FILL`` of a ``size``^2 square, and where that box was.

    Args:
        images: (B, 4, S, S) RGBA in [0, 1], RGB on white.
    Returns:
        (B, 4, size, size) alpha and the alpha-premultiplied RGB (0 outside the object), and (B, 3)
        framing: the box's longest side, centre x and centre y, as fractions of the image side (an
        image with no opaque pixel gives the whole image's).
    """
    if images.ndim != 4 or images.shape[1] != 4 or images.shape[2] != images.shape[3]:
        raise ValueError(f"images must be (B, 4, S, S) RGBA, got shape {tuple(images.shape)}")
    b, s = images.shape[0], images.shape[-1]
    x = images.detach().float()
    alpha = x[:, 3]
    inside = alpha >= 0.5
    idx = torch.arange(s, dtype=x.dtype, device=x.device)

    def span(mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        first = torch.where(mask, idx, torch.full_like(idx, float(s + 1))).amin(dim=1)
        last = torch.where(mask, idx, torch.full_like(idx, -1.0)).amax(dim=1) + 1.0
        return first, last

    left, right = span(inside.any(dim=1))
    top, bottom = span(inside.any(dim=2))
    empty = ~inside.flatten(1).any(dim=1)
    whole = torch.full_like(left, float(s))
    extent = torch.where(empty, whole, torch.maximum(right - left, bottom - top))
    cx = torch.where(empty, whole / 2, (left + right) / 2)
    cy = torch.where(empty, whole / 2, (top + bottom) / 2)
    # affine_grid's normalised coordinates: -1 and 1 are the image's outer edges (align_corners=False).
    theta = torch.zeros(b, 2, 3, dtype=x.dtype, device=x.device)
    theta[:, 0, 0] = theta[:, 1, 1] = extent / (CROP_FILL * s)
    theta[:, 0, 2] = 2 * cx / s - 1
    theta[:, 1, 2] = 2 * cy / s - 1
    premultiplied = torch.cat([alpha[:, None], x[:, :3] * alpha[:, None]], dim=1)
    grid = F.affine_grid(theta, [b, 4, 2 * size, 2 * size], align_corners=False)
    # Sampled at twice the side and box-averaged: the crop is often smaller than the input.
    crops = F.avg_pool2d(F.grid_sample(premultiplied, grid, mode="bilinear", padding_mode="zeros",
                                       align_corners=False), 2)
    return crops, torch.stack([extent, cx, cy], dim=1) / s


# The elevation output is (elevation - 30) / 20: about -1 .. 1 over the extra views' 10 to 50 degrees.
ELEVATION_CENTRE, ELEVATION_SCALE = 30.0, 20.0


@dataclass(frozen=True)
class ViewEstimate:
    """``ViewHead.estimate``'s answer for B images.

    Attributes:
        probabilities: (B, 24) of each NMR view.
        framing: (B, 3) extent, centre x, centre y of the silhouette in a training render from the
            most probable view (fractions of the image side).
        elevation: (B,) degrees, or None from a head without the elevation output.
    """

    probabilities: torch.Tensor
    framing: torch.Tensor
    elevation: torch.Tensor | None = None

    @property
    def views(self) -> torch.Tensor:
        """(B,) long: the most probable NMR view of each image."""
        return self.probabilities.argmax(dim=1)


class ViewHead(nn.Module):
    """Image -> NMR view logits (24) and framing (3), from ``normalise_crops``, and the camera's
    elevation where asked for.

    Args:
        channels: conv blocks (3x3 conv, batch norm, ReLU, 2x2 max pool), then a global mean.
        crop_size: side of the normalised crop.
        train_views: views of each training object it learns from per step (at most the batch's):
            its cost per step grows with them.
        elevation: also regress the camera's elevation (only data with extra views, at other
            elevations than NMR's 30 degrees, teaches it anything: ``data.extra_views``).
        lr_scale: its learning rate as a multiple of the stage's (its own parameter group in
            ``SVRLightningModule.configure_optimizers``; the schedule scales both alike).
        stages: the training stages it learns in (None: every stage); in the others it is frozen
            and costs nothing.
    """

    def __init__(self, channels: tuple[int, ...] | list[int] = (32, 64, 128), crop_size: int = 32,
                 train_views: int = 4, elevation: bool = False, lr_scale: float = 1.0,
                 stages: Optional[Sequence[str]] = None) -> None:
        super().__init__()
        if stages is not None:
            if isinstance(stages, str) or not stages:
                raise ValueError(f"stages must be null or a non-empty list of stages, got {stages!r}")
            stages = tuple(check_stage(str(s)) for s in stages)
        self.stages = stages
        check_int(crop_size, "crop_size", minimum=8)
        check_int(train_views, "train_views", minimum=1)
        self.train_views = int(train_views)
        if not isinstance(elevation, bool):
            raise ValueError(f"elevation must be true or false, got {elevation!r} (auto is resolved by the "
                             "training command, from whether it draws extra views)")
        self.lr_scale = check_float(lr_scale, "lr_scale", minimum=0.0)
        if self.lr_scale == 0:
            raise ValueError("lr_scale must be positive, got 0")
        if not channels or any(int(c) < 1 for c in channels):
            raise ValueError(f"channels must be a non-empty list of positive widths, got {channels!r}")
        layers: list[nn.Module] = []
        c_in = 4
        for c in channels:
            layers += [nn.Conv2d(c_in, int(c), 3, padding=1, bias=False), nn.BatchNorm2d(int(c)), nn.ReLU(inplace=True),
                       nn.MaxPool2d(2)]
            c_in = int(c)
        self.features = nn.Sequential(*layers)
        self.out = nn.Linear(c_in, NUM_VIEWS + 3)
        with torch.no_grad():  # the untrained framing: the procedural renders' median (45 / 64, centre (32, 33))
            self.out.bias[NUM_VIEWS:] = torch.tensor([0.7, 0.5, 0.52])
        self.crop_size = int(crop_size)
        self.elevation_out = nn.Linear(c_in, 1) if elevation else None
        if self.elevation_out is not None:
            nn.init.zeros_(self.elevation_out.weight)  # untrained: NMR's 30 degrees
            nn.init.zeros_(self.elevation_out.bias)

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, 4, S, S) RGBA -> (B, 24) view logits and (B, 3) framing."""
        return self._from_crops(normalise_crops(images, self.crop_size)[0])

    def _from_crops(self, crops: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        logits, framing, _ = self._outputs(crops)
        return logits, framing

    def _outputs(self, crops: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        feats = self.features(crops).mean(dim=(2, 3))
        y = self.out(feats)
        elevation = self.elevation_out(feats)[:, 0] if self.elevation_out is not None else None
        return y[:, :NUM_VIEWS], y[:, NUM_VIEWS:], elevation

    def loss(self, images: torch.Tensor, views: torch.Tensor,
             elevations: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The training loss of (N, 4, S, S) renders from known NMR ``views`` (N,) (for a view
        between them, the nearest): cross-entropy of the view plus the L1 error of the framing
        (fractions of the image side: weighted more, its gradients drown the view's, and on the demo's
        data the views right after 600 steps fell from 42% to 13%), plus, with the elevation output,
        the squared error of the elevation in units of ``ELEVATION_SCALE`` degrees against
        ``elevations`` (N,) (None: all NMR's 30); and the share of views right. Squared, not L1:
        most training views are NMR's, all at 30 degrees, and L1's optimum, the conditional median,
        stayed at 30 (on the demo's data with a quarter of extra views the output never moved)."""
        crops, target = normalise_crops(images, self.crop_size)  # once: the crops and the framing
        logits, framing, elevation = self._outputs(crops)
        loss = F.cross_entropy(logits, views.long()) + (framing - target).abs().sum(dim=1).mean()
        if elevation is not None:
            want = torch.full_like(elevation, ELEVATION_CENTRE) if elevations is None else elevations.to(elevation)
            loss = loss + (elevation - (want - ELEVATION_CENTRE) / ELEVATION_SCALE).square().mean()
        return loss, (logits.argmax(dim=1) == views).float().mean()

    @torch.no_grad()
    def estimate(self, images: torch.Tensor) -> ViewEstimate:
        """The view probabilities, framing and (with the elevation output) elevation of (B, 4, S, S)
        RGBA images (in eval mode)."""
        logits, framing, elevation = self._outputs(normalise_crops(images, self.crop_size)[0])
        if elevation is not None:
            elevation = (ELEVATION_CENTRE + ELEVATION_SCALE * elevation).clamp(-89.0, 89.0)
        return ViewEstimate(probabilities=logits.softmax(dim=1), framing=framing, elevation=elevation)

    def trains_in(self, stage: str) -> bool:
        """Whether the head learns in training stage ``stage``."""
        return self.stages is None or stage in self.stages


__all__ = ["CROP_FILL", "ViewEstimate", "ViewHead", "normalise_crops"]
