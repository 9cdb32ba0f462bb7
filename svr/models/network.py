"""SVRNet: encoder -> decoder (coarse SDF) -> refiner (refined SDF), with the grid's box."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

import renderer

from sdfcommon.tooling.checks import check_instance, check_positive
from svr.models.camera import ViewHead
from svr.models.decoder import SDFDecoder
from svr.models.encoder import ImageEncoder
from svr.models.local import PixelAlignedHead
from svr.models.prior import ShapePrior
from svr.models.refiner import BlockRefiner, SDFRefiner


@dataclass(frozen=True)
class SVRPrediction:
    """The network's output for B images.

    Attributes:
        coarse: (B, N, N, N) the decoder's SDF (world units, renderer.SDFGrid layout).
        refined: (B, N, N, N) the refiner's SDF, or None when the refiner was not run.
    """

    coarse: torch.Tensor
    refined: torch.Tensor | None

    @property
    def final(self) -> torch.Tensor:
        """The best SDF available: the refined one if it was computed, else the coarse one."""
        return self.refined if self.refined is not None else self.coarse


class SVRNet(nn.Module):
    """The single-view network of paper section 6 (three plain modules, built from config).

    Args:
        encoder: image (B, 4, 64, 64) -> code (B, latent_dim).
        decoder: code -> coarse SDF (B, N, N, N).
        refiner: coarse SDF -> refined SDF (B, N, N, N) (BlockRefiner or SDFRefiner).
        half_side: the SDF grid covers ``[-half_side, half_side]^3`` (world units); the normalised
            objects lie in [-0.5, 0.5]^3, so a value above 0.5 leaves a margin.
        local: an optional PixelAlignedHead that corrects the decoder's SDF from image features read
            where each sample projects into the input view; a network with one needs the input
            images' NMR view indices (``forward(images, views=...)``).
        camera: an optional ViewHead that estimates an image's NMR view and framing (for inputs
            whose camera is unknown, such as photos); trained beside the rest, apart from it.
        prior: an optional ShapePrior (the nearest training objects' visual hull, read by the
            pixel-aligned head at its samples; the head must be built with ``prior=True``).
    """

    def __init__(self, encoder: ImageEncoder, decoder: SDFDecoder, refiner: BlockRefiner | SDFRefiner,
                 half_side: float = 0.6, local: PixelAlignedHead | None = None,
                 camera: ViewHead | None = None, prior: ShapePrior | None = None) -> None:
        super().__init__()
        for name, mod, cls in (("encoder", encoder, ImageEncoder), ("decoder", decoder, SDFDecoder),
                               ("refiner", refiner, BlockRefiner)):
            check_instance(mod, name, nn.Module, f"an nn.Module ({cls.__name__})")
        check_positive(half_side, "half_side")
        if float(half_side) <= 0.5:
            raise ValueError(f"half_side must exceed 0.5 so the normalised objects fit, got {half_side!r}")
        for name, mod in (("decoder", decoder), ("refiner", refiner)):
            hs = getattr(mod, "half_side", None)
            if hs is not None and abs(float(hs) - float(half_side)) > 1e-9:
                raise ValueError(f"{name}.half_side ({hs}) must equal half_side ({half_side})")
        dec_n = getattr(decoder, "grid_resolution", None)
        ref_n = getattr(refiner, "grid_resolution", None)
        if dec_n is not None and ref_n is not None and dec_n != ref_n:
            raise ValueError(f"decoder.grid_resolution ({dec_n}) must equal refiner.grid_resolution ({ref_n})")
        if local is not None:
            check_instance(local, "local", PixelAlignedHead, "a PixelAlignedHead or None")
            have = encoder.map_channels[:len(local.image_channels)]
            if list(local.image_channels) != have:
                raise ValueError(f"local.image_channels {list(local.image_channels)} must match the encoder's first "
                                 f"maps' channels {have} (the input's, then each conv block's)")
            if local.volume_channels != decoder.channels[-1]:
                raise ValueError(f"local.volume_channels ({local.volume_channels}) must equal the decoder's last "
                                 f"channels ({decoder.channels[-1]})")
            if local.image_size != encoder.image_size:
                raise ValueError(f"local.image_size ({local.image_size}) must equal encoder.image_size "
                                 f"({encoder.image_size})")
        if camera is not None:
            check_instance(camera, "camera", ViewHead, "a ViewHead or None")
        if prior is not None:
            check_instance(prior, "prior", ShapePrior, "a ShapePrior or None")
            if local is None or not local.prior:
                raise ValueError("prior needs a pixel-aligned head that reads it (local.prior: true)")
            side = decoder.head_points.shape[0]
            if prior.side != side:
                raise ValueError(f"prior.side ({prior.side}) must equal the side of the decoder's head grid ({side})")
            prior.attach(decoder.head_points)
        elif local is not None and local.prior:
            raise ValueError("local.prior is true but the network has no prior (model.prior)")
        self.encoder = encoder
        self.decoder = decoder
        self.refiner = refiner
        self.local = local
        self.camera = camera
        self.prior = prior
        self.half_side = float(half_side)

    @property
    def needs_views(self) -> bool:
        """Whether the network reads the input view's camera (it has a pixel-aligned head)."""
        return self.local is not None

    @property
    def grid_resolution(self) -> int:
        return int(self.decoder.grid_resolution)

    @property
    def voxel_size(self) -> float:
        """Spacing of the SDF samples (world units)."""
        return 2.0 * self.half_side / (self.grid_resolution - 1)

    def shape_prior(self, images: torch.Tensor, views: torch.Tensor | None,
                    exclude: torch.Tensor | None = None) -> torch.Tensor | None:
        """(B, S, S, S) the shape prior of B images (None without one); ``exclude``: (B,) training
        objects it must not retrieve (training passes each input's own object)."""
        if self.prior is None:
            return None
        if views is None:
            raise ValueError("views: this network's shape prior compares the input with the training objects in the "
                             "input's view, so it needs the input images' NMR view indices (0..23), one per image")
        return self.prior(images[:, 3], views, exclude)

    def coarse(self, images: torch.Tensor, views: torch.Tensor | None = None,
               prior: torch.Tensor | None = None) -> torch.Tensor:
        """images: (B, 4, 64, 64) RGBA in [0, 1] (and, with a pixel-aligned head, views: (B,) their NMR
        view indices) -> (B, N, N, N) the decoder's SDF; ``prior``: the images' ``shape_prior`` where
        already made (else it is made here)."""
        if self.local is None:
            return self.decoder(self.encoder(images))
        if views is None:
            raise ValueError("views: this network reads image features where each sample projects into the input "
                             "view, so it needs the input images' NMR view indices (0..23), one per image")
        code, maps = self.encoder.forward_maps(images, len(self.local.image_channels))
        if prior is None:
            prior = self.shape_prior(images, views)
        feats = self.local(self.decoder.features(code), maps, views, self.decoder.head_points, prior)
        return self.decoder.finish(self.decoder.head(feats)[:, 0])

    def forward(self, images: torch.Tensor, refine: bool = True, views: torch.Tensor | None = None) -> SVRPrediction:
        """images: (B, 4, 64, 64) RGBA in [0, 1] -> SVRPrediction (coarse and, with refine, refined);
        ``views`` (B,) NMR view indices of the images, needed with a pixel-aligned head."""
        prior = self.shape_prior(images, views)
        coarse = self.coarse(images, views, prior)
        refined = self.refiner(coarse) if refine else None
        return SVRPrediction(coarse=coarse, refined=refined)

    def grid(self, sdf: torch.Tensor) -> renderer.SDFGrid:
        """The renderer's view of SDF values (B, N, N, N) over this network's box (no copy)."""
        return renderer.SDFGrid(sdf, -self.half_side, self.half_side)
