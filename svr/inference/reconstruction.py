"""Reconstructions of images by a loaded model: ``reconstruct_images`` predicts SDF grids
(``svr.inference.prediction``), extracts meshes by marching cubes (closed at the box, cleaned:
``clean_mesh``; each checked for watertightness and its problem said) and renders previews from NMR
views (``svr.nmr.views``); ``save_reconstruction`` writes one (``<name>_sdf.npz``, ``<name>.ply``,
``<name>.obj``, ``<name>_views.png``, each atomically) and ``infer_files`` does both for image files
(``svr.inference.images``) into a folder, image by image: one that cannot be read or gives no
surface is a failed item of its ``InferenceReport``, and the others go on. The functions take a
``LoadedModel``; turning a checkpoint path into one is the command's (``svr.infer``)."""
from __future__ import annotations

import dataclasses
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
from sdfcommon.tooling.outputs import ensure_output_dir, write_json, write_mesh, write_npz, write_png
from svr.inference.framing import TRAINING_FRAMING, frame_image
from svr.inference.images import find_images, find_mask, read_rgba, rgba_to_input
from svr.inference.input_camera import (InputCamera, check_elevation, estimate_cameras, mesh_in_camera_frame,
                                        view_of_azimuth)
from svr.inference.prediction import LoadedModel, check_input_views, check_model, predict
from svr.nmr.format import NUM_VIEWS, check_view_ids
from svr.nmr.views import PREVIEW_VIEWS, render_previews

PathLike = Union[str, os.PathLike]
OUTPUT_FORMATS = ("npz", "ply", "obj", "png", "camera")


@dataclass(frozen=True)
class Reconstruction:
    """One image's prediction, its mesh and renders.

    Attributes:
        values: (N, N, N) float32 CPU SDF (world units, renderer.SDFGrid layout).
        bbox_min, bbox_max: the grid's box (the first and last samples, world units, per axis).
        mesh: trimesh.Trimesh of the zero level set (closed at the box, ``clean_mesh``); empty if
            there is none.
        watertight: whether trimesh finds the mesh watertight (False for an empty mesh).
        renders: (K, S, S, 3) float32 CPU shaded renders from the NMR views ``views``.
        views: the NMR view indices of ``renders``.
        problem: what is wrong with the mesh ("no surface ...", "not watertight ..."), None when
            it is a non-empty watertight mesh (``mesh_problem``).
        camera: the input's camera when known (given or estimated); then ``views`` are offsets
            from its view.
    """

    values: torch.Tensor
    bbox_min: tuple[float, float, float]
    bbox_max: tuple[float, float, float]
    mesh: Any
    watertight: bool
    renders: Optional[torch.Tensor]
    views: tuple[int, ...]
    problem: Optional[str] = None
    camera: Optional[InputCamera] = None


def clean_mesh(mesh):
    """A copy of a trimesh.Trimesh with duplicate vertices merged and the faces that repeat a vertex
    (no area) or another face dropped, then unused vertices removed: what marching cubes leaves
    where the field is zero at a sample (two of its vertices coincide)."""
    out = mesh.copy()
    out.merge_vertices()
    f = out.faces
    out.update_faces((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))
    out.update_faces(out.unique_faces())
    out.remove_unreferenced_vertices()
    return out


def mesh_problem(mesh) -> Optional[str]:
    """What keeps a mesh from being a closed surface, in words, or None when it is non-empty and
    watertight (trimesh: every edge shared by exactly two faces)."""
    if len(mesh.faces) == 0:
        return "no surface: the predicted SDF has no zero crossing (positive everywhere), so there is no mesh"
    if mesh.is_watertight:
        return None
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    return (f"the mesh is not watertight: {int((counts == 1).sum())} open and {int((counts > 2).sum())} "
            f"non-manifold edges of {len(counts)}")


