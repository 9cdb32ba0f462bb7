"""Checkpoint inference: images -> SDF grids, watertight meshes and renders (``python -m svr.infer``).

Command line (configs/infer.yaml; hydra overrides)::

    python -m svr.infer ckpt_path=RUN/joint/checkpoints/best.ckpt images=photo.png
    python -m svr.infer ckpt_path=X.ckpt images=[a.png,b.png] output_dir=out/ device=cpu
    python -m svr.infer ckpt_path=X.ckpt images=folder/          # every PNG/JPEG in it

Per input image ``<stem>`` it writes into ``output_dir`` (each file atomically):

* ``<stem>_sdf.npz``: ``values`` (N, N, N) float32 SDF (world units) in renderer.SDFGrid's layout
  (``values[i, j, k]`` at world ``(x_i, y_j, z_k)``, samples on the box faces, y up, the NMR
  ShapeNet frame), ``bbox_min`` / ``bbox_max`` (3,) float32, ``stage`` and ``checkpoint``;
* ``<stem>.ply``, ``<stem>.obj``: the zero level set by marching cubes (``sdfcommon.numerics.meshing.sdf_to_mesh``,
  closed at the box), checked watertight with trimesh;
* ``<stem>_views.png``: the network's input (RGB, alpha) beside renders of the prediction from a
  few NMR views (``renderer.render`` with ``renderer.Cameras.nmr``).

Inputs are RGBA (alpha = the object's silhouette), or RGB/grey with a mask file (``masks=[...]``, or
``<stem>_mask.png`` beside the image). Images are read like the dataset's (``svr.data.nmr.
images_to_float``: RGB on white) and resized to the network's 64^2 with a warning. A silhouette that
cannot be an object on a background is refused (``check_silhouette``): a fully transparent image,
or an inverted mask (opaque along the whole border).

The output folder is ``output_dir`` (hydra's run folder and its ``.hydra/`` record go there too;
nothing is made in the working directory), else ``outputs/infer/<time>``. A mistake in the settings
or files is one line ``sdfdiff-infer: error: ...`` with exit status 2 (``sdfcommon.tooling.commands``).

Python API (in-memory tensors; loading and predicting live in ``svr.inference.prediction``, the preview
renders in ``svr.view_renders``)::

    model = svr.inference.prediction.load_model("best.ckpt", device="cpu")
    grids = svr.inference.prediction.predict(model, images)   # (B, 4, 64, 64) -> renderer.SDFGrid (B, N, N, N)
    recs = reconstruct(model, images)         # + meshes, watertight flags, renders
    save_reconstruction(recs[0], "out", "name", input_image=images[0])
"""
from __future__ import annotations

import logging
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np
import torch

import renderer
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.commands import config_bool, config_int, config_ints, config_value, hydra_entry
from sdfcommon.tooling.outputs import ensure_output_dir

from svr.data.nmr import check_view_ids
from svr.inference.images import find_images, find_mask, load_image
from svr.inference.prediction import ModelLike, as_model, load_model, predict
from svr.view_renders import PREVIEW_VIEWS, render_previews

log = logging.getLogger(__name__)

PathLike = Union[str, os.PathLike]
OUTPUT_FORMATS = ("npz", "ply", "obj", "png")


# ------------------------------------------------------------------------------------------------
# Reconstructions


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


def reconstruct(model: ModelLike, images: torch.Tensor, views: Sequence[int] = PREVIEW_VIEWS,
                render_size: int = 128, batch_size: int = 16, backend: str = "auto",
                require_watertight: bool = False, names: Optional[Sequence[str]] = None) -> list[Reconstruction]:
    """Predicts SDF grids, extracts watertight meshes and renders previews for B images.

    Args:
        model: LoadedModel, SVRNet or checkpoint path.
        images: (B, 4, 64, 64) float RGBA in [0, 1].
        views: NMR views of the preview renders (empty: no renders).
        render_size: side of the preview renders.
        require_watertight: raise instead of warning when a mesh is not watertight.
        names: per image, how warnings name it (default "image <b>").
    Returns:
        one Reconstruction per image.
    """
    from sdfcommon.numerics.meshing import sdf_to_mesh

    views = check_view_ids(views)
    check_int(render_size, "render_size", minimum=1)
    m = as_model(model)
    grid = predict(m, images, batch_size)
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
    from sdfcommon.tooling.outputs import write_mesh, write_npz, write_png

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


