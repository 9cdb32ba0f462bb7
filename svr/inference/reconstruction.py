"""Reconstructions of images by a loaded model: ``reconstruct_images`` predicts SDF grids
(``svr.inference.prediction``), extracts watertight meshes by marching cubes (closed at the box)
and renders previews from NMR views (``svr.nmr.views``); ``save_reconstruction`` writes one
(``<name>_sdf.npz``, ``<name>.ply``, ``<name>.obj``, ``<name>_views.png``, each atomically) and
``infer_files`` does both for image files (``svr.inference.images``) into a folder. The functions take
a ``LoadedModel``; turning a checkpoint path into one is the command's (``svr.infer``)."""
from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np
import torch
from tqdm.auto import tqdm

import renderer
from sdfcommon.numerics.meshing import sdf_to_mesh
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.outputs import ensure_output_dir, write_mesh, write_npz, write_png
from svr.inference.images import find_images, find_mask, load_image
from svr.inference.prediction import LoadedModel, check_input_views, check_model, predict
from svr.nmr.format import check_view_ids
from svr.nmr.views import PREVIEW_VIEWS, render_previews

PathLike = Union[str, os.PathLike]
OUTPUT_FORMATS = ("npz", "ply", "obj", "png")


@dataclass(frozen=True)
class Reconstruction:
    """One image's prediction, its mesh and renders.

    Attributes:
        values: (N, N, N) float32 CPU SDF (world units, renderer.SDFGrid layout).
        bbox_min, bbox_max: the grid's box (the first and last samples, world units, per axis).
        mesh: trimesh.Trimesh of the zero level set (closed at the box); empty if there is none.
        watertight: whether trimesh finds the mesh watertight (False for an empty mesh).
        renders: (K, S, S, 3) float32 CPU shaded renders from the NMR views ``views``.
        views: the NMR view indices of ``renders``.
    """

    values: torch.Tensor
    bbox_min: tuple[float, float, float]
    bbox_max: tuple[float, float, float]
    mesh: Any
    watertight: bool
    renders: Optional[torch.Tensor]
    views: tuple[int, ...]


def reconstruct_images(model: LoadedModel, images: torch.Tensor, views: Sequence[int] = PREVIEW_VIEWS,
                render_size: int = 128, batch_size: int = 16, backend: str = "auto",
                require_watertight: bool = False, names: Optional[Sequence[str]] = None,
                input_views=None) -> list[Reconstruction]:
    """Predicts SDF grids, extracts watertight meshes and renders previews for B images.

    Args:
        model: the network and its stage (``svr.inference.prediction.load_model``).
        images: (B, 4, 64, 64) float RGBA in [0, 1].
        views: NMR views of the preview renders (empty: no renders).
        render_size: side of the preview renders.
        require_watertight: raise instead of warning when a mesh is not watertight.
        names: per image, how warnings name it (default "image <b>").
        input_views: the NMR view index each image was taken from (one per image or one for all);
            needed by a network with a pixel-aligned head (``predict_sdf``'s ``views``).
    Returns:
        one Reconstruction per image.
    """
    m = check_model(model)
    views = check_view_ids(views)
    check_int(render_size, "render_size", minimum=1)
    grid = predict(m, images, batch_size, views=input_views)
    names = list(names) if names is not None else [f"image {b}" for b in range(grid.batch_size)]
    if len(names) != grid.batch_size:
        raise ValueError(f"names must have one entry per image ({grid.batch_size}), got {len(names)}")
    renders = None
    if views:
        renders = torch.cat([render_previews(renderer.SDFGrid(v, -m.half_side, m.half_side), views, render_size, backend)
                             for v in grid.values.split(batch_size)])
    values = grid.values.detach().float().cpu()
    lo = tuple(float(c) for c in grid.bbox_min.cpu())
    hi = tuple(float(c) for c in grid.bbox_max.cpu())
    out = []
    for b, v in enumerate(values):
        mesh = sdf_to_mesh(v, lo, hi, close=True)
        empty = len(mesh.faces) == 0
        tight = bool(not empty and mesh.is_watertight)
        if empty:
            warnings.warn(f"{names[b]}: the predicted SDF has no zero crossing: no surface, empty mesh",
                          RuntimeWarning, stacklevel=2)
        elif not tight:
            msg = f"{names[b]}: the extracted mesh is not watertight (trimesh.is_watertight is False)"
            if require_watertight:
                raise ValueError(msg)
            warnings.warn(msg, RuntimeWarning, stacklevel=2)
        out.append(Reconstruction(values=v, bbox_min=lo, bbox_max=hi, mesh=mesh, watertight=tight,
                                  renders=renders[b] if renders is not None else None,
                                  views=tuple(int(x) for x in views)))
    return out


def preview_picture(image: Optional[torch.Tensor], renders: Optional[torch.Tensor], gap: int = 4) -> np.ndarray:
    """One picture: the input's RGB and alpha (nearest-upscaled), then the renders, left to right.

    Args:
        image: (4, h, w) float RGBA in [0, 1] or None. renders: (K, S, S, 3) float in [0, 1] or None.
    Returns:
        (S, width, 3) float32 in [0, 1].
    """
    tiles = []
    size = renders.shape[1] if renders is not None and len(renders) else (image.shape[-1] if image is not None else 64)
    if image is not None:
        x = image.detach().float().cpu()[None]
        x = torch.nn.functional.interpolate(x, size=(size, size), mode="nearest")[0]
        tiles.append(x[:3].permute(1, 2, 0))
        tiles.append(x[3:4].permute(1, 2, 0).expand(size, size, 3))
    if renders is not None:
        tiles.extend(r.detach().float().cpu() for r in renders)
    if not tiles:
        raise ValueError("nothing to draw: give an image or renders")
    spacer = torch.full((size, gap, 3), 0.6)
    row = [tiles[0]]
    for t in tiles[1:]:
        row.extend([spacer, t])
    return torch.cat(row, dim=1).clamp(0, 1).numpy()


