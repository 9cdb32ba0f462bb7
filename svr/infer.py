"""Checkpoint inference: images -> SDF grids, watertight meshes and renders (``python -m svr.infer``).

Command line (configs/infer.yaml; hydra overrides)::

    python -m svr.infer ckpt_path=RUN/joint/checkpoints/best.ckpt images=photo.png
    python -m svr.infer ckpt_path=X.ckpt images=[a.png,b.png] output_dir=out/ device=cpu
    python -m svr.infer ckpt_path=X.ckpt images=folder/          # every PNG/JPEG in it

Per input image ``<stem>`` it writes into ``output_dir`` (each file atomically):

* ``<stem>_sdf.npz``: ``values`` (N, N, N) float32 SDF (world units) in renderer.SDFGrid's layout
  (``values[i, j, k]`` at world ``(x_i, y_j, z_k)``, samples on the box faces, y up, the NMR
  ShapeNet frame), ``bbox_min`` / ``bbox_max`` (3,) float32, ``stage`` and ``checkpoint``;
* ``<stem>.ply``, ``<stem>.obj``: the zero level set by marching cubes (``sdfcommon.geometry.sdf_to_mesh``,
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
or files is one line ``sdfdiff-infer: error: ...`` with exit status 2 (``sdfcommon.cli``).

Python API (in-memory tensors)::

    model = load_model("best.ckpt", device="cpu")
    grids = predict(model, images)            # images (B, 4, 64, 64) -> renderer.SDFGrid (B, N, N, N)
    recs = reconstruct(model, images)         # + meshes, watertight flags, renders
    save_reconstruction(recs[0], "out", "name", input_image=images[0])
"""
from __future__ import annotations

import logging
import os
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np
import torch

import renderer
from sdfcommon.outputs import remove_stale_temporaries
from sdfcommon.checks import check_int
from sdfcommon.cli import config_bool, config_int, config_ints, config_value, hydra_entry
from sdfcommon.serialization import scrub_unsafe_advice

from .data.nmr import NUM_VIEWS, check_view_ids, images_to_float
from .models.network import SVRNet, SVRPrediction

log = logging.getLogger(__name__)

PathLike = Union[str, os.PathLike]
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
OUTPUT_FORMATS = ("npz", "ply", "obj", "png")
DEFAULT_VIEWS = (0, 6, 12, 18)  # NMR views: azimuth 0, -90, -180, -270 degrees
# The renders of the prediction: a neutral grey material lit from each camera (every view alike).
PREVIEW_SCENE = renderer.Scene(effects=("shading",), lights=(), camera_light=0.75, camera_light_falloff=False,
                               ambient=0.25, albedo=(0.8, 0.8, 0.8), background=1.0)


# ------------------------------------------------------------------------------------------------
# Files (each written atomically by sdfcommon.outputs: temporary file beside it, then os.replace)


def ensure_output_dir(path: PathLike, argument: str = "output_dir") -> Path:
    """Creates the folder if needed and checks that files can be written into it, before any work.

    Raises:
        ValueError naming ``argument`` and the folder when it cannot be created or written.
    """
    folder = Path(path).expanduser()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test.", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        raise ValueError(f"{argument}: cannot write to the folder {folder} ({err.strerror or err})") from None
    remove_stale_temporaries(folder)  # what a run killed mid-write (kill -9) left
    return folder


# ------------------------------------------------------------------------------------------------
# Models


def resolve_device(device: Union[str, torch.device, None] = "auto") -> torch.device:
    """"auto" (or None): CUDA when available, else the CPU; otherwise the named device, checked.

    Raises:
        ValueError naming ``device`` when it is unknown or CUDA is asked for but not available.
    """
    if device is None or (isinstance(device, str) and device == "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got {device!r}") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device={str(device)!r} but CUDA is not available here (use device=cpu or auto)")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"device={str(device)!r} but only {torch.cuda.device_count()} CUDA device(s) exist")
    elif dev.type != "cpu":
        raise ValueError(f"device must be 'auto', 'cpu', 'cuda' or 'cuda:N', got {device!r}")
    return dev


@dataclass(frozen=True)
class LoadedModel:
    """A trained network ready for inference.

    Attributes:
        net: the SVRNet, in eval mode, on ``device``.
        stage: the training stage of the checkpoint ("coarse", "refine", "joint"); a "coarse"
            checkpoint's refiner is untrained, so its output is the coarse SDF.
        checkpoint: the file it came from (None for a network given directly).
        categories: the training data's (category id, name) pairs, when the checkpoint has them.
    """

    net: SVRNet
    stage: str = "joint"
    checkpoint: Optional[Path] = None
    categories: Optional[tuple[tuple[str, str], ...]] = None

    @property
    def device(self) -> torch.device:
        return next(self.net.parameters()).device

    @property
    def uses_refiner(self) -> bool:
        """Whether the final output is the refined SDF (every stage but "coarse")."""
        return self.stage != "coarse"

    @property
    def half_side(self) -> float:
        return self.net.half_side

    @property
    def grid_resolution(self) -> int:
        """N of the N^3 SDF grids the network outputs."""
        return int(self.net.decoder.grid_resolution)

    @property
    def image_size(self) -> int:
        return int(getattr(self.net.encoder, "image_size", 64))

    @property
    def output_name(self) -> str:
        return "refined" if self.uses_refiner else "coarse"


