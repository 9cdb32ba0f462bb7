"""What a checkpoint's predictions go through after the network, chosen once on the validation split
(``svr.evaluation.calibration_search``) and kept in the checkpoint: carving by the input silhouette and a
shift of the surface level. A network trained on silhouettes predicts shapes near the visual hull
of its supervised views, so it over-fills (on the demo's test split the median predicted volume was
1.75x the truth) and puts some material where the input view shows background. Carving removes
every sample whose projection into the input view falls outside the silhouette (the dataset's known
camera, as the pixel-aligned head reads it), and, with a mirror axis, every sample whose mirror
image does (the mirror image of the object seen from the same camera has the same silhouette);
the level moves the network's surface inwards by a fixed distance, and the carving cone has a level
of its own (0: the silhouette's exact cone). Both only use the input image and its camera, so they
apply wherever the network does."""
from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping, Optional

import numpy as np
import torch
from scipy import ndimage
from torch.nn import functional as F

from svr.nmr.views import view_cameras

CARVES = ("none", "view", "view+mirror")


@dataclass(frozen=True)
class Calibration:
    """Post-processing of predicted SDF grids.

    Attributes:
        carve: "none"; "view": intersect with the input silhouette's cone; "view+mirror": also with
            the cone's mirror image across the plane ``mirror_axis`` = 0 through the origin.
        mirror_axis: the world axis (0 = x, 1 = y, 2 = z) of "view+mirror".
        level: world units added to the network's SDF (positive: the surface moves inwards).
        threshold: alpha at or above which an input pixel is silhouette.
        carve_level: world units added to the carving cone's field (0: the silhouette's exact cone;
            negative: a wider cone). Records written before this field existed carved with the
            level added to both, and ``from_dict`` reads them so.
    """

    carve: str = "none"
    mirror_axis: Optional[int] = None
    level: float = 0.0
    threshold: float = 0.5
    carve_level: float = 0.0

    def __post_init__(self) -> None:
        if self.carve not in CARVES:
            raise ValueError(f"carve must be one of {', '.join(CARVES)}, got {self.carve!r}")
        if self.carve == "view+mirror" and self.mirror_axis not in (0, 1, 2):
            raise ValueError(f"carve='view+mirror' needs mirror_axis 0, 1 or 2, got {self.mirror_axis!r}")
        for name in ("level", "carve_level"):
            if not math.isfinite(float(getattr(self, name))):
                raise ValueError(f"{name} must be a finite number, got {getattr(self, name)!r}")
        if not 0.0 < float(self.threshold) < 1.0:
            raise ValueError(f"threshold must lie in (0, 1), got {self.threshold!r}")

    @property
    def is_identity(self) -> bool:
        return self.carve == "none" and float(self.level) == 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], name: str = "calibration") -> "Calibration":
        """The inverse of ``to_dict``; raises ValueError naming ``name`` on unknown keys or values."""
        unknown = set(data) - {"carve", "mirror_axis", "level", "threshold", "carve_level"}
        if unknown:
            raise ValueError(f"{name}: unknown keys {sorted(unknown)}")
        fields = dict(data)
        fields.setdefault("carve_level", fields.get("level", 0.0))  # the older records' meaning
        try:
            return cls(**fields)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{name}: {err}") from None

    def describe(self) -> str:
        mirror = f" (mirror axis {'xyz'[self.mirror_axis]})" if self.carve == "view+mirror" else ""
        cone = f" (cone level {self.carve_level:+.4f})" if self.carve != "none" and self.carve_level != 0.0 else ""
        return f"carve {self.carve}{mirror}{cone}, level {self.level:+.4f}"

    def cone(self, images: torch.Tensor, views: Optional[torch.Tensor], resolution: int,
             half_side: float) -> Optional[torch.Tensor]:
        """The field this calibration carves with (``silhouette_cone_sdf``) for ``images`` (B, 4, S,
        S) RGBA taken from NMR views ``views`` (B,) (or (B, 2) rows of view and elevation), on the
        N^3 grid over ``[-half_side, half_side]^3``; None when it carves nothing, or without views
        (nothing can be carved)."""
        if self.carve == "none" or views is None:
            return None
        axis = self.mirror_axis if self.carve == "view+mirror" else None
        return silhouette_cone_sdf(images[:, 3], views, resolution, half_side, axis, self.threshold)

    def apply(self, sdf: torch.Tensor, cone: Optional[torch.Tensor]) -> torch.Tensor:
        """(B, N, N, N) SDF grids -> the calibrated grids: intersected with ``cone`` (``self.cone``
        of the images they were predicted from, its field raised by ``carve_level``; None: no
        carving), with the level added to the network's field."""
        out = sdf + float(self.level) if float(self.level) != 0.0 else sdf
        if cone is None:
            return out
        cone = cone.to(sdf)
        return torch.maximum(out, cone + float(self.carve_level) if float(self.carve_level) != 0.0 else cone)


