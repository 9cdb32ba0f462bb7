"""One level of multi-view reconstruction: Adam on the grid values with greedy view selection. Paper
section 5.2 (and SPEC section 2): each pass first computes every view's loss; a view whose loss is
above the mean gets up to ``hard_view_updates`` (20) updates, stopping once its loss is below the
mean; the others get ``easy_view_updates`` (5); an update that raises the view's loss moves on to
the next view. A level stops when its loss is below a tolerance, when a pass moves no grid value by
more than a tiny step, when the loss stops improving, or at a pass or time limit.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Sequence, Union

import numpy as np
import torch
from tqdm.auto import tqdm

from renderer import Cameras, Scene, SDFGrid, TraceSettings, render

from sdfcommon.numerics.regularisers import band_regularisers
from sdfcommon.tooling.checks import check_float, check_int, check_positive

from .losses import view_image_losses, view_silhouette_losses

PerLevel = Union[int, float, None, Sequence[Union[int, float, None]]]


@dataclass(frozen=True)
class OptimSettings:
    """Hyperparameters of the per-level optimisation (the YAML says which come from the paper).

    Attributes:
        lr: Adam's learning rate in voxels of the current level (the step is ``lr * voxel size``).
        lr_decay: factor applied to the learning rate after every pass (1: constant).
        betas, eps: Adam's other parameters.
        image_weight, silhouette_weight, eikonal_weight, laplacian_weight: weights of the energy's
            terms (see mvr.losses); the silhouette and Laplacian terms are off in the paper.
        hard_view_updates: updates at most for a view above the mean loss (paper: 20).
        easy_view_updates: updates for the other views (paper: 5).
        max_passes: passes per level at most (an int, or one per level).
        min_passes: passes before the convergence tests may stop a level.
        loss_tol: stop once the mean view loss is below this.
        rel_tol, patience: stop once the mean view loss improved by less than ``rel_tol`` (relative)
            in ``patience`` passes in a row.
        step_tol: stop once a pass moved no grid value by more than ``step_tol`` voxels.
        max_seconds: time limit of a level (None: none; a number, or one per level).
        shuffle_views: visit the views in a new random order each pass (else in rig order).
        fill_cavities: after each pass, close pockets of positive SDF enclosed by the shape (see
            ``fill_cavities``; not in the paper).
    """

    lr: float = 0.05
    lr_decay: float = 0.8
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-5
    image_weight: float = 1.0
    silhouette_weight: float = 1.0
    eikonal_weight: float = 0.01
    laplacian_weight: float = 0.01
    hard_view_updates: int = 20
    easy_view_updates: int = 5
    max_passes: PerLevel = 10
    min_passes: int = 2
    loss_tol: float = 0.0
    rel_tol: float = 0.01
    patience: int = 2
    step_tol: float = 0.01
    max_seconds: PerLevel = None
    shuffle_views: bool = True
    fill_cavities: bool = True

    def __post_init__(self) -> None:
        check_positive(self.lr, "lr")
        if not 0 < self.lr_decay <= 1:
            raise ValueError(f"lr_decay must be in (0, 1], got {self.lr_decay!r}")
        betas = tuple(float(b) for b in self.betas)
        if len(betas) != 2 or not all(0 <= b < 1 for b in betas):
            raise ValueError(f"betas must be two numbers in [0, 1), got {self.betas!r}")
        object.__setattr__(self, "betas", betas)
        for name in ("image_weight", "silhouette_weight", "eikonal_weight", "laplacian_weight", "loss_tol",
                     "rel_tol", "step_tol"):
            check_float(getattr(self, name), name, minimum=0)
        if self.image_weight == 0 and self.silhouette_weight == 0:
            raise ValueError("image_weight and silhouette_weight cannot both be 0: nothing to fit")
        for name in ("hard_view_updates", "easy_view_updates", "patience"):
            check_int(getattr(self, name), name, minimum=1)
        check_int(self.min_passes, "min_passes", minimum=1)
        for name in ("max_passes", "max_seconds"):
            value = getattr(self, name)
            if isinstance(value, (list, tuple)):
                object.__setattr__(self, name, tuple(value))

    def for_level(self, name: str, level: int):
        """A per-level setting (``max_passes``, ``max_seconds``) for level ``level`` (0-based); a
        list shorter than the schedule repeats its last entry."""
        value = getattr(self, name)
        if isinstance(value, tuple):
            if not value:
                raise ValueError(f"{name} must be a number or a non-empty list, got []")
            return value[min(level, len(value) - 1)]
        return value


@dataclass(frozen=True)
class LevelReport:
    """What one level did.

    Attributes:
        level: 0-based index; resolution: grid samples per side; image_size: image side (pixels).
        passes, updates: passes and Adam updates made; seconds: wall time of the level.
        loss_start, loss_end: mean view loss (weighted image + silhouette) before and after.
        image_loss, silhouette_loss: their mean parts at the end; eikonal, laplacian: the
            regularisers (unweighted) at the end.
        stop_reason: "loss_tol", "step_tol", "plateau", "max_passes" or "max_seconds".
        history: one dict per pass (mean loss before it, updates, largest step in voxels, seconds).
    """

    level: int
    resolution: int
    image_size: int
    passes: int
    updates: int
    seconds: float
    loss_start: float
    loss_end: float
    image_loss: float
    silhouette_loss: float
    eikonal: float
    laplacian: float
    stop_reason: str
    history: list = field(default_factory=list)


def fill_cavities(values: torch.Tensor) -> torch.Tensor:
    """Closes interior cavities: positive regions of one grid (Nx, Ny, Nz) that do not reach the
    grid's border through face-adjacent samples (6-connected, so a pocket that leaks out only
    through a corner counts as closed, as marching cubes sees it) are enclosed by the shape,
    invisible from every camera, and only show up as spurious inner surfaces in the mesh; they are
    made negative (``-|f|``).

    Not in the paper: without it, pockets inside the shape (which no view constrains) survive as
    bubbles that dominate the Hausdorff distance. Returns a new tensor (no gradient).
    """
    from scipy import ndimage  # heavy: only the cavity filling needs it

    v = values.detach()
    outside = (v > 0).cpu().numpy()
    labels, count = ndimage.label(outside)
    if count <= 1:
        return v.clone()
    border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                       labels[:, :, [0, -1]].ravel()]))
    enclosed = (labels > 0) & ~np.isin(labels, border)
    if not enclosed.any():
        return v.clone()
    mask = torch.from_numpy(enclosed).to(v.device)
    return torch.where(mask, -v.abs(), v)


class ViewLosses:
    """Renders views of one grid and scores them against the targets.

    Args:
        cameras: (V,) cameras the optimiser believes in (possibly perturbed).
        images: (V, H, W, C) target images; masks: (V, H, W) float target coverage.
        scene, trace, backend: how to render (the scene must produce "shading", and "silhouette"
            when the silhouette weight is positive).
        settings: the weights.
    """

    def __init__(self, cameras: Cameras, images: torch.Tensor, masks: torch.Tensor, scene: Scene,
                 trace: TraceSettings, backend: str, settings: OptimSettings):
        if images.shape[:3] != masks.shape or images.shape[0] != cameras.batch_size:
            raise ValueError(f"images {tuple(images.shape)}, masks {tuple(masks.shape)} and "
                             f"{cameras.batch_size} cameras do not match")
        if tuple(images.shape[1:3]) != tuple(cameras.image_size):
            raise ValueError(f"images are {tuple(images.shape[1:3])} but cameras render {cameras.image_size}")
        self.cameras, self.images, self.masks = cameras, images, masks.float()
        self.scene, self.trace, self.backend, self.settings = scene, trace, backend, settings

    def data_loss(self, grid: SDFGrid, views: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Weighted image + silhouette loss of each of ``views`` (K,) long: (K,) total, image, silhouette."""
        out = render(grid, self.cameras[views], self.scene, self.trace, self.backend)
        s = self.settings
        img = view_image_losses(out.image, self.images[views])
        if s.silhouette_weight > 0:
            sil = view_silhouette_losses(out.silhouette, self.masks[views])
        else:
            sil = torch.zeros_like(img)
        return s.image_weight * img + s.silhouette_weight * sil, img, sil

    @torch.no_grad()
    def all_views(self, grid: SDFGrid, chunk: int = 8) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(V,) total, image and silhouette losses of every view, without gradients."""
        parts = [self.data_loss(grid, torch.arange(i, min(i + chunk, self.cameras.batch_size)))
                 for i in range(0, self.cameras.batch_size, chunk)]
        return tuple(torch.cat([p[k] for p in parts]) for k in range(3))  # type: ignore[return-value]

    def regulariser(self, grid: SDFGrid) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Weighted eikonal + Laplacian terms, and the two unweighted terms: the shared regularisers
        (``sdfcommon.numerics.regularisers``) at every interior vertex of the grid (``mu=None``). The eikonal
        term stays a mean over all the grid's vertices, the box faces (no central difference there)
        counting zero, so its weight per vertex is what it was when the faces had one-sided
        differences; a mean over the interior alone weighs each vertex (N / (N - 2))^3 more, 2.4x at
        the first 8^3 level, which measurably loosened the torus (docs/mvr_method.md)."""
        s = self.settings
        eik, lap = band_regularisers(grid.values, cube_voxel_size(grid), mu=None)
        n = grid.values.shape[1:]
        eik = eik * ((n[0] - 2) * (n[1] - 2) * (n[2] - 2) / (n[0] * n[1] * n[2]))
        return s.eikonal_weight * eik + s.laplacian_weight * lap, eik, lap