ModelLike = Union[LoadedModel, SVRNet, str, os.PathLike]


def load_model(ckpt_path: PathLike, device: Union[str, torch.device, None] = "auto") -> LoadedModel:
    """Loads one of our checkpoints (made on a CPU or a GPU) onto ``device`` for inference.

    The network is rebuilt from the model config stored in the checkpoint
    (``svr.models.module.load_network``), so no config is needed here.

    Raises:
        FileNotFoundError naming the file; ValueError naming the file when it is corrupt, truncated
        or not an SDFDiff single-view checkpoint, and naming ``device`` when that is unusable.
    """
    from .models.module import load_network

    if ckpt_path is None or str(ckpt_path).strip() in ("", "???"):
        raise ValueError("ckpt_path must name a checkpoint file (e.g. ckpt_path=RUN/joint/checkpoints/best.ckpt)")
    dev = resolve_device(device)
    path = Path(ckpt_path).expanduser()
    if path.is_dir():
        raise ValueError(f"ckpt_path: {path} is a folder, not a checkpoint file")
    try:
        net, meta = load_network(path, map_location=dev)
    except FileNotFoundError as err:
        raise FileNotFoundError(f"ckpt_path: {err}") from None
    except ValueError as err:
        raise ValueError(f"ckpt_path: {scrub_unsafe_advice(str(err))}") from None
    cats = meta.get("categories")
    return LoadedModel(net=net, stage=str(meta["stage"]), checkpoint=path,
                       categories=tuple((str(c), str(n)) for c, n in cats) if cats else None)


def as_model(model: ModelLike, device: Union[str, torch.device, None] = None) -> LoadedModel:
    """A LoadedModel from a LoadedModel, a bare SVRNet (treated as fully trained) or a checkpoint
    path (loaded onto ``device``, "auto" when None)."""
    if isinstance(model, LoadedModel):
        return model
    if isinstance(model, SVRNet):
        return LoadedModel(net=model.eval())
    if isinstance(model, (str, os.PathLike)):
        return load_model(model, "auto" if device is None else device)
    raise TypeError(f"model must be a LoadedModel, an SVRNet or a checkpoint path, got {type(model).__name__}")


def check_images(images: torch.Tensor, image_size: int = 64, name: str = "images") -> torch.Tensor:
    """Validates network inputs: (B, 4, S, S) (or one (4, S, S)) float RGBA in [0, 1].

    Returns:
        (B, 4, S, S) float32 tensor (same device).
    """
    if not isinstance(images, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(images).__name__}")
    x = images.unsqueeze(0) if images.ndim == 3 else images
    if x.ndim != 4 or tuple(x.shape[1:]) != (4, image_size, image_size):
        raise ValueError(f"{name} must have shape (B, 4, {image_size}, {image_size}) (RGBA in [0, 1]), "
                         f"got {tuple(images.shape)}; load_image() reads and resizes files")
    if x.shape[0] == 0:
        raise ValueError(f"{name} must hold at least one image")
    if not x.is_floating_point():
        raise TypeError(f"{name} must be a float tensor in [0, 1], got {x.dtype}")
    if not bool(torch.isfinite(x).all()) or float(x.min()) < 0.0 or float(x.max()) > 1.0:
        raise ValueError(f"{name} must hold finite values in [0, 1]")
    return x.float()