def reconstruct_images(model: LoadedModel, images: torch.Tensor, views: Sequence[int] = PREVIEW_VIEWS,
                render_size: int = 128, batch_size: int = 16, backend: str = "auto",
                require_watertight: bool = False, names: Optional[Sequence[str]] = None,
                input_views=None) -> list[Reconstruction]:
    """Predicts SDF grids, extracts meshes (``clean_mesh``) and renders previews for B images; warns
    about a mesh that is empty or not watertight (``Reconstruction.problem``).

    Args:
        model: the network and its stage (``svr.inference.prediction.load_model``).
        images: (B, 4, 64, 64) float RGBA in [0, 1].
        views: NMR views of the preview renders (empty: no renders).
        render_size: side of the preview renders.
        require_watertight: raise (ValueError naming the image) instead of warning when a mesh is
            not watertight.
        names: per image, how warnings name it (default "image <b>").
        input_views: the NMR view index each image was taken from (one per image or one for all);
            needed by a network with a pixel-aligned head (``predict_sdf``'s ``views``).
    Returns:
        one Reconstruction per image.
    """
    recs = _reconstruct(check_model(model), images, views, render_size, batch_size, backend, input_views)
    names = list(names) if names is not None else [f"image {b}" for b in range(len(recs))]
    if len(names) != len(recs):
        raise ValueError(f"names must have one entry per image ({len(recs)}), got {len(names)}")
    for name, rec in zip(names, recs):
        if rec.problem is not None:
            if require_watertight and len(rec.mesh.faces):
                raise ValueError(f"{name}: {rec.problem}")
            warnings.warn(f"{name}: {rec.problem}", RuntimeWarning, stacklevel=2)
    return recs


