"""Silhouette cones: the rays through a silhouette seen from an NMR camera, as a field on the
network's grid. A shape seen with that silhouette lies inside its cone, so the cone's field bounds
the shape's signed distance from below (``sdf >= cone`` at every point). The calibration carves
predictions with the input view's cone (``svr.inference.calibration``); the hull loss holds
training predictions inside the cones of their supervised views (``svr.losses.hull_loss``). The
pixel distances come from ``sdfcommon.numerics.hull``, which builds the same field for any cameras
(the multi-view fit's visual hull)."""
from __future__ import annotations

import functools
from typing import Optional

import torch

from sdfcommon.numerics.hull import cone_distances, project_to_images, signed_pixel_distance
from sdfcommon.tooling.checks import check_int
from svr.nmr.views import view_cameras


@functools.lru_cache(maxsize=128)
def _view_lookup(view: tuple[float, ...], size: int, resolution: int, half_side: float, flip_axis: Optional[int],
                 device: str, stride: int = 1) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where each sample of the N^3 grid (every ``stride``-th along each axis; mirrored across
    ``flip_axis`` when not None) projects in the S x S image of ``view`` (an NMR view index, or
    (view, elevation): ``view_cameras``): ``project_to_images``'s ``grid_sample`` coordinates
    (1, 1, M, 2), the samples' depths (1, M) and the camera's pixel angle (1, 1). The same for every
    image from that view, so it is computed once: projecting the grid for each image was most of an
    evaluation's prediction time."""
    axis = torch.linspace(-half_side, half_side, resolution, dtype=torch.float32, device=device)[::stride]
    points = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    if flip_axis is not None:
        flip = torch.ones(3, device=device)
        flip[flip_axis] = -1.0
        points = points * flip
    cams = view_cameras(torch.tensor([view] if len(view) == 2 else view, dtype=torch.float64), size)
    return project_to_images(cams.to(device, torch.float32), points)


def silhouette_cone_sdf(alpha: torch.Tensor, views: torch.Tensor, resolution: int, half_side: float,
                        mirror_axis: Optional[int] = None, threshold: float = 0.5, stride: int = 1) -> torch.Tensor:
    """An SDF-like field (world units, positive outside) of the cone of rays through each image's
    silhouette, sampled on the N^3 grid over ``[-half_side, half_side]^3`` (renderer.SDFGrid
    layout): the pixel distance to the silhouette at each sample's projection, scaled by the pixel's
    size at the sample's depth. With ``mirror_axis`` the field of the sample's mirror image is taken
    too (the larger of the two: the intersection of the two cones).

    Args:
        alpha: (B, S, S) the images' alpha.
        views: (B,) their NMR view indices, or (B, 2) rows of (view, elevation in degrees)
            (``svr.nmr.views.view_cameras``).
        stride: sample every ``stride``-th grid point along each axis (the grid's first sample
            included): a coarser field for a cheaper loss.
    Returns:
        (B, n, n, n) float32 on ``alpha``'s device, ``n = ceil(N / stride)``.
    """
    check_int(stride, "stride", minimum=1)
    b, size = alpha.shape[0], alpha.shape[-1]
    dist = signed_pixel_distance(alpha, threshold)  # (B, S, S)
    v = torch.as_tensor(views).detach().cpu().double()
    view_list = [tuple(row) for row in (v.reshape(-1, 2) if v.ndim == 2 else v.reshape(-1, 1)).tolist()]
    if len(view_list) != b:
        raise ValueError(f"views has {len(view_list)} entries for {b} images")
    n = len(range(0, int(resolution), stride))
    out = torch.empty(b, n ** 3, dtype=torch.float32, device=alpha.device)
    key = (size, int(resolution), float(half_side))
    for view in sorted(set(view_list)):
        rows = [i for i, v in enumerate(view_list) if v == view]
        for flip_axis in (None,) + ((mirror_axis,) if mirror_axis is not None else ()):
            grid, depth, pixel_angle = _view_lookup(view, *key, flip_axis, str(alpha.device), stride)
            k = len(rows)
            d = cone_distances(dist[rows], grid.expand(k, -1, -1, -1), depth.expand(k, -1), pixel_angle.expand(k, -1))
            out[rows] = d if flip_axis is None else torch.maximum(out[rows], d)
    return out.reshape(b, n, n, n)


__all__ = ["silhouette_cone_sdf"]