@torch.no_grad()
def predict_sdf(model: ModelLike, images: torch.Tensor, batch_size: int = 64,
                refine: Optional[bool] = None, clip: bool = True) -> SVRPrediction:
    """The network's coarse and (unless the model is a coarse-stage one) refined SDFs.

    Args:
        model: LoadedModel, SVRNet or checkpoint path.
        images: (B, 4, 64, 64) float RGBA in [0, 1], RGB on white (as the datasets give them).
        batch_size: images per forward pass.
        refine: run the refiner (default: ``model.uses_refiner``).
        clip: intersect the shapes with the cube the objects are normalised into
            (``svr.geometry.clip_to_box``), so none reaches past the benchmark's voxel grid. Every
            output of this module and ``svr.evaluate`` goes through it.
    Returns:
        SVRPrediction: ``coarse`` and ``refined`` (None without the refiner), (B, N, N, N) float32
        on the model's device, over the box ``[-half_side, half_side]^3`` (world units).
    """
    m = as_model(model)
    check_int(batch_size, "batch_size", minimum=1)
    x = check_images(images, m.image_size)
    use_refiner = m.uses_refiner if refine is None else bool(refine)
    m.net.eval()
    coarse, refined = [], []
    for chunk in x.split(batch_size):
        out = m.net(chunk.to(m.device, non_blocking=True), refine=use_refiner)
        coarse.append(out.coarse)
        if out.refined is not None:
            refined.append(out.refined)
    coarse_t = torch.cat(coarse)
    refined_t = torch.cat(refined) if use_refiner else None
    if clip:
        from .geometry import clip_to_box

        hs = m.half_side
        coarse_t = clip_to_box(coarse_t, -hs, hs)
        refined_t = clip_to_box(refined_t, -hs, hs) if refined_t is not None else None
    return SVRPrediction(coarse=coarse_t, refined=refined_t)


def predict(model: ModelLike, images: torch.Tensor, batch_size: int = 64,
            refine: Optional[bool] = None) -> renderer.SDFGrid:
    """SDF grids predicted from images: the model's final output (see ``predict_sdf``).

    Returns:
        renderer.SDFGrid with values (B, N, N, N) float32 on the model's device and the box
        ``[-half_side, half_side]^3`` (world, y up, NMR ShapeNet frame).
    """
    m = as_model(model)
    out = predict_sdf(m, images, batch_size, refine)
    return renderer.SDFGrid(out.final, -m.half_side, m.half_side)


# ------------------------------------------------------------------------------------------------
# Images


def _open_image(path: Path, what: str):
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise FileNotFoundError(f"{what} not found: {path}")
    try:
        img = Image.open(path)
        img.load()
    except Image.DecompressionBombError:
        raise ValueError(f"{path}: the {what} is too large to read safely (more than twice PIL's "
                         f"Image.MAX_IMAGE_PIXELS = {Image.MAX_IMAGE_PIXELS} pixels); shrink it first") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as err:
        raise ValueError(f"{path}: cannot read the {what} ({err})") from None
    return img


def check_silhouette(alpha: np.ndarray, name: str) -> None:
    """Refuses a silhouette that cannot be an object on a background: empty (no pixel opaque: a
    fully transparent image or a black mask) or covering the image's whole border (an inverted
    mask: object transparent, background opaque; an object of the benchmark's framing never
    touches all four edges). Opaque: alpha >= 128 of 255.

    Args:
        alpha: (H, W) uint8 alpha channel or mask (255 = object).
    Raises:
        ValueError naming ``name`` and saying which.
    """
    opaque = np.asarray(alpha) >= 128
    if not opaque.any():
        raise ValueError(f"{name}: the silhouette is empty (no opaque pixel: a fully transparent image or a "
                         f"black mask); the object must be opaque (alpha or mask white) on a transparent background")
    border = np.concatenate([opaque[0], opaque[-1], opaque[:, 0], opaque[:, -1]])
    if border.all():
        raise ValueError(f"{name}: the silhouette covers the whole image border, so the mask looks inverted "
                         f"(object transparent, background opaque); the object must be opaque (alpha or mask "
                         f"white) and the background transparent (black in a mask)")


def _has_alpha(img) -> bool:
    return img.mode in ("RGBA", "LA", "PA", "La", "RGBa") or (img.mode == "P" and "transparency" in img.info)