def signed_pixel_distance(alpha: torch.Tensor, threshold: float = 0.5) -> torch.Tensor:
    """(B, H, W) alpha -> (B, H, W) signed distance (pixels) from each pixel centre to the
    silhouette's edge, taken half a pixel outside the silhouette's outer pixel centres: positive
    outside (alpha < threshold), negative inside."""
    masks = (alpha.detach().cpu().numpy() >= threshold)
    out = np.empty(masks.shape, np.float32)
    for i, inside in enumerate(masks):
        if not inside.any():
            out[i] = 1e6  # no silhouette: everything is outside
            continue
        if inside.all():
            out[i] = -1e6
            continue
        outside_d = ndimage.distance_transform_edt(~inside)  # to the nearest silhouette pixel
        inside_d = ndimage.distance_transform_edt(inside)   # to the nearest background pixel
        out[i] = np.where(inside, 0.5 - inside_d, outside_d - 0.5)
    return torch.from_numpy(out).to(alpha.device)


@functools.lru_cache(maxsize=64)
def _view_lookup(view: tuple[float, ...], size: int, resolution: int, half_side: float, flip_axis: Optional[int],
                 device: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where each sample of the N^3 grid (mirrored across ``flip_axis`` when not None) projects in
    the S x S image of ``view`` (an NMR view index, or (view, elevation): ``view_cameras``):
    ``grid_sample`` coordinates (1, 1, N^3, 2), the camera's ``pixel_angle`` (1,) (a pixel's
    world size per unit of depth) and each sample's depth (N^3,).
    The same for every image from that view, so it is computed once: projecting the grid for each
    image was most of an evaluation's prediction time."""
    axis = torch.linspace(-half_side, half_side, resolution, dtype=torch.float32, device=device)
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    if flip_axis is not None:
        flip = torch.ones(3, device=device)
        flip[flip_axis] = -1.0
        points = points * flip
    cams = view_cameras(torch.tensor([view] if len(view) == 2 else view, dtype=torch.float64), size)
    cams = cams.to(device, torch.float32)
    pix, depth = cams.project(points)
    grid = ((pix + 0.5) * (2.0 / size) - 1.0).unsqueeze(1)  # grid_sample's align_corners=False
    return grid, cams.pixel_angle, depth[0]


def silhouette_cone_sdf(alpha: torch.Tensor, views: torch.Tensor, resolution: int, half_side: float,
                        mirror_axis: Optional[int] = None, threshold: float = 0.5) -> torch.Tensor:
    """An SDF-like field (world units, positive outside) of the cone of rays through the input
    view's silhouette, sampled on the N^3 grid over ``[-half_side, half_side]^3``
    (renderer.SDFGrid layout): the pixel distance to the silhouette at each sample's projection,
    scaled by the pixel's size at the sample's depth. With ``mirror_axis`` the field of the sample's
    mirror image is taken too (the larger of the two: the intersection of the two cones).

    Args:
        alpha: (B, S, S) the input images' alpha.
        views: (B,) their NMR view indices, or (B, 2) rows of (view, elevation in degrees)
            (``svr.nmr.views.view_cameras``).
    Returns:
        (B, N, N, N) float32 on ``alpha``'s device.
    """
    b, size = alpha.shape[0], alpha.shape[-1]
    dist = signed_pixel_distance(alpha, threshold)[:, None]  # (B, 1, S, S)
    v = torch.as_tensor(views).detach().cpu().double()
    view_list = [tuple(row) for row in (v.reshape(-1, 2) if v.ndim == 2 else v.reshape(-1, 1)).tolist()]
    if len(view_list) != b:
        raise ValueError(f"views has {len(view_list)} entries for {b} images")
    out = torch.empty(b, resolution ** 3, dtype=torch.float32, device=alpha.device)
    key = (size, int(resolution), float(half_side))
    for view in sorted(set(view_list)):
        rows = [i for i, v in enumerate(view_list) if v == view]
        for flip_axis in (None,) + ((mirror_axis,) if mirror_axis is not None else ()):
            grid, pixel_per_depth, depth = _view_lookup(view, *key, flip_axis, str(alpha.device))
            d = F.grid_sample(dist[rows], grid.expand(len(rows), -1, -1, -1), mode="bilinear",
                              padding_mode="border", align_corners=False)[:, 0, 0] * depth * pixel_per_depth
            out[rows] = d if flip_axis is None else torch.maximum(out[rows], d)
    return out.reshape(b, resolution, resolution, resolution)


__all__ = ["CARVES", "Calibration", "signed_pixel_distance", "silhouette_cone_sdf"]
