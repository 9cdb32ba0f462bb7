"""ShapePrior: what the training objects that look most like the input say about the space behind
it. A network trained on a few hundred objects for a few dozen passes each learns each category's
depth, not each object's (docs/training_recipe.md); an object whose silhouette in the same view
looks like the input's often has the input's shape behind it too. The prior holds each training
object's silhouettes in the 24 NMR views (the hulls they carve are made from them: images only, no
voxels), finds the training objects whose silhouette in the input's view overlaps the input's best,
and hands the mean of their visual hulls to the pixel-aligned head as one more input per sample;
in training an object is never its own neighbour, so the network learns to use neighbours as it
meets them on new objects."""
from __future__ import annotations

from typing import Callable, Optional

import torch
from torch import nn
from torch.nn import functional as F

from renderer import NMR_NUM_VIEWS
from sdfcommon.tooling.checks import check_int, check_shape
from svr.nmr.metrics import silhouette_features, soft_silhouette_iou
from svr.nmr.views import sample_grid, view_cameras

FEATURE_SIDE = 32  # silhouettes are compared as 2x2 means of the 64^2 alpha (silhouette_features)


def view_grid(points: torch.Tensor, image_size: int = 64) -> torch.Tensor:
    """(24, 1, P, 2) where world ``points`` (P, 3) project in each NMR view, as ``F.grid_sample``'s
    grid (``align_corners=False``)."""
    cams = view_cameras(torch.arange(NMR_NUM_VIEWS), image_size, dtype=points.dtype, device=points.device)
    pix, _ = cams.project(points)
    return sample_grid(pix, image_size).unsqueeze(1)