def load_image(path: PathLike, mask: Optional[PathLike] = None, image_size: int = 64) -> torch.Tensor:
    """Reads one input image for the network.

    RGBA (or grey + alpha, or a palette with transparency) is used as is; RGB or grey needs a mask
    file (any mode, read as grey: white = object), which replaces the alpha channel. A non-square
    image is padded to a square (transparent, white); any other size is resized to
    ``image_size`` (area averaging when shrinking), with a warning. The result is converted like the
    datasets' images (``svr.data.nmr.images_to_float``: RGB on white).

    The silhouette must be an object on a background (``check_silhouette``): a fully transparent
    image or an inverted mask is refused.

    Returns:
        (4, S, S) float32 RGBA in [0, 1].
    Raises:
        FileNotFoundError / ValueError naming the image or mask file.
    """
    from PIL import Image

    path = Path(path)
    img = _open_image(path, "image")
    if mask is not None:
        mpath = Path(mask)
        m = _open_image(mpath, "mask").convert("L")
        if m.size != img.size:
            raise ValueError(f"{mpath}: mask size {m.size} differs from the image {path} size {img.size}")
        rgba = img.convert("RGB").convert("RGBA")
        rgba.putalpha(m)
    elif _has_alpha(img):
        rgba = img.convert("RGBA")
    else:
        raise ValueError(f"{path}: the image has no alpha channel ({img.mode}); give an RGBA image or a mask "
                         f"file (masks=[...], or <stem>_mask.png beside it)")
    check_silhouette(np.asarray(rgba.getchannel("A")), str(mask if mask is not None else path))
    w, h = rgba.size
    if (w, h) != (image_size, image_size):
        warnings.warn(f"{path}: {w}x{h} image resized to {image_size}x{image_size}"
                      + (" (padded to a square first)" if w != h else ""), UserWarning, stacklevel=2)
        if w != h:
            side = max(w, h)
            square = Image.new("RGBA", (side, side), (255, 255, 255, 0))
            square.paste(rgba, ((side - w) // 2, (side - h) // 2))
            rgba = square
        resample = Image.Resampling.BOX if rgba.size[0] > image_size else Image.Resampling.BILINEAR
        rgba = rgba.resize((image_size, image_size), resample)
    arr = np.asarray(rgba, dtype=np.uint8).transpose(2, 0, 1)  # (4, S, S), row 0 = top
    return images_to_float(arr, "composite")


def find_images(inputs: Union[PathLike, Sequence[PathLike]], mask_suffix: str = "_mask") -> list[Path]:
    """Expands image paths and folders (every PNG/JPEG in a folder, sorted, except masks: files whose
    stem ends with ``mask_suffix``).

    Raises:
        ValueError when nothing is given or a folder holds no image; FileNotFoundError naming a
        missing path.
    """
    items = [inputs] if isinstance(inputs, (str, os.PathLike)) else list(inputs or [])
    if not items:
        raise ValueError("images must name at least one image file or folder")
    out: list[Path] = []
    for item in items:
        p = Path(item).expanduser()
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES
                           and not (mask_suffix and f.stem.endswith(mask_suffix)))
            if not found:
                raise ValueError(f"images: the folder {p} holds no PNG/JPEG image")
            out.extend(found)
        elif p.exists():
            out.append(p)
        else:
            raise FileNotFoundError(f"image not found: {p}")
    return out


def find_mask(image: Path, mask_suffix: str = "_mask") -> Optional[Path]:
    """``<stem><mask_suffix>.<ext>`` beside the image (PNG/JPEG), if there is one."""
    if not mask_suffix:
        return None
    for ext in (image.suffix, *IMAGE_SUFFIXES):
        cand = image.with_name(f"{image.stem}{mask_suffix}{ext}")
        if cand.is_file():
            return cand
    return None


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


@torch.no_grad()
def render_views(grid: renderer.SDFGrid, views: Sequence[int] = DEFAULT_VIEWS, image_size: int = 128,
                 backend: str = "auto") -> torch.Tensor:
    """Shaded renders of each grid from the NMR cameras ``views`` (``PREVIEW_SCENE``: grey, white background).

    Returns:
        (B, K, S, S, 3) float32 CPU in [0, 1].
    """
    views = list(check_view_ids(views, allow_empty=False))
    check_int(image_size, "image_size", minimum=1)
    b = grid.batch_size
    cams = renderer.Cameras.nmr(views * b, image_size=image_size, dtype=grid.dtype, device=grid.device)
    out = renderer.render(grid, cams, PREVIEW_SCENE, backend=backend)
    img = out.image.detach().float().clamp(0, 1).cpu()
    return img.reshape(b, len(views), image_size, image_size, img.shape[-1])


def reconstruct(model: ModelLike, images: torch.Tensor, views: Sequence[int] = DEFAULT_VIEWS,
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
    from sdfcommon.geometry import sdf_to_mesh

    views = check_view_ids(views)
    check_int(render_size, "render_size", minimum=1)
    m = as_model(model)
    grid = predict(m, images, batch_size)
    names = list(names) if names is not None else [f"image {b}" for b in range(grid.batch_size)]
    if len(names) != grid.batch_size:
        raise ValueError(f"names must have one entry per image ({grid.batch_size}), got {len(names)}")
    renders = None
    if views:
        renders = torch.cat([render_views(renderer.SDFGrid(v, -m.half_side, m.half_side), views, render_size, backend)
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
    from sdfcommon.outputs import write_mesh, write_npz, write_png

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
                views: Sequence[int] = DEFAULT_VIEWS, render_size: int = 128, batch_size: int = 16,
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


__all__ = ["LoadedModel", "Reconstruction", "load_model", "as_model", "resolve_device", "check_images",
           "predict_sdf", "predict", "load_image", "find_images", "find_mask", "render_views", "reconstruct",
           "preview_picture", "save_reconstruction", "infer_files", "ensure_output_dir", "check_view_ids",
           "check_silhouette", "check_formats", "run", "main",
           "DEFAULT_VIEWS", "OUTPUT_FORMATS", "PREVIEW_SCENE"]