def save_reconstruction(rec: Reconstruction, out_dir: PathLike, name: str, input_image: Optional[torch.Tensor] = None,
                        formats: Sequence[str] = OUTPUT_FORMATS, meta: Optional[Mapping[str, str]] = None
                        ) -> dict[str, Path]:
    """Writes a Reconstruction (each file atomically): ``<name>_sdf.npz``, ``<name>.ply``,
    ``<name>.obj`` (skipped for an empty mesh), ``<name>_views.png``.

    Args:
        formats: any of ``OUTPUT_FORMATS``.
        meta: extra strings stored in the npz (e.g. checkpoint, stage).
    Returns:
        {format: path} of the files written.
    """
    check_formats(formats)
    folder = Path(out_dir)
    written: dict[str, Path] = {}
    if "npz" in formats:
        extra = {k: np.array(str(v)) for k, v in (meta or {}).items()}
        written["npz"] = write_npz(folder / f"{name}_sdf.npz", values=rec.values.numpy().astype(np.float32),
                                   bbox_min=np.asarray(rec.bbox_min, np.float32),
                                   bbox_max=np.asarray(rec.bbox_max, np.float32), **extra)
    if len(rec.mesh.faces):
        for fmt in ("ply", "obj"):
            if fmt in formats:
                written[fmt] = write_mesh(folder / f"{name}.{fmt}", rec.mesh)
    if "png" in formats:
        written["png"] = write_png(folder / f"{name}_views.png", preview_picture(input_image, rec.renders))
    return written


def check_formats(formats: Sequence[str]) -> list[str]:
    """Raises ValueError naming ``formats`` unless it is a list of ``OUTPUT_FORMATS``."""
    if isinstance(formats, str) or not isinstance(formats, Sequence) or any(f not in OUTPUT_FORMATS for f in formats):
        raise ValueError(f"formats must be a list among {list(OUTPUT_FORMATS)}, got {formats!r}")
    return list(formats)


def _unique_names(paths: Sequence[Path]) -> list[str]:
    seen: dict[str, int] = {}
    names = []
    for p in paths:
        n = seen.get(p.stem, 0)
        seen[p.stem] = n + 1
        names.append(p.stem if n == 0 else f"{p.stem}_{n}")
    return names


def infer_files(model: LoadedModel, images: Union[PathLike, Sequence[PathLike]], output_dir: PathLike,
                masks: Optional[Sequence[Optional[PathLike]]] = None, mask_suffix: str = "_mask",
                views: Sequence[int] = PREVIEW_VIEWS, render_size: int = 128, batch_size: int = 16,
                formats: Sequence[str] = OUTPUT_FORMATS, require_watertight: bool = False,
                backend: str = "auto", progress: bool = False, input_view: Optional[float] = None
                ) -> list[dict[str, Path]]:
    """Reads images (files or folders), reconstructs them and writes the results into ``output_dir``.

    Args:
        model: the network and its stage (``svr.inference.prediction.load_model``).
        images: an image file, a folder (every PNG/JPEG in it but masks) or a list of them.
        masks: one mask path (or None) per expanded image; default: ``<stem><mask_suffix>.*`` beside
            each image when it exists.
        input_view: the NMR view index (0..23, azimuth -15 * view degrees at 30 degrees elevation) of
            every image's camera; needed by a network with a pixel-aligned head.
        Others: see ``reconstruct_images`` and ``save_reconstruction``.
    Returns:
        per image, {format: path} of the files written (in the order of the expanded inputs).
    Raises:
        ValueError naming ``output_dir`` when it cannot be written (checked before any work), and
        the file of an unreadable image or mask.
    """
    # Every setting is checked before the first image is read (a bad one must not cost a model run).
    m = check_model(model)
    check_int(batch_size, "batch_size", minimum=1)
    check_int(render_size, "render_size", minimum=1)
    views = check_view_ids(views)
    check_input_views(input_view, 1, m.net.needs_views, "input_view")
    check_formats(formats)
    folder = ensure_output_dir(output_dir, "output_dir")
    paths = find_images(images, mask_suffix)
    if masks is not None and len(masks) != len(paths):
        raise ValueError(f"masks must have one entry per image ({len(paths)} images), got {len(masks)}")
    tensors = []
    for i, p in enumerate(paths):
        mask = masks[i] if masks is not None else find_mask(p, mask_suffix)
        tensors.append(load_image(p, mask, m.image_size))
    names = _unique_names(paths)
    meta = {"checkpoint": str(m.checkpoint) if m.checkpoint else "", "stage": m.stage, "output": m.output_name}
    results = []
    with tqdm(total=len(paths), desc="infer", unit="img", disable=not progress) as bar:
        for start in range(0, len(paths), batch_size):
            batch = torch.stack(tensors[start:start + batch_size])
            recs = reconstruct_images(m, batch, views, render_size, batch_size, backend, require_watertight,
                               names=[str(p) for p in paths[start:start + batch_size]], input_views=input_view)
            for k, rec in enumerate(recs):
                i = start + k
                results.append(save_reconstruction(rec, folder, names[i], tensors[i], formats,
                                                   {**meta, "image": str(paths[i])}))
            bar.update(len(recs))
    return results


__all__ = ["Reconstruction", "reconstruct_images", "preview_picture", "save_reconstruction", "infer_files", "check_formats",
           "OUTPUT_FORMATS"]