def _reconstruct(m: LoadedModel, images: torch.Tensor, views: Sequence[int], render_size: int, batch_size: int,
                 backend: str, input_views, cameras: Optional[Sequence[InputCamera]] = None) -> list[Reconstruction]:
    """``reconstruct_images`` without its verdicts: each Reconstruction says its mesh's problem.
    With ``cameras`` (one per image) the previews are rendered from each camera's view plus the
    offsets ``views``."""
    views = check_view_ids(views)
    check_int(render_size, "render_size", minimum=1)
    if cameras is not None and len(cameras) != len(images):
        raise ValueError(f"cameras must have one entry per image ({len(images)}), got {len(cameras)}")
    grid = predict(m, images, batch_size, views=input_views)
    renders = None
    if views:
        per_image = (torch.tensor([[((c.view + v) % NUM_VIEWS, c.elevation_deg) for v in views] for c in cameras],
                                  dtype=torch.float64)
                     if cameras is not None else None)
        renders = torch.cat([render_previews(renderer.SDFGrid(v, -m.half_side, m.half_side),
                                             views if per_image is None else per_image[a:a + batch_size],
                                             render_size, backend)
                             for a, v in zip(range(0, len(grid.values), batch_size), grid.values.split(batch_size))])
    values = grid.values.detach().float().cpu()
    lo = tuple(float(c) for c in grid.bbox_min.cpu())
    hi = tuple(float(c) for c in grid.bbox_max.cpu())
    out = []
    for b, v in enumerate(values):
        mesh = clean_mesh(sdf_to_mesh(v, lo, hi, close=True, off_level=True))
        problem = mesh_problem(mesh)
        out.append(Reconstruction(values=v, bbox_min=lo, bbox_max=hi, mesh=mesh,
                                  watertight=bool(len(mesh.faces) and mesh.is_watertight),
                                  renders=renders[b] if renders is not None else None,
                                  views=tuple(int(x) for x in views), problem=problem,
                                  camera=cameras[b] if cameras is not None else None))
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
    ``<name>.obj`` (the canonical frame; skipped for an empty mesh), ``<name>_views.png``, and with
    the input's camera known ("camera") ``<name>_camera.json`` (``InputCamera.record``) and
    ``<name>_camera_frame.ply`` (the mesh in the camera's frame: ``mesh_in_camera_frame``).

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
    if "camera" in formats and rec.camera is not None:
        written["camera"] = write_json(folder / f"{name}_camera.json", rec.camera.record())
        if len(rec.mesh.faces):
            written["camera_frame"] = write_mesh(folder / f"{name}_camera_frame.ply",
                                                 mesh_in_camera_frame(rec.mesh, rec.camera))
    return written


def check_formats(formats: Sequence[str]) -> list[str]:
    """Raises ValueError naming ``formats`` unless it is a non-empty list of ``OUTPUT_FORMATS``."""
    if (isinstance(formats, str) or not isinstance(formats, Sequence) or not formats
            or any(f not in OUTPUT_FORMATS for f in formats)):
        raise ValueError(f"formats must be a non-empty list among {list(OUTPUT_FORMATS)}, got {formats!r}")
    return list(formats)


def _unique_names(paths: Sequence[Path]) -> list[str]:
    seen: dict[str, int] = {}
    names = []
    for p in paths:
        n = seen.get(p.stem, 0)
        seen[p.stem] = n + 1
        names.append(p.stem if n == 0 else f"{p.stem}_{n}")
    return names


@dataclass(frozen=True)
class ImageResult:
    """What ``infer_files`` made of one input image.

    Attributes:
        image: the input file.
        files: {format: path} of the files written; empty when it failed.
        error: why it failed (None: done): the image or its mask could not be read or was refused,
            the prediction has no surface, or (``require_watertight``) its mesh is not watertight.
        problem: a problem of a written mesh that did not fail it (not watertight), else None.
        camera: the estimated camera in words (None when given or unknown).
    """

    image: Path
    files: Mapping[str, Path]
    error: Optional[str] = None
    problem: Optional[str] = None
    camera: Optional[str] = None

    @property
    def done(self) -> bool:
        return self.error is None


@dataclass(frozen=True)
class InferenceReport:
    """``infer_files``'s result.

    Attributes:
        images: one ImageResult per input image, in the order of the expanded inputs.
        skipped: what the given folders and patterns held that was not read (``find_images``).
    """

    images: tuple[ImageResult, ...]
    skipped: tuple[Path, ...] = ()

    @property
    def done(self) -> tuple[ImageResult, ...]:
        return tuple(r for r in self.images if r.done)

    @property
    def failed(self) -> tuple[ImageResult, ...]:
        return tuple(r for r in self.images if not r.done)


def infer_files(model: LoadedModel, images: Union[PathLike, Sequence[PathLike]], output_dir: PathLike,
                masks: Optional[Sequence[Optional[PathLike]]] = None, mask_suffix: str = "_mask",
                views: Sequence[int] = PREVIEW_VIEWS, render_size: int = 128, batch_size: int = 16,
                formats: Sequence[str] = OUTPUT_FORMATS, require_watertight: bool = False,
                backend: str = "auto", progress: bool = False, input_view: Optional[float] = None,
                azimuth: Optional[float] = None, frame: Optional[bool] = None,
                elevation: Optional[float] = None) -> InferenceReport:
    """Reads images (files, folders or glob patterns), reconstructs them and writes the results into
    ``output_dir``, image by image: an image that cannot be read, is refused (``read_rgba``,
    ``frame_image``) or gives no surface (or, with ``require_watertight``, a mesh that is not
    watertight) is a failed item of the report, with nothing written for it, and the others go on.

    The input camera is ``input_view`` or ``azimuth`` when given; otherwise the network's camera
    head estimates it from each image (``svr.inference.input_camera.estimate_cameras``), and a
    network that reads the camera but has no head is refused. Framing (``frame_image``) crops and
    scales each photo so that its object sits as in a training render from that camera: by default
    (``frame`` None) where the camera is not given, with the checkpoint's framing bank
    (``svr.inference.framing_bank``; else the head's framing, else the training renders' median);
    ``frame`` True or False asks for it or not.

    Args:
        model: the network and its stage (``svr.inference.prediction.load_model``).
        images: an image file, a folder (every PNG/JPEG in it but masks), a glob pattern or a list
            of them (``svr.inference.images.find_images``).
        masks: one mask path (or None) per expanded image; default: ``<stem><mask_suffix>.*`` beside
            each image when it exists.
        views: the preview's views: offsets from the input camera's view when it is known, NMR
            views otherwise.
        input_view: the NMR view index (in [0, 24): azimuth -15 * view degrees at 30 degrees
            elevation) of every image's camera. azimuth: the same in degrees (not both).
        elevation: every image's camera elevation in degrees (None: 30 with a given camera, else
            the camera head's estimate where it has the elevation output, else 30).
        Others: see ``reconstruct_images`` and ``save_reconstruction``.
    Returns:
        InferenceReport: per image, the files written or why it failed, and what was skipped.
    Raises:
        ValueError naming the setting (checked before any image is read) or ``output_dir`` when it
        cannot be written; FileNotFoundError naming a missing input path.
    """
    # Every setting is checked before the first image is read (a bad one must not cost a model run).
    m = check_model(model)
    check_int(batch_size, "batch_size", minimum=1)
    check_int(render_size, "render_size", minimum=1)
    views = check_view_ids(views)
    if input_view is not None and azimuth is not None:
        raise ValueError(f"give input_view or azimuth, not both (got input_view={input_view!r}, azimuth={azimuth!r})")
    given = view_of_azimuth(azimuth) if azimuth is not None else input_view
    head = getattr(m.net, "camera", None)
    if given is None and m.net.needs_views and head is None:
        raise ValueError("input_view: this checkpoint reads the input camera and has no camera head to estimate it "
                         "(trained before model.camera existed); give input_view=K (an NMR view, 0..23) or "
                         "azimuth=DEGREES")
    check_input_views(given, 1, False, "input_view")
    check_elevation(elevation)
    if frame not in (None, True, False):
        raise ValueError(f"frame must be true, false or null (frame where the camera is not given), got {frame!r}")
    check_formats(formats)
    folder = ensure_output_dir(output_dir, "output_dir")
    found = find_images(images, mask_suffix)
    paths = found.images
    if masks is not None and len(masks) != len(paths):
        raise ValueError(f"masks must have one entry per image ({len(paths)} images), got {len(masks)}")
    names = _unique_names(paths)
    meta = {"checkpoint": str(m.checkpoint) if m.checkpoint else "", "stage": m.stage, "output": m.output_name}
    framed = frame if frame is not None else given is None
    results: dict[int, ImageResult] = {}
    loaded: list[tuple[int, torch.Tensor, Optional[InputCamera]]] = []
    for i, p in enumerate(paths):
        try:
            rgba = read_rgba(p, masks[i] if masks is not None else find_mask(p, mask_suffix))
            loaded.append((i, *input_and_camera(m, rgba, str(p), given, framed, elevation)))
        except (OSError, ValueError) as err:  # the message names the file
            results[i] = ImageResult(p, {}, error=str(err))
    with tqdm(total=len(paths), desc="infer", unit="img", disable=not progress) as bar:
        bar.update(len(results))
        for start in range(0, len(loaded), batch_size):
            chunk = loaded[start:start + batch_size]
            cameras = [c for _, _, c in chunk]
            known = all(c is not None for c in cameras)
            recs = _reconstruct(m, torch.stack([t for _, t, _ in chunk]), views, render_size, batch_size, backend,
                                torch.tensor([c.row for c in cameras]) if known else None, cameras if known else None)
            for (i, tensor, _), rec in zip(chunk, recs):
                if len(rec.mesh.faces) == 0:
                    results[i] = ImageResult(paths[i], {}, error=rec.problem)
                    continue
                if rec.problem is not None and require_watertight:
                    results[i] = ImageResult(paths[i], {}, error=f"{rec.problem} (require_watertight=true)")
                    continue
                files = save_reconstruction(rec, folder, names[i], tensor, formats, {**meta, "image": str(paths[i])})
                results[i] = ImageResult(paths[i], files, problem=rec.problem, camera=_camera_words(rec.camera))
            bar.update(len(recs))
    return InferenceReport(images=tuple(results[i] for i in range(len(paths))), skipped=found.skipped)


def _camera_words(camera: Optional[InputCamera]) -> Optional[str]:
    if camera is None or camera.source != "estimated":
        return None
    return (f"camera estimated: NMR view {camera.view:.2f}, azimuth {camera.azimuth_deg:.1f} degrees, "
            f"elevation {camera.elevation_deg:.0f}, probability {camera.probability:.2f}")


def input_and_camera(m: LoadedModel, rgba: np.ndarray, name: str, given: Optional[float],
                     framed: bool, elevation: Optional[float] = None) -> tuple[torch.Tensor, Optional[InputCamera]]:
    """One photo's network input and camera: the camera given, or estimated by the camera head from
    the photo framed as the training renders' median (the head crops to the silhouette, so only the
    resolution matters), its view weighed by the votes of the model's framing bank where that keeps
    the renders' views; then, when ``framed``, the photo framed as the camera's renders are: by
    the model's framing bank where it has one (``svr.inference.framing_bank``), else by the head's
    framing, else the median. ``elevation`` (degrees) replaces the given or estimated camera's."""
    head = getattr(m.net, "camera", None)
    camera = InputCamera(view=float(given)) if given is not None else None
    framing, source = TRAINING_FRAMING, "training median"
    if (head is not None and (camera is None or framed)) or (framed and m.framing_bank is not None):
        median, _ = frame_image(rgba, name, m.image_size, TRAINING_FRAMING)
        banked, votes = m.framing_bank.look_up(median[..., 3]) if m.framing_bank is not None else (None, None)
        if head is not None:
            estimate = estimate_cameras(m.net, rgba_to_input(median, name, m.image_size)[None],
                                        votes[None] if votes is not None and camera is None else None)[0]
            camera = camera if camera is not None else estimate
            framing, source = estimate.framing, "camera head"
        if banked is not None:
            framing, source = banked, "framing bank"
    if camera is not None and elevation is not None:
        camera = dataclasses.replace(camera, elevation_deg=float(elevation))
    if not framed:
        return rgba_to_input(rgba, name, m.image_size), camera
    image, transform = frame_image(rgba, name, m.image_size, framing)
    if camera is not None:
        camera = dataclasses.replace(camera, framing=framing, framing_source=source, transform=transform)
    return rgba_to_input(image, name, m.image_size), camera


__all__ = ["Reconstruction", "reconstruct_images", "clean_mesh", "mesh_problem", "preview_picture", "save_reconstruction",
           "infer_files", "input_and_camera", "ImageResult", "InferenceReport", "check_formats", "OUTPUT_FORMATS"]
