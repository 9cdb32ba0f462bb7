"""The batch the single-view data modules yield and the training/evaluation code consumes."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch

import renderer


@dataclass(frozen=True)
class ShadingModel:
    """How a dataset's RGB was shaded, when known (the procedural data), so the training loss can
    render the same shading with renderer.Scene. None of this is known for NMR ShapeNet."""

    light_direction: tuple[float, float, float]
    light_intensity: float
    ambient: float
    albedo: tuple[float, float, float]
    background: tuple[float, float, float]

    def scene(self, effects: tuple[str, ...] = ("silhouette", "shading"), **kwargs):
        """The renderer.Scene that shades like the dataset: one directional light (world frame),
        ambient, albedo and background. ``kwargs`` go to Scene (e.g. ``silhouette_sigma``)."""
        return renderer.Scene(effects=effects,
                              lights=(renderer.DirectionalLight(tuple(self.light_direction),
                                                                float(self.light_intensity)),),
                              ambient=float(self.ambient), albedo=tuple(self.albedo),
                              background=tuple(self.background), **kwargs)


@dataclass
class SVRBatch:
    """B objects, V views each.

    Attributes:
        images: (B, V, 4, 64, 64) float32 RGBA in [0, 1] (alpha = anti-aliased silhouette, RGB on a
            white background after inversion detection); view 0 of each object is the network input.
        view_ids: (B, V) long NMR view indices (0..23), for renderer.Cameras.nmr.
        voxels: (B, 32, 32, 32) bool solid voxels in the NMR voxel frame (svr/nmr/voxels.py).
        category: (B,) long index into the data module's ``categories`` list.
        object_index: (B,) long index of the object within its category and split.
        cameras: None where every view is one of the 24 NMR views; else (B, V, 2) float32 rows of
            (view, elevation in degrees) for ``svr.nmr.views.view_cameras``: a batch with extra
            training views (``svr.data.datasets.NMRDataset``: any azimuth, other elevations), whose
            ``view_ids`` then hold the nearest NMR view of each.
    """

    images: torch.Tensor
    view_ids: torch.Tensor
    voxels: torch.Tensor
    category: torch.Tensor
    object_index: torch.Tensor
    cameras: Optional[torch.Tensor] = None

    @property
    def views(self) -> torch.Tensor:
        """What renders each view (``svr.nmr.views.render_views``): ``cameras`` when the batch has
        them, else ``view_ids``."""
        return self.cameras if self.cameras is not None else self.view_ids

    def to(self, device) -> "SVRBatch":
        return SVRBatch(*(t.to(device) for t in (self.images, self.view_ids, self.voxels, self.category,
                                                  self.object_index)),
                        cameras=None if self.cameras is None else self.cameras.to(device))

    def __len__(self) -> int:
        return self.images.shape[0]


def collate_batch(items: list[dict]) -> SVRBatch:
    """Stacks per-sample dicts with keys images, view_ids, voxels, category, object_index, and
    cameras where any item has them (an item without: its NMR views at the NMR elevation)."""
    view_ids = torch.stack([torch.as_tensor(i["view_ids"]) for i in items]).long()
    cameras = None
    if any("cameras" in i for i in items):
        nmr = torch.stack([view_ids.float(), torch.full(view_ids.shape, renderer.NMR_ELEVATION_DEG)], dim=-1)
        cameras = torch.stack([torch.as_tensor(i["cameras"], dtype=torch.float32) if "cameras" in i else nmr[k]
                               for k, i in enumerate(items)])
    return SVRBatch(
        images=torch.stack([torch.as_tensor(i["images"]) for i in items]).float(),
        view_ids=view_ids,
        voxels=torch.stack([torch.as_tensor(i["voxels"]) for i in items]).bool(),
        category=torch.as_tensor([int(i["category"]) for i in items], dtype=torch.long),
        object_index=torch.as_tensor([int(i["object_index"]) for i in items], dtype=torch.long),
        cameras=cameras,
    )


__all__ = ["SVRBatch", "ShadingModel", "collate_batch"]
