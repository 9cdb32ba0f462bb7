"""The camera an input image was taken from: given (``input_view`` or ``azimuth``) or estimated by
the network's ViewHead (``svr.models.camera``), with its place in the frame, the transform from
the world (the training data's canonical frame: y up, the front towards -z) to the camera's frame,
and what a user needs in a JSON file. The camera is NMR's distance 2.732 and 30 degree field of
view at an elevation of 30 degrees unless given or estimated otherwise (a head with the elevation
output, trained on extra views). The estimate weighs the head's probabilities of NMR's 24 views with
the votes of the training silhouettes most like the photo (``FramingBank.view_votes``), where the
checkpoint has them, and reads an azimuth between two views off the probabilities next to the most
probable one (``view_between``)."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Optional

import numpy as np
import torch

import renderer
from renderer import NMR_DISTANCE, NMR_ELEVATION_DEG, NMR_FOV_DEG
from svr.inference.framing import Framing, FrameTransform
from svr.nmr.format import NUM_VIEWS


def view_of_azimuth(azimuth_deg: float, name: str = "azimuth") -> float:
    """The NMR view index in [0, 24) of an azimuth in degrees (NMR's azimuth is ``-15 * view``)."""
    try:
        a = float(azimuth_deg)
    except (TypeError, ValueError):
        a = float("nan")
    if not math.isfinite(a):
        raise ValueError(f"{name} must be a finite number of degrees, got {azimuth_deg!r}")
    return float((-a / 15.0) % NUM_VIEWS)


def check_elevation(elevation: Optional[float]) -> Optional[float]:
    """``elevation`` as a float in (-90, 90) degrees, or None; else a ValueError naming it."""
    if elevation is None:
        return None
    try:
        value = float(elevation)
    except (TypeError, ValueError):
        value = float("nan")
    if not (math.isfinite(value) and -90.0 < value < 90.0):
        raise ValueError(f"elevation must be a number of degrees in (-90, 90), got {elevation!r}")
    return value


@dataclass(frozen=True)
class InputCamera:
    """The camera of one input image.

    Attributes:
        view: NMR view index (azimuth ``-15 * view`` degrees; fractional when given so, and when
            estimated).
        source: "given" or "estimated".
        probability: the estimate's probability of its most probable NMR view (None when given).
        framing: where the object's silhouette sits in a training render from this camera (the
            estimate's; None when given or unknown).
        framing_source: what ``framing`` came from: "framing bank", "camera head" or "training
            median" (None with no framing).
        transform: how the photo was cropped and scaled into the network's input (None: resized as
            it came).
        elevation_deg: the camera's elevation (NMR's 30 unless given or estimated).
    """

    view: float
    source: str = "given"
    probability: Optional[float] = None
    framing: Optional[Framing] = None
    transform: Optional[FrameTransform] = None
    elevation_deg: float = NMR_ELEVATION_DEG
    framing_source: Optional[str] = None

    @property
    def row(self) -> tuple[float, float]:
        """(view, elevation): what ``predict_sdf`` and the renders take for a camera off NMR's 24."""
        return float(self.view), float(self.elevation_deg)

    @property
    def azimuth_deg(self) -> float:
        """In [0, 360)."""
        return float((-15.0 * self.view) % 360.0)

    def world_to_camera(self) -> np.ndarray:
        """(4, 4) float64: world points (the canonical frame) to the camera's frame, whose x runs to
        the image's right, y to its top and z from the object towards the eye (the eye at the
        origin, looking down -z). NMR's camera is left-handed (``renderer.Cameras.nmr``), so this
        matrix has determinant -1: the camera-frame copy is the photo's handedness."""
        cams = renderer.Cameras.nmr([self.view], dtype=torch.float64, elevation_deg=[self.elevation_deg])
        eye = cams.eye[0].numpy()
        rot = np.stack([cams.right[0].numpy(), cams.up[0].numpy(), -cams.forward[0].numpy()])
        out = np.eye(4)
        out[:3, :3] = rot
        out[:3, 3] = -rot @ eye
        return out

    def record(self) -> dict[str, Any]:
        """Plain values for ``<stem>_camera.json``."""
        out: dict[str, Any] = {
            "source": self.source, "nmr_view": round(float(self.view), 6), "azimuth_deg": round(self.azimuth_deg, 6),
            "elevation_deg": round(float(self.elevation_deg), 6), "distance": NMR_DISTANCE, "fov_deg": NMR_FOV_DEG,
            "note": ("the training renders' camera (distance and field of view fixed); world: y up, front towards -z; "
                     "camera frame: x right, y up, z towards the eye"),
            "world_to_camera": [[round(float(v), 9) for v in row] for row in self.world_to_camera()],
        }
        if self.probability is not None:
            out["probability"] = round(float(self.probability), 6)
        if self.framing is not None:
            out["framing"] = asdict(self.framing)
            if self.framing_source is not None:
                out["framing_source"] = self.framing_source
        if self.transform is not None:
            out["photo_to_input"] = self.transform.to_dict()
        return out


# How the head's view probabilities and the framing bank's votes combine, chosen on photos of the
# demo preset's validation split at random cameras (docs/svr_inference.md, "The camera"):
# probabilities * (votes + VOTE_FLOOR) ** VOTE_POWER; the floor keeps a view no neighbour voted for
# possible. VIEW_SPAN: the neighbours on each side whose probabilities place the azimuth between views.
VOTE_FLOOR, VOTE_POWER, VIEW_SPAN = 0.02, 0.5, 2


def weigh_votes(probabilities: torch.Tensor, votes: Optional[torch.Tensor]) -> torch.Tensor:
    """(B, 24) view probabilities weighed by (B, 24) votes (each row summing to 1; None: unchanged),
    renormalised."""
    if votes is None:
        return probabilities
    out = probabilities.double() * (votes.double() + VOTE_FLOOR) ** VOTE_POWER
    return out / out.sum(dim=1, keepdim=True)


def view_between(probabilities: torch.Tensor, span: int = VIEW_SPAN) -> torch.Tensor:
    """(B,) float view coordinates in [0, 24) from (B, 24) probabilities: the most probable view,
    moved by the probability-weighted mean offset of it and its ``span`` neighbours on each side (a
    camera between two NMR views gives both some probability)."""
    best = probabilities.argmax(dim=1)
    offsets = torch.arange(-span, span + 1)
    w = probabilities.double().gather(1, (best[:, None] + offsets[None]) % NUM_VIEWS)
    return (best.double() + (w * offsets).sum(dim=1) / w.sum(dim=1).clamp_min(1e-12)) % NUM_VIEWS


def estimate_cameras(net, images: torch.Tensor, votes: Optional[torch.Tensor] = None) -> list[InputCamera]:
    """The ViewHead's camera of (B, 4, S, S) RGBA images (``net.camera``, in eval mode), its view
    probabilities weighed by ``votes`` (B, 24) when given (``weigh_votes``), the azimuth read between
    views (``view_between``); ``probability`` is that of the most probable NMR view.

    Raises:
        ValueError when the network has no ViewHead.
    """
    head = getattr(net, "camera", None)
    if head is None:
        raise ValueError("this checkpoint has no camera head (model.camera), so it cannot estimate the input camera")
    device = next(head.parameters()).device
    est = head.estimate(images.to(device))
    probs = weigh_votes(est.probabilities.cpu(), None if votes is None else torch.as_tensor(votes).cpu())
    views, framing = view_between(probs), est.framing.float().cpu()
    elevation = ([NMR_ELEVATION_DEG] * len(views) if est.elevation is None
                 else [float(e) for e in est.elevation.float().cpu()])
    return [InputCamera(view=float(v), source="estimated", probability=float(p.max()),
                        framing=Framing(*(float(x) for x in f)), elevation_deg=e)
            for v, p, f, e in zip(views.tolist(), probs, framing, elevation)]


def mesh_in_camera_frame(mesh, camera: InputCamera):
    """A copy of a trimesh.Trimesh moved into the camera's frame (``InputCamera.world_to_camera``),
    its faces re-wound where the transform mirrors, so that normals still point out."""
    m = mesh.copy()
    matrix = camera.world_to_camera()
    m.vertices = m.vertices @ matrix[:3, :3].T + matrix[:3, 3]
    if np.linalg.det(matrix[:3, :3]) < 0:
        m.faces = m.faces[:, ::-1].copy()
    return m


__all__ = ["InputCamera", "check_elevation", "estimate_cameras", "mesh_in_camera_frame", "view_between",
           "view_of_azimuth", "weigh_votes"]
