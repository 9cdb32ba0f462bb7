"""Where a reconstruction is wrong: its error coloured on the surfaces, seen from the rig's cameras.
Each surface is ray cast from a few cameras (``sdfcommon.numerics.raycast.mesh_caster``), and each
pixel's hit point gets its exact distance to the *other* surface
(``mvr.metrics.one_sided_distances``), the quantity whose maximum is the Hausdorff distance. The
picture has two rows: the target coloured by its distance to the reconstruction, which shows the
parts the reconstruction misses (a concavity filled in, a thin part lost), and the reconstruction
coloured by its distance to the target, which shows the parts it adds (a pocket no silhouette
carves, a bridge between limbs). The colour is Lambert shading (the reconstruction's own scene)
times a ramp from light grey (distance 0) through yellow to red (``vmax`` and beyond), so that the
eye goes to where the distance is large.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import torch
import trimesh

from renderer import Cameras, Scene, shade_lambert
from sdfcommon.numerics.raycast import mesh_caster
from sdfcommon.tooling.checks import check_positive
from sdfcommon.tooling.pictures import labelled_grid

from .metrics import one_sided_distances

# The ramp's stops: (fraction of vmax, RGB).
_RAMP = np.array([[0.0, 0.85, 0.85, 0.85], [0.25, 0.95, 0.9, 0.3], [0.6, 0.95, 0.5, 0.1], [1.0, 0.8, 0.0, 0.0]])


@dataclass(frozen=True)
class ErrorViews:
    """One surface seen from V cameras, with its distance to another surface.

    Attributes:
        colours: (V, H, W, 3) float32 RGB in [0, 1], white where rays miss.
        distances: (V, H, W) float64 distance of each pixel's hit point to the other surface (world
            units); NaN where rays miss.
    """

    colours: np.ndarray
    distances: np.ndarray


def error_colours(distances: np.ndarray, vmax: float) -> np.ndarray:
    """The ramp's colour of each distance (any shape S): (S..., 3) float in [0, 1]; distances at or
    above ``vmax`` are red, 0 light grey."""
    vmax = check_positive(vmax, "vmax")
    x = np.clip(np.asarray(distances, dtype=np.float64) / vmax, 0.0, 1.0)
    return np.stack([np.interp(x, _RAMP[:, 0], _RAMP[:, c]) for c in (1, 2, 3)], axis=-1)


def error_views(mesh: trimesh.Trimesh, other: trimesh.Trimesh, cameras: Cameras, scene: Scene,
                vmax: float) -> ErrorViews:
    """Renders ``mesh`` from ``cameras`` coloured by each visible point's distance to ``other``.

    Args:
        mesh: the surface seen. other: the surface measured to. Both in world coordinates.
        cameras: (V,) cameras (their image size sets H, W). scene: lights for the shading (its first
            light setting; the colour replaces the albedo).
        vmax: the distance shown fully red (world units).
    """
    cams = cameras.to(dtype=torch.float64, device="cpu")
    origins, directions = cams.rays()
    v, h, w, _ = directions.shape
    o = origins.reshape(-1, 3).numpy()
    d = directions.reshape(-1, 3).numpy()
    hits = mesh_caster(mesh.vertices, mesh.faces).first_hits(o, d)
    idx = np.nonzero(hits.hit)[0]
    points = o[idx] + hits.t[idx, None] * d[idx]
    normals = np.asarray(mesh.face_normals)[hits.face[idx]]
    eyes = cams.eye.numpy()[idx // (h * w)]
    grey = replace(scene, albedo=(1.0,), background=0.0)
    shade = shade_lambert(torch.from_numpy(normals), torch.from_numpy(points), torch.from_numpy(eyes),
                          grey).numpy()[:, :1]
    dist = np.full(v * h * w, np.nan)
    colours = np.ones((v * h * w, 3))
    if len(idx):
        dist[idx] = one_sided_distances(points, other)
        colours[idx] = np.clip(shade, 0.0, 1.0) * error_colours(dist[idx], vmax)
    return ErrorViews(colours=colours.reshape(v, h, w, 3).astype(np.float32), distances=dist.reshape(v, h, w))


def error_picture(target: trimesh.Trimesh, recon: trimesh.Trimesh, cameras: Cameras, scene: Scene,
                  vmax: float, view_names: Sequence[str]) -> np.ndarray:
    """The two rows (target coloured by its distance to the reconstruction, reconstruction by its
    distance to the target) over the views, labelled: an (H', W', 3) float32 array
    (``sdfcommon.tooling.pictures.labelled_grid``)."""
    if len(view_names) != cameras.batch_size:
        raise ValueError(f"need {cameras.batch_size} view names, got {len(view_names)}")
    tiles = np.stack([error_views(target, recon, cameras, scene, vmax).colours,
                      error_views(recon, target, cameras, scene, vmax).colours])  # (2, V, H, W, 3)
    # Crop every tile to the box where any of them shows a surface, so the shapes fill the tiles.
    busy = (tiles < 1.0).any(axis=(0, 1, 4))
    rows, cols = np.nonzero(busy)
    if len(rows):
        margin = 2
        r0, r1 = max(rows.min() - margin, 0), min(rows.max() + margin + 1, busy.shape[0])
        c0, c1 = max(cols.min() - margin, 0), min(cols.max() + margin + 1, busy.shape[1])
        tiles = tiles[:, :, r0:r1, c0:c1]
    return labelled_grid(tiles, ["target: distance to ours", "ours: distance to target"], list(view_names))
