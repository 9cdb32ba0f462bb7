"""What a checkpoint's predictions go through after the network, chosen once on the validation split
(``svr.evaluation.calibration_search``) and kept in the checkpoint: carving by the input silhouette and a
shift of the surface level. A network trained on silhouettes predicts shapes near the visual hull
of its supervised views, so it over-fills (on the demo's test split the median predicted volume was
1.75x the truth) and puts some material where the input view shows background. Carving removes
every sample whose projection into the input view falls outside the silhouette (the dataset's known
camera, as the pixel-aligned head reads it), and, with a mirror axis, every sample whose mirror
image does (the mirror image of the object seen from the same camera has the same silhouette);
the level moves the network's surface inwards by a fixed distance, and the carving cone has a level
of its own (0: the silhouette's exact cone). Both only use the input image and its camera, so they
apply wherever the network does."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping, Optional

import torch

from svr.nmr.cones import silhouette_cone_sdf

CARVES = ("none", "view", "view+mirror")


@dataclass(frozen=True)
class Calibration:
    """Post-processing of predicted SDF grids.

    Attributes:
        carve: "none"; "view": intersect with the input silhouette's cone; "view+mirror": also with
            the cone's mirror image across the plane ``mirror_axis`` = 0 through the origin.
        mirror_axis: the world axis (0 = x, 1 = y, 2 = z) of "view+mirror".
        level: world units added to the network's SDF (positive: the surface moves inwards).
        threshold: alpha at or above which an input pixel is silhouette.
        carve_level: world units added to the carving cone's field (0: the silhouette's exact cone;
            negative: a wider cone). Records written before this field existed carved with the
            level added to both, and ``from_dict`` reads them so.
    """

    carve: str = "none"
    mirror_axis: Optional[int] = None
    level: float = 0.0
    threshold: float = 0.5
    carve_level: float = 0.0

    def __post_init__(self) -> None:
        if self.carve not in CARVES:
            raise ValueError(f"carve must be one of {', '.join(CARVES)}, got {self.carve!r}")
        if self.carve == "view+mirror" and self.mirror_axis not in (0, 1, 2):
            raise ValueError(f"carve='view+mirror' needs mirror_axis 0, 1 or 2, got {self.mirror_axis!r}")
        for name in ("level", "carve_level"):
            if not math.isfinite(float(getattr(self, name))):
                raise ValueError(f"{name} must be a finite number, got {getattr(self, name)!r}")
        if not 0.0 < float(self.threshold) < 1.0:
            raise ValueError(f"threshold must lie in (0, 1), got {self.threshold!r}")

    @property
    def is_identity(self) -> bool:
        return self.carve == "none" and float(self.level) == 0.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], name: str = "calibration") -> "Calibration":
        """The inverse of ``to_dict``; raises ValueError naming ``name`` on unknown keys or values."""
        unknown = set(data) - {"carve", "mirror_axis", "level", "threshold", "carve_level"}
        if unknown:
            raise ValueError(f"{name}: unknown keys {sorted(unknown)}")
        fields = dict(data)
        fields.setdefault("carve_level", fields.get("level", 0.0))  # the older records' meaning
        try:
            return cls(**fields)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{name}: {err}") from None

    def describe(self) -> str:
        mirror = f" (mirror axis {'xyz'[self.mirror_axis]})" if self.carve == "view+mirror" else ""
        cone = f" (cone level {self.carve_level:+.4f})" if self.carve != "none" and self.carve_level != 0.0 else ""
        return f"carve {self.carve}{mirror}{cone}, level {self.level:+.4f}"

    def cone(self, images: torch.Tensor, views: Optional[torch.Tensor], resolution: int,
             half_side: float) -> Optional[torch.Tensor]:
        """The field this calibration carves with (``silhouette_cone_sdf``) for ``images`` (B, 4, S,
        S) RGBA taken from NMR views ``views`` (B,) (or (B, 2) rows of view and elevation), on the
        N^3 grid over ``[-half_side, half_side]^3``; None when it carves nothing, or without views
        (nothing can be carved)."""
        if self.carve == "none" or views is None:
            return None
        axis = self.mirror_axis if self.carve == "view+mirror" else None
        return silhouette_cone_sdf(images[:, 3], views, resolution, half_side, axis, self.threshold)

    def apply(self, sdf: torch.Tensor, cone: Optional[torch.Tensor]) -> torch.Tensor:
        """(B, N, N, N) SDF grids -> the calibrated grids: intersected with ``cone`` (``self.cone``
        of the images they were predicted from, its field raised by ``carve_level``; None: no
        carving), with the level added to the network's field."""
        out = sdf + float(self.level) if float(self.level) != 0.0 else sdf
        if cone is None:
            return out
        cone = cone.to(sdf)
        return torch.maximum(out, cone + float(self.carve_level) if float(self.carve_level) != 0.0 else cone)


__all__ = ["CARVES", "Calibration"]