def infer_files(model: ModelLike, images: Union[PathLike, Sequence[PathLike]], output_dir: PathLike,
                masks: Optional[Sequence[Optional[PathLike]]] = None, mask_suffix: str = "_mask",
                views: Sequence[int] = PREVIEW_VIEWS, render_size: int = 128, batch_size: int = 16,
                formats: Sequence[str] = OUTPUT_FORMATS, require_watertight: bool = False,
                backend: str = "auto", progress: bool = False) -> list[dict[str, Path]]:
    """Reads images (files or folders), reconstructs them and writes the results into ``output_dir``.

    Args:
        masks: one mask path (or None) per expanded image; default: ``<stem><mask_suffix>.*`` beside
            each image when it exists.
        Others: see ``reconstruct`` and ``save_reconstruction``.
    Returns:
        per image, {format: path} of the files written (in the order of the expanded inputs).
    Raises:
        ValueError naming ``output_dir`` when it cannot be written (checked before any work), and
        the file of an unreadable image or mask.
    """
    from tqdm.auto import tqdm

    # Every setting is checked before the first image is read (a bad one must not cost a model run).
    check_int(batch_size, "batch_size", minimum=1)
    check_int(render_size, "render_size", minimum=1)
    views = check_view_ids(views)
    check_formats(formats)
    folder = ensure_output_dir(output_dir, "output_dir")
    paths = find_images(images, mask_suffix)
    if masks is not None and len(masks) != len(paths):
        raise ValueError(f"masks must have one entry per image ({len(paths)} images), got {len(masks)}")
    m = as_model(model)
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
            recs = reconstruct(m, batch, views, render_size, batch_size, backend, require_watertight,
                               names=[str(p) for p in paths[start:start + batch_size]])
            for k, rec in enumerate(recs):
                i = start + k
                results.append(save_reconstruction(rec, folder, names[i], tensors[i], formats,
                                                   {**meta, "image": str(paths[i])}))
            bar.update(len(recs))
    return results


# ------------------------------------------------------------------------------------------------
# Entry point

def run(cfg) -> list[dict[str, Path]]:
    """The body of ``main``: a composed configs/infer.yaml -> ``infer_files``; prints what it wrote.

    The output folder is ``output_dir``, else hydra's run folder (infer.yaml makes them one).
    """
    from hydra.core.hydra_config import HydraConfig

    settings = dict(masks=config_value(cfg, "masks"), mask_suffix=str(config_value(cfg, "mask_suffix") or ""),
                    views=check_view_ids(config_ints(cfg, "views")),
                    render_size=config_int(cfg, "render_size", minimum=1),
                    batch_size=config_int(cfg, "batch_size", minimum=1),
                    formats=check_formats(config_value(cfg, "formats")),
                    require_watertight=config_bool(cfg, "require_watertight"),
                    backend=str(config_value(cfg, "backend")), progress=config_bool(cfg, "progress"))
    out = config_value(cfg, "output_dir") or HydraConfig.get().runtime.output_dir
    folder = ensure_output_dir(out, "output_dir")
    model = load_model(config_value(cfg, "ckpt_path"), config_value(cfg, "device"))
    print(f"checkpoint {model.checkpoint} ({model.stage} stage, {model.output_name} output) on {model.device}")
    results = infer_files(model, config_value(cfg, "images"), folder, **settings)
    for files in results:
        print("wrote " + ", ".join(str(p) for p in files.values()))
    print(f"{len(results)} image(s) -> {folder}")
    return results


main = hydra_entry("sdfdiff-infer", "infer", run)


if __name__ == "__main__":
    main()


__all__ = ["Reconstruction", "reconstruct", "preview_picture", "save_reconstruction", "infer_files", "check_formats",
           "run", "main", "OUTPUT_FORMATS"]
