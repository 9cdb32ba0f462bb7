"""The trained network, used: ``load_model`` (the one place a checkpoint path becomes a model)
reads a checkpoint (``svr.inference.checkpoints``) onto a device as a ``LoadedModel``; ``predict_sdf``
runs a LoadedModel on images in batches without gradients, applies the checkpoint's calibration
(``svr.inference.calibration``: silhouette carving and a level, chosen on the validation split) and
closes the shapes at the normalisation cube (``svr.nmr.voxels.clip_to_box``); ``predict``
gives ``renderer.SDFGrid``s.
Evaluation, inference and the demo all predict through here, so they score and show the same
shapes; a network in memory is wrapped as ``LoadedModel(net)``."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import torch

import renderer
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.serialization import scrub_unsafe_advice

from svr.inference.calibration import Calibration
from svr.inference.checkpoints import load_network
from svr.inference.framing_bank import FramingBank
from svr.models.network import SVRNet, SVRPrediction
from svr.nmr.format import NUM_VIEWS
from svr.nmr.voxels import clip_to_box

PathLike = Union[str, os.PathLike]


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
        calibration: what the predictions go through after the network (None: nothing), the
            checkpoint's when it holds one (``svr.evaluation.calibration_search.store_calibration``).
        framing_bank: how a photo is framed when its camera is estimated (``svr.inference.framing_bank``),
            the checkpoint's when it holds one (None: the camera head's framing).
    """

    net: SVRNet
    stage: str = "joint"
    checkpoint: Optional[Path] = None
    categories: Optional[tuple[tuple[str, str], ...]] = None
    calibration: Optional[Calibration] = None
    framing_bank: Optional[FramingBank] = None

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


def load_model(ckpt_path: PathLike, device: Union[str, torch.device, None] = "auto") -> LoadedModel:
    """Loads one of our checkpoints (made on a CPU or a GPU) onto ``device`` for inference.

    The network is rebuilt from the model config stored in the checkpoint
    (``svr.inference.checkpoints.load_network``), so no config is needed here.

    Raises:
        FileNotFoundError naming the file; ValueError naming the file when it is corrupt, truncated
        or not an SDFDiff single-view checkpoint, and naming ``device`` when that is unusable.
    """
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
    calibration, bank = meta.get("calibration"), meta.get("framing_bank")
    return LoadedModel(net=net, stage=str(meta["stage"]), checkpoint=path,
                       categories=tuple((str(c), str(n)) for c, n in cats) if cats else None,
                       calibration=(Calibration.from_dict(calibration["settings"], f"{path}: calibration")
                                    if calibration else None),
                       framing_bank=(FramingBank.from_record(bank, f"ckpt_path: {path}: framing bank")
                                     if bank else None))


def check_model(model: LoadedModel, name: str = "model") -> LoadedModel:
    """Raises TypeError naming ``name`` unless ``model`` is a LoadedModel (a path is the command's
    to load: ``load_model``; a network in memory is ``LoadedModel(net)``)."""
    if not isinstance(model, LoadedModel):
        raise TypeError(f"{name} must be a LoadedModel (load_model(path) reads a checkpoint, LoadedModel(net) "
                        f"wraps a network), got {type(model).__name__}")
    return model


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
def predict_sdf(model: LoadedModel, images: torch.Tensor, batch_size: int = 64,
                refine: Optional[bool] = None, clip: bool = True, views=None,
                calibrated: bool = True) -> SVRPrediction:
    """The network's coarse and (unless the model is a coarse-stage one) refined SDFs.

    Args:
        model: the network and its stage (``load_model``, or ``LoadedModel(net)``).
        images: (B, 4, 64, 64) float RGBA in [0, 1], RGB on white (as the datasets give them).
        batch_size: images per forward pass.
        refine: run the refiner (default: ``model.uses_refiner``).
        clip: intersect the shapes with the cube the objects are normalised into
            (``svr.nmr.voxels.clip_to_box``), so none reaches past the benchmark's voxel grid. Every
            output of this module and ``svr.evaluate`` goes through it.
        views: the images' NMR view indices (B,) (0..23, fractional allowed), or one for all, or
            (B, 2) rows of (view, elevation in degrees): the camera each image was taken from.
            Needed by a network that reads pixel-aligned image features (``SVRNet.needs_views``),
            and by a calibration's carving (skipped without them).
        calibrated: apply ``model.calibration`` (to the coarse and the refined SDF) when it has one.
    Returns:
        SVRPrediction: ``coarse`` and ``refined`` (None without the refiner), (B, N, N, N) float32
        on the model's device, over the box ``[-half_side, half_side]^3`` (world units).
    """
    m = check_model(model)
    check_int(batch_size, "batch_size", minimum=1)
    x = check_images(images, m.image_size)
    use_refiner = m.uses_refiner if refine is None else bool(refine)
    v = check_input_views(views, len(x), m.net.needs_views)
    m.net.eval()
    post = m.calibration if calibrated and m.calibration is not None and not m.calibration.is_identity else None
    coarse, refined = [], []
    for i, chunk in enumerate(x.split(batch_size)):
        vc = v[i * batch_size:(i + 1) * batch_size].to(m.device) if v is not None else None
        chunk = chunk.to(m.device, non_blocking=True)
        out = m.net(chunk, refine=use_refiner, views=vc)
        cone = post.cone(chunk, vc, out.coarse.shape[-1], m.half_side) if post is not None else None
        coarse.append(out.coarse if post is None else post.apply(out.coarse, cone))
        if out.refined is not None:
            refined.append(out.refined if post is None else post.apply(out.refined, cone))
    coarse_t = torch.cat(coarse)
    refined_t = torch.cat(refined) if use_refiner else None
    if clip:
        hs = m.half_side
        coarse_t = clip_to_box(coarse_t, -hs, hs)
        refined_t = clip_to_box(refined_t, -hs, hs) if refined_t is not None else None
    return SVRPrediction(coarse=coarse_t, refined=refined_t)


