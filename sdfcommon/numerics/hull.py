"""Silhouettes as fields in space: a shape seen from a camera with a given silhouette lies inside
that camera's cone of rays through the silhouette, and inside the intersection of the cones of all
its views (the visual hull). ``visual_hull`` samples that intersection as a signed field, positive
outside, which bounds any consistent shape's signed distance from below: the multi-view fit carves
with it (``mvr``), and the single-view code builds its NMR-camera cones on ``signed_pixel_distance``
(``svr.nmr.cones``)."""
from __future__ import annotations

import numpy as np
import torch
from scipy import ndimage
from torch.nn import functional as F

from renderer import Cameras


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


def visual_hull(pixel_distance: torch.Tensor, cameras: Cameras, points: torch.Tensor, chunk: int = 8) -> torch.Tensor:
    """The visual hull of V silhouettes as a field (world units, positive outside) at ``points``.

    Each view contributes the signed pixel distance (``signed_pixel_distance``) at the point's
    projection, times the width of a pixel at the point's depth: about the point's distance to that
    view's cone, exact in sign. The hull's field is the largest over the views (a point outside one
    cone is outside the hull). A point that projects outside an image takes the distance at the
    image's border; a view says nothing of a point behind its camera.

    Args:
        pixel_distance: (V, H, W) signed pixel distances of the views' silhouettes.
        cameras: (V,) the cameras that saw them (``image_size`` (H, W)).
        points: (P, 3) world points.
        chunk: views projected at once (bounds the memory to ``chunk * P`` samples).
    Returns:
        (P,) float32 on ``points``' device (``-inf`` where no view bounds a point).
    """
    v, h, w = pixel_distance.shape
    if cameras.batch_size != v or tuple(cameras.image_size) != (h, w):
        raise ValueError(f"{v} silhouettes of {h}x{w} pixels for {cameras.batch_size} cameras of "
                         f"{tuple(cameras.image_size)}")
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (P, 3), got {tuple(points.shape)}")
    scale = torch.tensor([2.0 / w, 2.0 / h], device=points.device)
    field = torch.full((points.shape[0],), -float("inf"), device=points.device)
    for start in range(0, v, chunk):
        cams = cameras[start:start + chunk]
        pix, depth = cams.project(points)
        grid = ((pix.float() + 0.5) * scale - 1.0).unsqueeze(1)  # grid_sample's align_corners=False
        d = F.grid_sample(pixel_distance[start:start + chunk, None].float().to(points.device), grid, mode="bilinear",
                          padding_mode="border", align_corners=False)[:, 0, 0]
        width = depth.float().clamp_min(0.0) * cams.pixel_angle.float().to(points.device)[:, None]
        d = torch.where(depth > 0, d * width, torch.full_like(d, -float("inf")))
        field = torch.maximum(field, d.amax(0))
    return field


__all__ = ["signed_pixel_distance", "visual_hull"]