def visual_hull(alpha: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """The soft visual hull of one object's 24 NMR views.

    Args:
        alpha: (24, H, W) the views' alpha in [0, 1], view k at NMR view k.
        grid: (24, 1, P, 2) ``view_grid`` of the points.
    Returns:
        (P,) the smallest alpha, over the views, where each point projects (bilinear; 0 outside the
        image): 1 well inside every silhouette, 0 where any view shows background.
    """
    check_shape(alpha, "alpha", f"{NMR_NUM_VIEWS}, H, W")
    seen = F.grid_sample(alpha[:, None].to(grid.dtype), grid, mode="bilinear", padding_mode="zeros",
                         align_corners=False)[:, 0, 0]
    return seen.amin(0)


class ShapePrior(nn.Module):
    """The mean visual hull of the training objects whose silhouettes look most like the input's.

    Args:
        objects: training objects held, at least 2 (the training command sets it from the data: ``auto``).
        side: side S of the head's sample grid (the decoder's ``head_points``).
        neighbours: how many nearest objects are averaged (at most ``objects - 1``: one may be excluded).
        categories: categories of the training split (``auto`` in the training command).

    Buffers: ``silhouettes`` (24, objects, 1024) uint8, each object's alpha in each view as 2x2 means,
    and ``first`` (categories,), the global index of each category's first object (so a training
    batch's ``(category, object_index)`` can exclude the object itself), saved with the network and
    filled by ``fill``; ``hulls`` (objects, S^3) uint8, each object's soft visual hull at the head's
    samples, made from the stored silhouettes (``rebuild``) after ``fill`` and after loading weights,
    so a checkpoint holds 10 MB for the demo's 416 objects instead of 24. ``bank`` (24, objects,
    1024) float32, the silhouettes in [0, 1], and ``bank_sums`` (24, objects), made by ``rebuild``
    too and never saved: the lookup of every training step compares against them, which otherwise
    converted the stored bytes each time (41 MB in memory for the demo, 511 MB for the bench's
    5200 objects).
    """

    def __init__(self, objects: int, side: int, neighbours: int = 4, categories: int = 1) -> None:
        super().__init__()
        for name, value in (("objects", objects), ("categories", categories)):
            if value == "auto":
                raise ValueError(f"{name} 'auto' is resolved by the training command from the training split; a "
                                 f"network built directly needs the number")
        check_int(objects, "objects", minimum=2)
        check_int(side, "side", minimum=1)
        check_int(neighbours, "neighbours", minimum=1)
        check_int(categories, "categories", minimum=1)
        self.objects, self.side, self.neighbours = objects, side, min(neighbours, objects - 1)
        self.register_buffer("silhouettes", torch.zeros(NMR_NUM_VIEWS, objects, FEATURE_SIDE ** 2, dtype=torch.uint8))
        self.register_buffer("first", torch.zeros(categories, dtype=torch.long))
        self.register_buffer("hulls", torch.zeros(objects, side ** 3, dtype=torch.uint8), persistent=False)
        self.register_buffer("grid", torch.zeros(NMR_NUM_VIEWS, 1, side ** 3, 2), persistent=False)
        self.register_buffer("bank", torch.zeros(NMR_NUM_VIEWS, objects, FEATURE_SIDE ** 2), persistent=False)
        self.register_buffer("bank_sums", torch.zeros(NMR_NUM_VIEWS, objects), persistent=False)

    def attach(self, points: torch.Tensor) -> None:
        """Where the hulls are sampled: ``points`` (S, S, S, 3), the head's sample positions (``SVRNet``
        calls it with the decoder's ``head_points``)."""
        check_shape(points, "points", f"{self.side}, {self.side}, {self.side}, 3")
        self.grid = view_grid(points.reshape(-1, 3).float().cpu()).to(self.grid.device)
        if bool(self.silhouettes.any()):  # a new prior's hulls are empty, as its silhouettes
            self.rebuild()

    @torch.no_grad()
    def rebuild(self) -> None:
        """Each object's soft visual hull from its stored 32^2 silhouettes, and the lookup's ``bank``."""
        self.bank.copy_(self.silhouettes.float().div_(255.0))
        self.bank_sums.copy_(self.bank.sum(2))
        for g in range(self.objects):
            alpha = self.bank[:, g].reshape(NMR_NUM_VIEWS, FEATURE_SIDE, FEATURE_SIDE)
            self.hulls[g] = visual_hull(alpha, self.grid).mul(255.0).round().to(torch.uint8)

    @torch.no_grad()
    def fill(self, dataset, progress: Optional[Callable[[int], None]] = None) -> None:
        """Reads the training split ``dataset`` (``NMRDataset``: ``images_uint8``, ``offsets``), then
        rebuilds the hulls."""
        if len(dataset) != self.objects:
            raise ValueError(f"the prior holds {self.objects} objects, the training split has {len(dataset)}")
        first = torch.as_tensor(dataset.offsets[:-1], dtype=torch.long)
        if len(first) != len(self.first):
            raise ValueError(f"the prior was built for {len(self.first)} categories, the training split has {len(first)}")
        for g in range(self.objects):
            alpha = torch.from_numpy(dataset.images_uint8(g)[:, 3]).float().div_(255.0)
            self.silhouettes[:, g] = silhouette_features(alpha).mul(255.0).round().to(torch.uint8)
            if progress is not None:
                progress(1)
        self.first.copy_(first)
        self.rebuild()

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self.rebuild()  # the hulls of the silhouettes just loaded

    def nearest(self, alpha: torch.Tensor, views: torch.Tensor, exclude: Optional[torch.Tensor] = None) -> torch.Tensor:
        """(B, neighbours) the training objects whose silhouette in each input's NMR view (``views`` (B,)
        long) overlaps the input's alpha (B, 64, 64) best (soft IoU), ``exclude`` (B,) (-1: none) left out."""
        q = silhouette_features(alpha.float())  # (B, F)
        score = torch.empty(len(q), self.objects, device=q.device)
        for v in torch.unique(views).tolist():  # one product per view
            rows = (views == v).nonzero()[:, 0]
            score[rows] = soft_silhouette_iou(q[rows], self.bank[v], self.bank_sums[v])
        if exclude is not None:
            keep = exclude >= 0
            score[keep.nonzero()[:, 0], exclude[keep]] = -1.0
        return score.topk(self.neighbours, dim=1).indices

    def forward(self, alpha: torch.Tensor, views: torch.Tensor, exclude: Optional[torch.Tensor] = None) -> torch.Tensor:
        """The prior of B inputs.

        Args:
            alpha: (B, 64, 64) the inputs' alpha in [0, 1].
            views: (B,) NMR view indices (fractional allowed) or (B, 2) rows of (view, elevation): the
                nearest NMR view is where the silhouettes are compared.
            exclude: (B,) global training indices to leave out (the inputs' own objects in training),
                -1 for none; None: none.
        Returns:
            (B, S, S, S) in [0, 1]: the neighbours' mean soft hull at the head's samples.
        """
        b = alpha.shape[0]
        check_shape(alpha, "alpha", f"{b}, 64, 64")
        v = torch.as_tensor(views, device=alpha.device)
        v = v[:, 0] if v.ndim == 2 else v
        v = torch.round(v.float()).long() % NMR_NUM_VIEWS
        with torch.no_grad():
            idx = self.nearest(alpha, v, exclude)
            out = self.hulls[idx].float().mean(1).div_(255.0)
        return out.reshape(b, self.side, self.side, self.side).to(alpha.dtype)

    def exclusion(self, category: torch.Tensor, object_index: torch.Tensor) -> torch.Tensor:
        """(B,) global training indices of a training batch's objects."""
        return self.first[category.long()] + object_index.long()


__all__ = ["ShapePrior", "view_grid", "visual_hull"]