def check_input_views(views, count: int, required: bool, name: str = "views") -> Optional[torch.Tensor]:
    """(count,) float view indices from ``views`` (one per image, or a single one for all), or
    (count, 2) rows of (view, elevation in degrees) when given so (a camera at another elevation), or
    None when not given; raises ValueError naming ``name`` when they are required and missing, or
    malformed (not one per image, a view outside [0, NUM_VIEWS): views 0..23, fractional ones
    between them, or an elevation outside (-90, 90))."""
    if views is None:
        if required:
            raise ValueError(f"{name}: this network reads image features where each sample projects into the input "
                             f"view, so it needs each image's NMR view index (0..23, the camera it was taken from)")
        return None
    v = torch.as_tensor(views, dtype=torch.float32).cpu()
    if v.ndim == 2 and v.shape[1] == 2:  # rows of (view, elevation): a camera off NMR's 24
        if v.shape[0] != count:
            raise ValueError(f"{name}: expected one (view, elevation) row per image ({count}), got {v.shape[0]}")
        el = v[:, 1]
        if not bool((torch.isfinite(el) & (el > -90) & (el < 90)).all()):
            raise ValueError(f"{name}: elevations must lie in (-90, 90) degrees, got {el.tolist()[:4]}")
        rows, v = v, v[:, 0]
    else:
        rows, v = None, v.reshape(-1)
    if v.numel() == 1:
        v = v.expand(count)
    if v.numel() != count:
        raise ValueError(f"{name}: expected one NMR view index per image ({count}) or one for all, got {v.numel()}")
    outside = v[~(torch.isfinite(v) & (v >= 0) & (v < NUM_VIEWS))]
    if outside.numel():
        raise ValueError(f"{name} must be an NMR view index in [0, {NUM_VIEWS}) (0..{NUM_VIEWS - 1}, fractional "
                         f"allowed), got {_number(outside[0])}")
    return v if rows is None else rows


def _number(x: torch.Tensor) -> str:
    """A view index as the user wrote it (24, not 24.0)."""
    value = float(x)
    return str(int(value)) if value.is_integer() else repr(value)


def predict(model: LoadedModel, images: torch.Tensor, batch_size: int = 64,
            refine: Optional[bool] = None, views=None) -> renderer.SDFGrid:
    """SDF grids predicted from images: the model's final output (see ``predict_sdf``).

    Returns:
        renderer.SDFGrid with values (B, N, N, N) float32 on the model's device and the box
        ``[-half_side, half_side]^3`` (world, y up, NMR ShapeNet frame).
    """
    out = predict_sdf(model, images, batch_size, refine, views=views)
    return renderer.SDFGrid(out.final, -model.half_side, model.half_side)


__all__ = ["LoadedModel", "load_model", "check_model", "resolve_device", "check_images", "check_input_views", "predict_sdf",
           "predict"]
