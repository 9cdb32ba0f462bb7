"""The typed settings of the mesh-to-NMR builder (configs/build.yaml), built from the composed config
by ``sdfcommon.tooling.settings.build_settings``: an unknown key, a value of the wrong type or one out
of range fails with a message naming the key before anything is written. Every default is written
once, in the YAML."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Optional

from sdfcommon.tooling.checks import check_float, check_int
from svr.data.build.layouts import LAYOUTS, check_split_ratios
from svr.data.build.voxels import DIRECTION_SETS

# The settings that change the data (part of the build's plan: a rerun with other values starts
# afresh); the others (workers, progress, ...) change only how it is made.
DATA_FIELDS = ("input", "layout", "categories", "split_lists", "split_ratios", "seed", "views", "elevation",
               "distance", "image_size", "supersample", "voxel_resolution", "ray_directions", "orient",
               "sdf_resolution", "extra_views")


@dataclass(frozen=True)
class BuildSettings:
    """The builder's settings (configs/build.yaml; its comments say more).

    Attributes:
        input: the mesh folder (one subfolder per category). out: the NMR-format folder made
            (outside ``input``: ``build_dataset`` checks).
        layout: "auto", "shapenet_v1", "shapenet_v2" or "flat".
        categories: ids or names to build (None: every category folder with meshes).
        split_lists: a folder of ``{cid}_{split}ids.txt`` lists (None: seeded ratios).
        split_ratios: train, val, test fractions (each > 0, summing to 1) for categories without
            lists. seed: their shuffle.
        views, elevation, distance: the cameras (NMR: 24, 30 degrees, 2.732).
        image_size: image side (NMR: 64). supersample: rays per pixel side.
        voxel_resolution: voxel grid side (NMR: 32). ray_directions: 3, 7 or 13 line directions
            of the voxel votes. orient: orient faces consistently before the votes.
        sdf_resolution: side of the optional signed distance grids (0: none).
        extra_views: K extra views of each training object (any azimuth, elevation 10 to 50
            degrees; ``svr.nmr.format.extra_view_files``), 0: none.
        workers: processes (None: one per core; 0: this process alone).
        overwrite: replace a finished build in ``out`` made with other settings.
        keep_work: keep the per-object results (``out/.build``) after packing. progress: a bar.
    """

    input: str
    out: str
    layout: str
    categories: Optional[list[str]]
    split_lists: Optional[str]
    split_ratios: list[float]
    seed: int
    views: int
    elevation: float
    distance: float
    image_size: int
    supersample: int
    voxel_resolution: int
    ray_directions: int
    orient: bool
    sdf_resolution: int
    extra_views: int
    workers: Optional[int]
    overwrite: bool
    keep_work: bool
    progress: bool

    def __post_init__(self) -> None:
        for name in ("input", "out"):
            if not str(getattr(self, name)).strip():
                raise ValueError(f"{name} must name a folder, got an empty string")
        if self.layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {LAYOUTS}, got {self.layout!r}")
        if isinstance(self.categories, str):
            raise ValueError(f"categories must be a list of ids or names, got the string {self.categories!r}")
        check_split_ratios(self.split_ratios)
        check_int(self.seed, "seed")
        check_int(self.views, "views", minimum=1)
        check_float(self.elevation, "elevation", -89.0, 89.0)
        check_float(self.distance, "distance", minimum=0.0)
        if not self.distance > 0.9:
            raise ValueError(f"distance must exceed 0.9 (the eye must lie outside the normalised object), "
                             f"got {self.distance!r}")
        check_int(self.image_size, "image_size", minimum=1)
        check_int(self.supersample, "supersample", minimum=1)
        check_int(self.voxel_resolution, "voxel_resolution", minimum=2)
        if self.ray_directions not in DIRECTION_SETS:
            raise ValueError(f"ray_directions must be one of {sorted(DIRECTION_SETS)}, got {self.ray_directions!r}")
        check_int(self.sdf_resolution, "sdf_resolution", minimum=0)
        if self.sdf_resolution == 1:
            raise ValueError("sdf_resolution must be 0 (no grids) or at least 2, got 1")
        check_int(self.extra_views, "extra_views", minimum=0)
        if self.workers is not None:
            check_int(self.workers, "workers", minimum=0)

    def data_record(self) -> dict:
        """The settings that change the data, as plain values (the build's plan)."""
        record = dataclasses.asdict(self)
        out = {k: record[k] for k in DATA_FIELDS}
        if not self.extra_views:
            del out["extra_views"]  # a build without them keeps the plan it had before the setting existed
        return out


__all__ = ["BuildSettings", "DATA_FIELDS"]