def cube_voxel_size(grid: SDFGrid) -> float:
    """The grid's sample spacing, the same along the three axes (mvr's grids are cubes)."""
    h = [float(v) for v in grid.voxel_size]
    if max(h) - min(h) > 1e-6 * max(h):
        raise ValueError(f"the regularisers need equal spacing along x, y, z; the grid's is {h}")
    return h[0]


def optimise_level(grid: SDFGrid, losses: ViewLosses, level: int = 0, seed: int = 0, progress: bool = True,
                   description: str = "") -> tuple[SDFGrid, LevelReport]:
    """Fits one grid to the target views (one level of the coarse-to-fine schedule).

    Args:
        grid: the starting grid (one grid, B = 1); its values are copied, not changed.
        losses: the views, targets and settings (weights, Adam, stopping rules: ``losses.settings``).
        level: 0-based level index (for per-level settings).
        seed: seeds the order of the views.
        progress: show a tqdm bar over the passes.
    Returns:
        the fitted grid (detached) and the level's report.
    """
    if grid.batch_size != 1:
        raise ValueError(f"optimise_level fits one grid, got a batch of {grid.batch_size}")
    settings = losses.settings
    t_start = time.perf_counter()
    voxel = float(grid.voxel_size.min())
    values = grid.values.detach().clone().requires_grad_(True)
    lo, hi = grid.bbox_min, grid.bbox_max
    opt = torch.optim.Adam([values], lr=settings.lr * voxel, betas=settings.betas, eps=settings.eps)
    gen = torch.Generator().manual_seed(int(seed) * 1000 + level)
    max_passes = int(settings.for_level("max_passes", level))
    max_seconds = settings.for_level("max_seconds", level)
    n_views = losses.cameras.batch_size

    def current() -> SDFGrid:
        return SDFGrid(values, lo, hi)

    history: list[dict] = []
    updates = 0
    stop = "max_passes"
    view_loss, img_v, sil_v = losses.all_views(SDFGrid(values.detach(), lo, hi))
    loss_start = float(view_loss.mean())
    bar = tqdm(total=max_passes, desc=description or f"level {level}", disable=not progress, leave=True,
               dynamic_ncols=True)
    stalls = 0
    timed_out = False
    try:
        for pass_index in range(max_passes):
            t_pass = time.perf_counter()
            mean = float(view_loss.mean())
            before = values.detach().clone()
            pass_updates = 0
            order = torch.randperm(n_views, generator=gen) if settings.shuffle_views else torch.arange(n_views)
            for v in order.tolist():
                hard = float(view_loss[v]) > mean
                budget = settings.hard_view_updates if hard else settings.easy_view_updates
                previous = math.inf
                for k in range(budget):
                    g = current()
                    data, _, _ = losses.data_loss(g, torch.tensor([v]))
                    reg, _, _ = losses.regulariser(g)
                    total = data[0] + reg
                    value = float(total.detach())
                    if k > 0 and value > previous:
                        break  # the last update raised this view's loss: move on
                    if hard and k > 0 and float(data[0].detach()) < mean:
                        break
                    previous = value
                    opt.zero_grad(set_to_none=True)
                    total.backward()
                    opt.step()
                    pass_updates += 1
                if max_seconds is not None and time.perf_counter() - t_start > max_seconds:
                    timed_out = True
                    break
            updates += pass_updates
            for group in opt.param_groups:
                group["lr"] *= settings.lr_decay
            if settings.fill_cavities:
                with torch.no_grad():
                    values.copy_(fill_cavities(values[0]).unsqueeze(0))
            step = float((values.detach() - before).abs().max()) / voxel
            view_loss, img_v, sil_v = losses.all_views(SDFGrid(values.detach(), lo, hi))
            new_mean = float(view_loss.mean())
            history.append({"pass": pass_index, "loss_before": mean, "loss_after": new_mean,
                            "updates": pass_updates, "max_step_voxels": step,
                            "seconds": time.perf_counter() - t_pass})
            bar.update(1)
            bar.set_postfix(loss=f"{new_mean:.3e}", step=f"{step:.3f}")
            if timed_out:
                stop = "max_seconds"
                break
            improved = (mean - new_mean) / max(abs(mean), 1e-30)
            stalls = stalls + 1 if improved < settings.rel_tol else 0
            if pass_index + 1 >= settings.min_passes:
                if new_mean <= settings.loss_tol:
                    stop = "loss_tol"
                    break
                if step <= settings.step_tol:
                    stop = "step_tol"
                    break
                if stalls >= settings.patience:
                    stop = "plateau"
                    break
    finally:
        bar.close()

    final = SDFGrid(values.detach().clone(), lo, hi)
    with torch.no_grad():
        _, eik, lap = losses.regulariser(final)
    report = LevelReport(
        level=level, resolution=grid.resolution[0], image_size=losses.cameras.image_size[0],
        passes=len(history), updates=updates, seconds=time.perf_counter() - t_start,
        loss_start=loss_start, loss_end=float(view_loss.mean()), image_loss=float(img_v.mean()),
        silhouette_loss=float(sil_v.mean()), eikonal=float(eik), laplacian=float(lap),
        stop_reason=stop, history=history,
    )
    return final, report
