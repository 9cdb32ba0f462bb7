"""NMR-style renders of a loaded mesh by ray casting (``sdfcommon.numerics.raycast``): the NMR cameras
(``renderer.Cameras.nmr``: elevation, distance and a 30 degree field of view, azimuth
``-360 k / V`` for view k), S x S rays per pixel through the centres of an S x S sub-pixel grid,
each hit shaded flat (its face's normal, turned towards the camera: both sides of a face are lit,
as Blender renders them) with the face's colour or its texture at the hit, under the project's
NMR light (``svr.data.procedural.appearance.NMR_LIGHTING``, as the procedural data); the samples
are averaged with a white background, and alpha is the fraction of samples that hit (coverage).
"""
from __future__ import annotations

import functools
from typing import Optional

import numpy as np
import torch

import renderer
from sdfcommon.numerics.raycast import RayCaster
from svr.data.build.meshes import LoadedMesh
from svr.data.procedural.appearance import NMR_LIGHTING, Lighting
from svr.nmr.views import view_cameras, view_rows


@functools.lru_cache(maxsize=4)
def nmr_sample_rays(image_size: int, supersample: int, views: int, distance: float,
                    elevation: float) -> tuple[np.ndarray, np.ndarray]:
    """Eyes (V, 3) and unit directions (V, H*S, W*S, 3), float32, of the S x S sub-pixel samples of
    ``views`` NMR cameras (view k at azimuth ``-360 k / views`` degrees; 24 views: NMR's)."""
    ids = [k * renderer.NMR_NUM_VIEWS / views for k in range(views)]
    cams = renderer.Cameras.nmr(ids, image_size=image_size * supersample, dtype=torch.float64,
                                distance=distance, elevation_deg=elevation)
    _, d = cams.rays()
    return cams.eye.numpy().astype(np.float32), d.numpy().astype(np.float32)


def camera_sample_rays(image_size: int, supersample: int, cameras: np.ndarray,
                       distance: float) -> tuple[np.ndarray, np.ndarray]:
    """As ``nmr_sample_rays`` for K cameras given as (K, 2) rows of (azimuth, elevation) in degrees
    (``svr.nmr.format.extra_view_files``' convention)."""
    cams = view_cameras(view_rows(cameras), image_size * supersample, torch.float64, distance=distance)
    _, d = cams.rays()
    return cams.eye.numpy().astype(np.float32), d.numpy().astype(np.float32)


def _albedo(mesh: LoadedMesh, face: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(K, 3) colour of K hits: the face colour, times the texture (nearest texel, wrapped UVs)."""
    albedo = mesh.face_colours[face]
    tex = mesh.face_texture[face]
    for k, image in enumerate(mesh.textures):
        sel = np.nonzero(tex == k)[0]
        if not len(sel):
            continue
        corners = mesh.faces[face[sel]]
        w1, w2 = u[sel, None].astype(np.float64), v[sel, None].astype(np.float64)
        uv = (1.0 - w1 - w2) * mesh.uv[corners[:, 0]] + w1 * mesh.uv[corners[:, 1]] + w2 * mesh.uv[corners[:, 2]]
        h, w = image.shape[:2]
        col = np.floor((uv[:, 0] % 1.0) * w).astype(np.int64).clip(0, w - 1)
        row = np.floor((1.0 - uv[:, 1] % 1.0) * h).astype(np.int64).clip(0, h - 1)
        albedo[sel] = albedo[sel] * image[row, col]
    return albedo


def render_mesh(mesh: LoadedMesh, caster: RayCaster, normals: np.ndarray, image_size: int, supersample: int,
                views: int, distance: float, elevation: float, lighting: Lighting = NMR_LIGHTING,
                cameras: Optional[np.ndarray] = None) -> np.ndarray:
    """The views of a mesh (see the module docstring).

    Args:
        mesh: a normalised mesh; caster: its ray caster; normals: (F, 3) its face normals.
        image_size: H = W. supersample: S. views, distance, elevation: the cameras (NMR: 24 views,
            distance 2.732, elevation 30 degrees; configs/build.yaml).
        cameras: instead of ``views`` and ``elevation``, (K, 2) rows of (azimuth, elevation) in
            degrees (``camera_sample_rays``).
    Returns:
        (V, 4, H, W) uint8 RGBA: RGB composited on white, alpha = coverage.
    """
    if cameras is None:
        eyes, dirs = nmr_sample_rays(image_size, supersample, views, distance, elevation)
    else:
        eyes, dirs = camera_sample_rays(image_size, supersample, cameras, distance)
    v, hs, ws = dirs.shape[:3]
    d = dirs.reshape(-1, 3)
    hits = caster.first_hits(np.repeat(eyes, hs * ws, axis=0), d)
    hit = np.nonzero(hits.hit)[0]
    face = hits.face[hit]
    back = np.einsum("ij,ij->i", normals[face], d[hit]) > 0  # seen from behind: lit on that side
    rgb = np.ones((len(d), 3), dtype=np.float32)
    plain = mesh.face_texture[face] < 0
    if plain.any():
        # Flat shading: the colour of an untextured face's side is computed once, not per sample.
        key = face[plain] * 2 + back[plain]
        sides, which = np.unique(key, return_inverse=True)
        side_normals = normals[sides // 2] * np.where(sides % 2 == 1, -1.0, 1.0)[:, None]
        rgb[hit[plain]] = lighting.shade(side_normals, mesh.face_colours[sides // 2])[which]
    if not plain.all():
        tex = ~plain
        n = normals[face[tex]] * np.where(back[tex], -1.0, 1.0)[:, None]
        rgb[hit[tex]] = lighting.shade(n, _albedo(mesh, face[tex], hits.barycentric[hit[tex], 1],
                                                       hits.barycentric[hit[tex], 2]))
    s = supersample
    cover = np.zeros((len(d), 1), dtype=np.float32)
    cover[hit] = 1.0
    samples = np.concatenate([rgb, cover], 1).reshape(v, image_size, s, image_size, s, 4)
    img = samples.mean(axis=(2, 4), dtype=np.float64).transpose(0, 3, 1, 2)
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)


__all__ = ["nmr_sample_rays", "camera_sample_rays", "render_mesh"]
