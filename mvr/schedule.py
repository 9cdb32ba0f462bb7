"""The coarse-to-fine schedule: grid resolution per level and the image resolution rule."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import torch

from renderer import Cameras
from sdfcommon.tooling.checks import check_int, check_positive


@dataclass(frozen=True)
class Schedule:
    """Which grids and images each level of the coarse-to-fine optimisation uses.

    Attributes:
        start: grid resolution (samples per side) of the first level (the paper: 8).
        end: grid resolution of the last level (the paper: 64).
        levels: number of levels; resolutions grow geometrically from ``start`` to ``end`` (1: a
            single level at ``end``).
        resolutions: an explicit list of resolutions instead of start/end/levels.
        image_size: a fixed image side for every level; None applies the paper's rule (see
            ``rule_image_size``).
        voxel_footprint_px: the rule's footprint, in pixels across, of a sphere of radius one voxel
            at the box corner farthest from a camera (the paper: 2, a 2x2 block).
        min_image_size, max_image_size: clamp of the rule's result.
    """

    start: int = 8
    end: int = 64
    levels: int = 4
    resolutions: Optional[Sequence[int]] = None
    image_size: Optional[int] = None
    voxel_footprint_px: float = 2.0
    min_image_size: int = 16
    max_image_size: int = 512

    def __post_init__(self) -> None:
        if self.resolutions is not None:
            res = [int(r) for r in self.resolutions]
            if not res or min(res) < 4 or any(b <= a for a, b in zip(res, res[1:])):
                raise ValueError(f"resolutions must be increasing ints >= 4, got {list(self.resolutions)!r}")
            object.__setattr__(self, "resolutions", tuple(res))
        else:
            for name in ("start", "end", "levels"):
                check_int(getattr(self, name), name, minimum=1)
            if self.start < 4 or self.end < self.start:
                raise ValueError(f"need 4 <= start <= end, got start={self.start}, end={self.end}")
            if self.levels > 1 and self.end - self.start + 1 < self.levels:
                raise ValueError(f"levels={self.levels} distinct resolutions do not fit between "
                                 f"start={self.start} and end={self.end}")
        if self.image_size is not None:
            check_int(self.image_size, "image_size", minimum=4)
        check_positive(self.voxel_footprint_px, "voxel_footprint_px")
        if not 4 <= self.min_image_size <= self.max_image_size:
            raise ValueError(f"need 4 <= min_image_size <= max_image_size, got {self.min_image_size}, "
                             f"{self.max_image_size}")

    def grid_resolutions(self) -> list[int]:
        """The grid resolution of each level, increasing."""
        if self.resolutions is not None:
            return list(self.resolutions)
        if self.levels == 1:
            return [self.end]
        ratio = self.end / self.start
        res = [round(self.start * ratio ** (i / (self.levels - 1))) for i in range(self.levels)]
        # Rounding may repeat a value for dense schedules: push duplicates up by one.
        for i in range(1, len(res)):
            res[i] = max(res[i], res[i - 1] + 1)
        if res[-1] != self.end:
            raise ValueError(f"cannot fit {self.levels} levels between {self.start} and {self.end}")
        return res

    def image_size_for(self, cameras: Cameras, bbox_min: torch.Tensor, bbox_max: torch.Tensor,
                       resolution: int) -> int:
        """The image side of a level: ``image_size`` if fixed, else the paper's rule, clamped."""
        if self.image_size is not None:
            return self.image_size
        size = rule_image_size(cameras, bbox_min, bbox_max, resolution, self.voxel_footprint_px)
        return int(min(max(size, self.min_image_size), self.max_image_size))


def rule_image_size(cameras: Cameras, bbox_min: torch.Tensor, bbox_max: torch.Tensor, resolution: int,
                    voxel_footprint_px: float = 2.0) -> int:
    """The paper's image resolution rule (section 5.2).

    A sphere of radius one voxel ``h`` at the box corner farthest from a camera, at distance ``D``,
    spans ``2 h / D`` radians; the image is made just fine enough for that sphere to cover
    ``voxel_footprint_px`` pixels across (2: a 2x2 block), i.e. one pixel spans
    ``2 h / (D * voxel_footprint_px)`` radians at the image centre. With the full vertical field of
    view ``fov`` the image side is then ``H = ceil(2 tan(fov / 2) D voxel_footprint_px / (2 h))``,
    taken over all cameras (they share one image size). Coarser images would let a voxel fall
    between pixels; finer ones cost time without showing the grid anything new.

    Args:
        cameras: (V,) cameras; bbox_min, bbox_max: (3,) the grid's box (world); resolution: samples
            per side of the grid.
    Returns:
        the image side H (square images).
    """
    lo = torch.as_tensor(bbox_min, dtype=torch.float64).reshape(3)
    hi = torch.as_tensor(bbox_max, dtype=torch.float64).reshape(3)
    h = float(((hi - lo) / (resolution - 1)).max())
    corners = torch.stack([torch.where(torch.tensor([(c >> a) & 1 for a in range(3)], dtype=torch.bool), hi, lo)
                           for c in range(8)])  # (8, 3)
    eyes = cameras.eye.to(torch.float64)
    far = (eyes[:, None, :] - corners[None]).norm(dim=-1).amax(dim=1)  # (V,)
    tan_half = torch.tan(torch.deg2rad(cameras.fov_deg.to(torch.float64)) / 2.0)
    size = (2.0 * tan_half * far * voxel_footprint_px / (2.0 * h)).amax()
    return int(math.ceil(float(size) - 1e-9))
