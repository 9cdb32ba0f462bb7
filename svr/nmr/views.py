"""Predicted SDF grids rendered from NMR views: prediction -> renders. One function,
``render_views``, renders B grids each from its own V NMR views (``renderer.Cameras.nmr``) with a
scene whose effects decide which passes run. Training's image loss uses it with gradients and the
dataset's scene; ``render_previews`` is the same call without gradients and with a neutral grey
preview scene, for the pictures of inference and the demo.
"""
from __future__ import annotations

from typing import Optional, Sequence

import torch

import renderer
from sdfcommon.numerics.regularisers import check_grid
from sdfcommon.tooling.checks import check_int, check_shape

from svr.nmr.format import check_view_ids

PREVIEW_VIEWS = (0, 6, 12, 18)  # NMR views: azimuth 0, -90, -180, -270 degrees
# The renders of the prediction: a neutral grey material lit from each camera (every view alike).
PREVIEW_SCENE = renderer.Scene(effects=("shading",), lights=(), camera_light=0.75, camera_light_falloff=False,
                               ambient=0.25, albedo=(0.8, 0.8, 0.8), background=1.0)


def view_rows(angles) -> torch.Tensor:
    """(N, 2) float64 rows of (view, elevation) for ``view_cameras`` from (N, 2) rows of (azimuth,
    elevation) in degrees (``svr.nmr.format.extra_view_files``' convention): the view coordinate
    is ``-azimuth / 15``, taken modulo 24."""
    a = torch.as_tensor(angles, dtype=torch.float64).reshape(-1, 2)
    return torch.stack([torch.remainder(-a[:, 0] / 15.0, float(renderer.NMR_NUM_VIEWS)), a[:, 1]], dim=1)


def view_cameras(views: torch.Tensor, image_size: int = 64, dtype: torch.dtype = torch.float32,
                 device=None, distance: float = renderer.NMR_DISTANCE) -> renderer.Cameras:
    """The cameras of N views given as NMR view coordinates.

    Args:
        views: (N,) view indices (azimuth ``-15 * view`` degrees, fractional allowed) at the NMR
            elevation (30 degrees), or (N, 2) rows of (view, elevation in degrees): views the
            dataset's 24 do not hold, as the extra training views (``svr.data.datasets``) have.
        distance: the eye's distance from the origin (NMR's 2.732).
    Returns:
        ``renderer.Cameras.nmr`` of those views (NMR field of view).
    """
    v = torch.as_tensor(views).detach().cpu()
    if v.ndim == 2 and v.shape[1] == 2:
        cams = renderer.Cameras.nmr(v[:, 0], image_size=image_size, dtype=dtype, distance=distance,
                                    elevation_deg=v[:, 1])
    elif v.ndim == 1:
        cams = renderer.Cameras.nmr(v, image_size=image_size, dtype=dtype, distance=distance)
    else:
        raise ValueError(f"views must be (N,) NMR view indices or (N, 2) rows of (view, elevation), got shape "
                         f"{tuple(v.shape)}")
    return cams.to(device) if device is not None else cams


def render_views(
    sdf: torch.Tensor,
    half_side: float,
    view_ids: torch.Tensor,
    scene: renderer.Scene,
    image_size: int = 64,
    trace_settings: renderer.TraceSettings = renderer.TraceSettings(),
    backend: str = "auto",
) -> tuple[Optional[torch.Tensor], Optional[torch.Tensor]]:
    """Renders each of B SDF grids from its V NMR views.

    Args:
        sdf: (B, N, N, N) SDF over ``[-half_side, half_side]^3`` (world units, NMR ShapeNet frame).
        view_ids: (B, V) NMR view indices (``renderer.Cameras.nmr``), or (B, V, 2) rows of (view,
            elevation in degrees) (``view_cameras``).
        scene: renderer.Scene (its effects decide which passes run).
        image_size: render side H = W.
    Returns:
        silhouettes (B, V, H, W) (None unless the scene asks for them) and colours (B, V, C, H, W)
        (None unless the scene shades).
    """
    check_grid(sdf)
    check_shape(view_ids, "view_ids", f"{sdf.shape[0]}, V" if view_ids.ndim < 3 else f"{sdf.shape[0]}, V, 2")
    check_int(image_size, "image_size", minimum=1)
    b, v = view_ids.shape[:2]
    grid = renderer.SDFGrid(sdf, -float(half_side), float(half_side))
    cams = view_cameras(view_ids.reshape(b * v, *view_ids.shape[2:]), image_size, sdf.dtype, sdf.device)
    out = renderer.render(grid, cams, scene, trace_settings, backend)
    sil = out.silhouette.reshape(b, v, image_size, image_size) if out.silhouette is not None else None
    colours = None
    if out.image is not None:
        colours = out.image.reshape(b, v, image_size, image_size, -1).permute(0, 1, 4, 2, 3)
    return sil, colours


@torch.no_grad()
def render_previews(grid: renderer.SDFGrid, views: Sequence[int] | torch.Tensor = PREVIEW_VIEWS, image_size: int = 128,
                    backend: str = "auto") -> torch.Tensor:
    """Shaded renders of each grid from NMR ``views`` (``PREVIEW_SCENE``: grey, white background).

    Args:
        grid: B SDF grids over a cube centred at the origin (the network's box).
        views: the same K view indices 0..23 for every grid, or a (B, K) tensor of each grid's own
            (fractional allowed), or a (B, K, 2) tensor of (view, elevation) rows.
    Returns:
        (B, K, S, S, 3) float32 CPU in [0, 1].
    """
    if isinstance(views, torch.Tensor) and views.ndim in (2, 3):
        check_shape(views, "views", f"{grid.batch_size}, K" + (", 2" if views.ndim == 3 else ""))
        if not bool(torch.isfinite(views).all()):
            raise ValueError("views must be finite NMR view indices")
        ids = views.detach().double().cpu()
    else:
        ids = torch.tensor(list(check_view_ids(views, allow_empty=False)), dtype=torch.long).repeat(grid.batch_size, 1)
    half = float(grid.bbox_max[0])
    if not (torch.allclose(grid.bbox_max, torch.full_like(grid.bbox_max, half))
            and torch.allclose(grid.bbox_min, torch.full_like(grid.bbox_min, -half))):
        raise ValueError(f"grid must span a cube centred at the origin (the network's box), got "
                         f"{grid.bbox_min.tolist()} .. {grid.bbox_max.tolist()}")
    _, colours = render_views(grid.values, half, ids, PREVIEW_SCENE, image_size, backend=backend)
    return colours.permute(0, 1, 3, 4, 2).float().clamp(0, 1).cpu()



def sample_grid(pixels: torch.Tensor, image_size: int) -> torch.Tensor:
    """Continuous pixel coordinates (..., 2) (``renderer.Cameras.project``: integral at pixel
    centres) -> ``F.grid_sample`` coordinates in [-1, 1] for an image of side ``image_size``
    (``align_corners=False``)."""
    return (pixels + 0.5) * (2.0 / image_size) - 1.0

__all__ = ["view_rows", "view_cameras", "render_views", "render_previews", "sample_grid", "PREVIEW_SCENE",
           "PREVIEW_VIEWS"]
