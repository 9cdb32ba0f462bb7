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
from dataclasses import dataclass, field, replace
from typing import Callable, Optional, Sequence, Union

import numpy as np
import torch
from tqdm.auto import tqdm

from renderer import Cameras, Scene, SDFGrid, TraceSettings, render, rotation_matrices

from sdfcommon.numerics.hull import signed_pixel_distance, visual_hull
from sdfcommon.numerics.redistance import redistance
from sdfcommon.numerics.regularisers import band_regularisers, box_face_eikonal_sum
from sdfcommon.tooling.checks import check_float, check_int, check_positive

from .losses import IMAGE_LOSSES, view_image_losses, view_silhouette_losses

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
        silhouette_tolerance: the silhouette term's dead zone: a pixel whose soft coverage is within
            this of its target costs nothing (0: the plain squared difference; see
            ``view_silhouette_losses``). 0.27 is the coverage a ray gets one soft-silhouette width
            (``scene.silhouette_sigma`` pixels) from the surface: ``sigmoid(-1)``.
        image_loss: "l1" (the authors' code's) or "l2" (the paper's) image loss.
        image_levels: levels of the image pyramid the image loss averages over (1: the images alone).
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
        carve: after each pass, raise the values to the target silhouettes' visual hull less
            ``carve_tolerance`` voxels (``ViewLosses.carve``): whatever the fit grew outside the
            cones of the views' silhouettes goes (not in the paper; docs/mvr_method.md).
        carve_tolerance: how far (voxels of the level) the shape may reach outside the hull.
        redistance: after each pass (after carving and filling), replace the values away from the
            surface by the distance to it, the surface kept (``sdfcommon.numerics.redistance``;
            Vicini et al. 2022 re-distance after every step; not in the paper).
        regulariser_band: the regularisers at the vertices within this many voxels of the surface
            only (None: every vertex, the box's faces too); needs ``redistance``, which keeps the
            values beyond it a distance, and costs a fraction at fine levels.
        erosion: the last ``erosion_levels`` levels start from the level before shrunk by this many
            voxels of their own grid (the values raised by it), so that they grow the surface back
            from inside and a concavity the coarser level bridged opens again (0: as it ends;
            not in the paper; docs/mvr_method.md).
        erosion_keep: with it, a part is thinned to no less than this half-thickness (voxels) and
            one thinner not at all (``shrink``): the erosion does not remove thin parts, which a
            level does not grow back (None: every value raised by ``erosion``).
        erosion_levels: how many of the schedule's last levels start shrunk (never the first; no
            level where the cameras are refined, ``cameras``: the poses would read the shrunk
            start's silhouettes as camera error, bunny00's seed 1 3.5 times the noiseless distance).
        erosion_pass_factor: a level that starts shrunk runs up to this many times its
            ``max_passes`` (rounded up): it has more to grow back.
        residual_carve: after the last level, carve the samples along the rays of badly shaded
            pixels to this many samples behind the surface, then refit (0: off; with
            ``cameras`` the rays are those of the refined cameras, which the refit goes on refining;
            measured in docs/mvr_method.md).
        residual_carve_rounds: how many times to carve and refit (each a stage of its own).
        residual_carve_views, residual_carve_threshold: the views whose rays must agree on a sample,
            and the image difference (mean over channels) that makes a pixel bad.
        residual_carve_edge: pixels this close to either silhouette's edge cast no carving ray.
        refit_passes, refit_lr_scale: the refit's passes at most, at ``lr`` times this (at the full
            step the per-view updates walk back into the bridge: docs/mvr_method.md).
        batch_steps: 0: a pass updates view by view (the paper's way); N: a pass is N Adam steps on
            the mean loss of all views at once (a step no view's own update can walk off with).
        refit_batch_steps: ``batch_steps`` for the refit after the residual carve.
        cameras: refine each camera's pose (an orbit about the origin, a distance and an aim, ``CameraPoses``) with
            the shape, by the render's camera gradient (not in the paper; for inexact cameras).
        camera_lr: Adam's step for the poses (radians for the orbit and the aim, the log of the
            distance; ``CameraPoses``).
        camera_levels: the cameras are refined in the schedule's last ``camera_levels`` levels
            (earlier, the coarse shape's errors would be put into the cameras).
        camera_rounds: with ``cameras``, how many times the whole schedule runs: each later round
            starts again from the sphere with the cameras as the rounds before left them (every
            level sees the corrected cameras, the last ``camera_levels`` refine them further, with
            the step and the Adam state the round before left), so that the coarse levels no longer
            build the given cameras' errors into the shape.
    """

    lr: float = 0.05
    lr_decay: float = 0.8
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-5
    image_weight: float = 1.0
    silhouette_weight: float = 1.0
    silhouette_tolerance: float = 0.27
    eikonal_weight: float = 0.01
    laplacian_weight: float = 0.01
    image_loss: str = "l1"
    image_levels: int = 1
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
    carve: bool = True
    carve_tolerance: float = 1.0
    redistance: bool = False
    regulariser_band: Optional[float] = None
    erosion: float = 2.0
    erosion_keep: Optional[float] = 1.5
    erosion_levels: int = 1
    erosion_pass_factor: float = 2.0
    residual_carve: float = 2.0
    residual_carve_rounds: int = 1
    residual_carve_views: int = 3
    residual_carve_threshold: float = 0.1
    residual_carve_edge: int = 3
    refit_passes: int = 10
    refit_lr_scale: float = 0.2
    batch_steps: int = 0
    refit_batch_steps: int = 0
    cameras: bool = False
    camera_lr: float = 0.003
    camera_levels: int = 1
    camera_rounds: int = 1

    def __post_init__(self) -> None:
        check_positive(self.lr, "lr")
        for name in ("cameras", "carve", "fill_cavities", "redistance", "shuffle_views"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name} must be true or false, got {getattr(self, name)!r}")
        check_float(self.carve_tolerance, "carve_tolerance", minimum=0)
        if self.regulariser_band is not None:
            check_positive(self.regulariser_band, "regulariser_band")
            if not self.redistance:
                raise ValueError(f"regulariser_band={self.regulariser_band} needs redistance=true (beyond the band "
                                 f"nothing else keeps the values a distance)")
        check_float(self.silhouette_tolerance, "silhouette_tolerance", minimum=0, maximum=0.45)
        check_float(self.erosion, "erosion", minimum=0)
        if self.erosion_keep is not None:
            check_float(self.erosion_keep, "erosion_keep", minimum=0)
        check_int(self.erosion_levels, "erosion_levels", minimum=1)
        check_float(self.erosion_pass_factor, "erosion_pass_factor", minimum=1)
        check_float(self.residual_carve, "residual_carve", minimum=0)
        check_int(self.residual_carve_rounds, "residual_carve_rounds", minimum=1)
        check_int(self.residual_carve_views, "residual_carve_views", minimum=1)
        check_float(self.residual_carve_threshold, "residual_carve_threshold", minimum=0)
        check_int(self.residual_carve_edge, "residual_carve_edge", minimum=0)
        check_int(self.refit_passes, "refit_passes", minimum=1)
        check_positive(self.refit_lr_scale, "refit_lr_scale")
        check_int(self.batch_steps, "batch_steps", minimum=0)
        check_int(self.refit_batch_steps, "refit_batch_steps", minimum=0)
        if self.image_loss not in IMAGE_LOSSES:
            raise ValueError(f"image_loss must be one of {', '.join(IMAGE_LOSSES)}, got {self.image_loss!r}")
        check_int(self.image_levels, "image_levels", minimum=1)
        check_positive(self.camera_lr, "camera_lr")
        check_int(self.camera_levels, "camera_levels", minimum=1)
        check_int(self.camera_rounds, "camera_rounds", minimum=1)
        if self.camera_rounds > 1 and not self.cameras:
            raise ValueError(f"camera_rounds={self.camera_rounds} needs cameras=true (later rounds use the refined "
                             f"cameras)")
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
        object.__setattr__(self, "max_passes", _per_level(self.max_passes, "max_passes", "an integer >= 1",
                                                          _is_pass_count))
        object.__setattr__(self, "max_seconds", _per_level(self.max_seconds, "max_seconds",
                                                           "a positive number or null (no limit)", _is_time_limit))

    def carve_rounds(self) -> int:
        """The residual carve's rounds after the schedule (none where ``residual_carve`` is 0). With
        ``cameras`` they come after the last round, when the cameras are as refined as they get."""
        return self.residual_carve_rounds if self.residual_carve > 0 else 0

    def erodes(self, level: int, levels: int) -> bool:
        """Whether level ``level`` (0-based) of a schedule of ``levels`` levels starts from the
        level before shrunk by ``erosion`` voxels (never where the cameras are refined)."""
        return self.erosion > 0 and not self.cameras and level > 0 and level >= levels - self.erosion_levels

    def passes(self, level: int, levels: int) -> int:
        """Passes at most of level ``level`` of a schedule of ``levels`` levels: ``max_passes``,
        times ``erosion_pass_factor`` (rounded up) where the level starts shrunk."""
        n = int(self.for_level("max_passes", level))
        return math.ceil(n * self.erosion_pass_factor) if self.erodes(level, levels) else n

    def for_level(self, name: str, level: int):
        """A per-level setting (``max_passes``, ``max_seconds``) for level ``level`` (0-based); a
        list shorter than the schedule repeats its last entry."""
        value = getattr(self, name)
        if isinstance(value, tuple):
            return value[min(level, len(value) - 1)]
        return value


def _is_pass_count(v: object) -> bool:
    return not isinstance(v, bool) and isinstance(v, int) and v >= 1


def _is_time_limit(v: object) -> bool:
    return v is None or (not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) and v > 0)


def _per_level(value: PerLevel, name: str, expected: str, valid: Callable[[object], bool]) -> PerLevel:
    """A per-level setting, one value or a non-empty list of them (one per level; made a tuple),
    each of which ``valid`` accepts.

    Raises:
        ValueError: ``"<name> must be <expected>, or a non-empty list of them (one per level), got <value!r>"``.
    """
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    if not values or not all(valid(v) for v in values):
        raise ValueError(f"{name} must be {expected}, or a non-empty list of them (one per level), got {value!r}")
    return tuple(values) if isinstance(value, (list, tuple)) else value


@dataclass(frozen=True)
class LevelReport:
    """What one level did.

    Attributes:
        level: the level's number, 1 for the first (as the log, levels.json/csv and the checkpoints
            ``level_01.pt``... count); resolution: grid samples per side; image_size: image side (pixels).
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


def shrink(values: torch.Tensor, voxel: float, erosion: float, keep: Optional[float]) -> torch.Tensor:
    """``values`` (N, N, N), an SDF of spacing ``voxel``, with its shape shrunk by ``erosion``
    voxels (``OptimSettings.erosion``): every value raised by that much, or with ``keep``, by
    ``min(erosion, max(0, depth - keep))`` voxels, where ``depth`` is the deepest inside value
    within ``erosion + keep`` voxels of the sample (in voxels): a part whose half-thickness is
    under ``erosion + keep`` is thinned to ``keep`` at most, one under ``keep`` not at all, so the
    erosion does not remove what the level could not grow back. Returns a new tensor (no gradient)."""
    v = values.detach()
    if keep is None:
        return v + erosion * voxel
    from scipy import ndimage  # heavy: only the thinning needs it

    radius = erosion + keep
    n = int(math.ceil(radius))
    offsets = np.mgrid[-n:n + 1, -n:n + 1, -n:n + 1]
    ball = (offsets ** 2).sum(0) <= radius * radius
    depth = -ndimage.minimum_filter(v.cpu().numpy(), footprint=ball, mode="nearest") / voxel
    amount = np.clip(depth - keep, 0.0, erosion) * voxel
    return v + torch.from_numpy(amount).to(device=v.device, dtype=v.dtype)


@torch.no_grad()
def residual_carve(grid: SDFGrid, losses: "ViewLosses", depth: float, views: int = 3, threshold: float = 0.1,
                   edge_px: int = 3, chunk: int = 8) -> SDFGrid:
    """``grid`` with the samples along the rays of badly shaded pixels set outside: for each of the
    views' pixels that both the grid and the target hit, ``edge_px`` pixels or more from either
    silhouette's edge (0: any), whose image differs from the target's by more than ``threshold`` (mean
    over the channels), the ray from half a sample before the grid's hit point to ``depth`` samples
    behind it; a sample that the rays of at least ``views`` views pass within half a sample of is
    raised to half a sample outside. Where a concavity was bridged, the rays that should have reached
    its floor agree on the bridge from several sides (docs/mvr_method.md: with a refit at a small
    step, the fandisk's fillet stayed open). A new grid; no gradient."""
    from scipy import ndimage

    n = grid.resolution
    lo, vox = grid.bbox_min.to(torch.float32), grid.voxel_size.to(torch.float32)
    count = torch.zeros(int(np.prod(n)), dtype=torch.int32)
    top = torch.tensor(n) - 1  # the last sample's index on each axis
    scene = replace(losses.scene, effects=tuple(dict.fromkeys((*losses.scene.effects, "depth"))))
    for start in range(0, losses.cameras.batch_size, chunk):
        ids = torch.arange(start, min(start + chunk, losses.cameras.batch_size))
        cams = losses.cameras_of(ids)
        out = render(grid, cams, scene, losses.trace, losses.backend)
        target, mask = losses.images[ids], losses.masks[ids] >= 0.5
        both = out.hit & mask
        rims = np.stack([ndimage.binary_dilation(m ^ ndimage.binary_erosion(m), iterations=edge_px)
                         if edge_px > 0 else np.zeros_like(m)  # (scipy reads 0 iterations as "until it stops")
                         for m in (mask | out.hit).cpu().numpy()])
        bad = both & ~torch.from_numpy(rims) & ((out.image - target).abs().mean(-1) > threshold)
        origins, dirs = cams.rays()
        view_of = torch.nonzero(bad)[:, 0]
        hit = origins[bad].float() + out.depth[bad][:, None].float() * dirs[bad].float()
        step = dirs[bad].float() * float(vox.min())
        seen = torch.zeros(len(ids), len(count), dtype=torch.bool)
        for t in np.arange(-0.5, depth + 1e-6, 0.5):
            idx = torch.minimum(torch.round((hit + float(t) * step - lo) / vox).long().clamp(min=0), top)
            seen[view_of, (idx[:, 0] * n[1] + idx[:, 1]) * n[2] + idx[:, 2]] = True
        count += seen.sum(0, dtype=torch.int32)
    carve = (count >= views).reshape(n)
    values = grid.values[0].detach().clone()
    values[carve] = torch.clamp(values[carve], min=0.5 * float(vox.min()))
    return SDFGrid(values[None], grid.bbox_min, grid.bbox_max)


class CameraPoses:
    """Corrections of V camera poses, refined with the shape (``OptimSettings.cameras``). Per camera:
    an orbit (a rotation vector about the scene's origin that turns the eye and the camera's axes
    together: the camera sees the object from another side), a change of its distance to the origin
    (the log of the factor), and an aim (a turn about its own eye, world axes, radians). All are
    zero at the start and have their own Adam (step ``lr``). The basis matters: an eye shifted
    sideways and the camera turned to keep the object in the frame move the image almost alike, so
    a correction in those terms climbs a narrow valley (measured, docs/mvr_noise.md); orbit, distance
    and aim each move it differently (parallax, scale, a shift of the whole image). Each camera's
    corrections are parameters of their own, so an update moves only the cameras whose views were
    rendered since the last one (Adam would move the others on their old momentum, were they one
    tensor with zero gradients).
    """

    PARAMETERISATION = "orbit-distance-aim"

    def __init__(self, views: int, lr: float):
        check_int(views, "views", minimum=1)
        check_positive(lr, "camera_lr")
        self.orbits = [torch.zeros(3, dtype=torch.float64, requires_grad=True) for _ in range(views)]
        self.distances = [torch.zeros(1, dtype=torch.float64, requires_grad=True) for _ in range(views)]
        self.aims = [torch.zeros(3, dtype=torch.float64, requires_grad=True) for _ in range(views)]
        self.opt = torch.optim.Adam(self.orbits + self.distances + self.aims, lr=lr)

    @property
    def orbit(self) -> torch.Tensor:
        """(V, 3) the orbits' rotation vectors (detached)."""
        return torch.stack([r.detach() for r in self.orbits])

    @property
    def distance(self) -> torch.Tensor:
        """(V,) the logs of the distance factors (detached)."""
        return torch.cat([d.detach() for d in self.distances])

    @property
    def aim(self) -> torch.Tensor:
        """(V, 3) the aims' rotation vectors (detached)."""
        return torch.stack([r.detach() for r in self.aims])

    def apply(self, cameras: Cameras, views: torch.Tensor) -> Cameras:
        """``cameras[views]`` of all V cameras, orbited, moved along their line to the origin and
        turned by their corrections (differentiable in them while grad is enabled)."""
        if cameras.batch_size != len(self.orbits):
            raise ValueError(f"{cameras.batch_size} cameras for {len(self.orbits)} pose corrections")
        index = [int(v) for v in views.reshape(-1).tolist()]
        cams = cameras[views]
        orbit = torch.stack([self.orbits[v] for v in index]).to(cams.dtype)
        log_distance = torch.stack([self.distances[v] for v in index]).to(cams.dtype)
        aim = torch.stack([self.aims[v] for v in index]).to(cams.dtype)
        turn = rotation_matrices(orbit)  # (K, 3, 3)
        eye = (turn @ cams.eye[..., None])[..., 0] * torch.exp(log_distance)
        return cams.moved(orbit, eye - cams.eye).moved(aim)

    def step(self) -> None:
        """One Adam update of the cameras that received a gradient, then their gradients cleared,
        then the mean orbit and the mean change of distance of all cameras removed: every camera
        orbited alike is the shape turned the other way, every distance scaled alike the shape
        scaled, which the images cannot tell apart (the rig's corrections of camera noise average
        out)."""
        self.opt.step()
        self.opt.zero_grad(set_to_none=True)
        with torch.no_grad():
            for group in (self.orbits, self.distances):
                mean = torch.stack([p.detach() for p in group]).mean(0)
                for p in group:
                    p.sub_(mean)

    def decay(self, factor: float) -> None:
        """Multiplies Adam's step by ``factor`` (after each pass, as the grid's)."""
        for group in self.opt.param_groups:
            group["lr"] *= factor

    def state(self) -> dict:
        """The corrections and Adam's state (for a checkpoint)."""
        return {"parameterisation": self.PARAMETERISATION, "orbit": self.orbit.clone(),
                "distance": self.distance.clone(), "aim": self.aim.clone(), "adam": self.opt.state_dict()}

    @classmethod
    def check_state(cls, state, where: str) -> None:
        """ValueError naming ``where`` unless ``state`` is a ``state()`` of this parameterisation (a
        checkpoint of an earlier version holds a turn and a shift of each eye)."""
        if not isinstance(state, dict) or state.get("parameterisation") != cls.PARAMETERISATION:
            raise ValueError(f"{where} holds camera corrections of an earlier version (a turn and a shift of each "
                             f"eye); resume=false starts this run afresh")

    def load(self, state: dict) -> None:
        """Restores ``state()``'s corrections and Adam's state; ValueError for the state of another
        parameterisation (a checkpoint of an earlier version)."""
        self.check_state(state, "the checkpoint")
        with torch.no_grad():
            for k, (o, d, a) in enumerate(zip(self.orbits, self.distances, self.aims)):
                o.copy_(state["orbit"][k])
                d.copy_(state["distance"][k:k + 1])
                a.copy_(state["aim"][k])
        self.opt.load_state_dict(state["adam"])


class ViewLosses:
    """Renders views of one grid and scores them against the targets.

    Args:
        cameras: (V,) cameras the optimiser believes in (possibly perturbed).
        images: (V, H, W, C) target images; masks: (V, H, W) float target coverage.
        scene, trace, backend: how to render (the scene must produce "shading", and "silhouette"
            when the silhouette weight is positive).
        settings: the weights.
        poses: corrections of the cameras refined with the shape (``CameraPoses``), or None.
    """

    def __init__(self, cameras: Cameras, images: torch.Tensor, masks: torch.Tensor, scene: Scene,
                 trace: TraceSettings, backend: str, settings: OptimSettings,
                 poses: Optional[CameraPoses] = None):
        if images.shape[:3] != masks.shape or images.shape[0] != cameras.batch_size:
            raise ValueError(f"images {tuple(images.shape)}, masks {tuple(masks.shape)} and "
                             f"{cameras.batch_size} cameras do not match")
        if tuple(images.shape[1:3]) != tuple(cameras.image_size):
            raise ValueError(f"images are {tuple(images.shape[1:3])} but cameras render {cameras.image_size}")
        self.cameras, self.images, self.masks = cameras, images, masks.float()
        self.scene, self.trace, self.backend, self.settings = scene, trace, backend, settings
        self.poses = poses
        self._pixel_distance: Optional[torch.Tensor] = None

    def cameras_of(self, views: torch.Tensor) -> Cameras:
        """The cameras of ``views`` (K,) long, with the poses' corrections where there are any."""
        return self.cameras[views] if self.poses is None else self.poses.apply(self.cameras, views)

    def data_loss(self, grid: SDFGrid, views: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Weighted image + silhouette loss of each of ``views`` (K,) long: (K,) total, image, silhouette."""
        out = render(grid, self.cameras_of(views), self.scene, self.trace, self.backend)
        s = self.settings
        img = view_image_losses(out.image, self.images[views], s.image_loss, s.image_levels)
        if s.silhouette_weight > 0:
            sil = view_silhouette_losses(out.silhouette, self.masks[views], s.silhouette_tolerance)
        else:
            sil = torch.zeros_like(img)
        return s.image_weight * img + s.silhouette_weight * sil, img, sil

    @torch.no_grad()
    def all_views(self, grid: SDFGrid, chunk: int = 8) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(V,) total, image and silhouette losses of every view, without gradients."""
        parts = [self.data_loss(grid, torch.arange(i, min(i + chunk, self.cameras.batch_size)))
                 for i in range(0, self.cameras.batch_size, chunk)]
        return tuple(torch.cat([p[k] for p in parts]) for k in range(3))  # type: ignore[return-value]

    @torch.no_grad()
    def carve(self, values: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, tolerance: float) -> torch.Tensor:
        """``values`` (N, N, N) of a grid over ``[lo, hi]`` raised to at least the visual hull of the
        target silhouettes (``sdfcommon.numerics.hull``) less ``tolerance`` (world units), seen from
        the cameras as now believed: a new tensor; what lies outside a view's silhouette cone by more
        than the tolerance is outside the shape."""
        if self._pixel_distance is None:  # the targets are fixed for the level
            self._pixel_distance = signed_pixel_distance(self.masks)
        cams = self.cameras_of(torch.arange(self.cameras.batch_size)).detach()
        points = SDFGrid(values.detach()[None], lo, hi).points().reshape(-1, 3)
        bound = visual_hull(self._pixel_distance, cams, points).reshape(values.shape) - tolerance
        return torch.maximum(values.detach(), bound.to(values.dtype))

    def regulariser(self, grid: SDFGrid) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Weighted eikonal + Laplacian terms, and the two unweighted terms: the shared regularisers
        (``sdfcommon.numerics.regularisers``) at every interior vertex of the grid (``mu=None``), the
        eikonal term also on the box faces (one-sided differences across them,
        ``box_face_eikonal_sum``) and a mean over all the vertices. Without the faces their values
        drift and a shape near them grows pits: the rounded box went from 0.0039 to 0.0344 relative
        Hausdorff with genus 3 when they were dropped (docs/mvr.md). With
        ``settings.regulariser_band`` only the interior vertices within that many voxels of the
        surface count (their sum over every vertex's count, so a vertex weighs the same): the
        re-distancing (``settings.redistance``) keeps the rest a distance."""
        s = self.settings
        h = cube_voxel_size(grid)
        b, nx, ny, nz = grid.values.shape
        if s.regulariser_band is not None:
            # the vertices within the band only, each weighted as in the sum over every vertex
            eik, lap = band_regularisers(grid.values, h, mu=s.regulariser_band)
            inner = grid.values.detach()[:, 1:-1, 1:-1, 1:-1]
            share = float((inner.abs() <= s.regulariser_band * h).sum()) / (b * nx * ny * nz)
            return s.eikonal_weight * eik * share + s.laplacian_weight * lap * share, eik * share, lap * share
        eik, lap = band_regularisers(grid.values, h, mu=None)
        eik = (eik * (b * (nx - 2) * (ny - 2) * (nz - 2)) + box_face_eikonal_sum(grid.values, h)) / (b * nx * ny * nz)
        return s.eikonal_weight * eik + s.laplacian_weight * lap, eik, lap


def cube_voxel_size(grid: SDFGrid) -> float:
    """The grid's sample spacing, the same along the three axes (mvr's grids are cubes)."""
    h = [float(v) for v in grid.voxel_size]
    if max(h) - min(h) > 1e-6 * max(h):
        raise ValueError(f"the regularisers need equal spacing along x, y, z; the grid's is {h}")
    return h[0]


def optimise_level(grid: SDFGrid, losses: ViewLosses, level: int = 0, seed: int = 0, progress: bool = True,
                   description: str = "", max_passes: Optional[int] = None) -> tuple[SDFGrid, LevelReport]:
    """Fits one grid to the target views (one level of the coarse-to-fine schedule).

    Args:
        grid: the starting grid (one grid, B = 1); its values are copied, not changed.
        losses: the views, targets and settings (weights, Adam, stopping rules: ``losses.settings``).
        level: 0-based level index (for per-level settings and the seed); the report numbers it
            ``level + 1``.
        seed: seeds the order of the views.
        progress: show a tqdm bar over the passes.
        max_passes: the level's passes at most (None: ``losses.settings.max_passes`` for the level).
    Returns:
        the fitted grid (detached) and the level's report.
    """
    if grid.batch_size != 1:
        raise ValueError(f"optimise_level fits one grid, got a batch of {grid.batch_size}")
    t_start = time.perf_counter()
    fit = _start_fitting(grid, losses.settings)
    passes = _run_passes(fit, losses, level, seed, progress, description, t_start, max_passes)
    final = SDFGrid(fit.values.detach().clone(), fit.lo, fit.hi)
    with torch.no_grad():
        _, eik, lap = losses.regulariser(final)
    report = LevelReport(
        level=level + 1, resolution=grid.resolution[0], image_size=losses.cameras.image_size[0],
        passes=len(passes.history), updates=passes.updates, seconds=time.perf_counter() - t_start,
        loss_start=passes.loss_start, loss_end=float(passes.view_loss.mean()),
        image_loss=float(passes.image_loss.mean()), silhouette_loss=float(passes.silhouette_loss.mean()),
        eikonal=float(eik), laplacian=float(lap), stop_reason=passes.stop_reason, history=passes.history,
    )
    return final, report


@dataclass(frozen=True)
class _Fitting:
    """What one level fits, updated in place: the grid values (1, N, N, N) that carry gradients,
    the grid's box (lo, hi: (3,) world), Adam over the values and the voxel size (world)."""

    values: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor
    opt: torch.optim.Adam
    voxel: float

    def grid(self) -> SDFGrid:
        """The grid, differentiable in the values."""
        return SDFGrid(self.values, self.lo, self.hi)

    def detached(self) -> SDFGrid:
        """The grid without gradients (for scoring)."""
        return SDFGrid(self.values.detach(), self.lo, self.hi)


@dataclass(frozen=True)
class _Passes:
    """What a level's passes did: the mean view loss before them, each view's (V,) total, image and
    silhouette losses after them, the per-pass history, the updates made and why they stopped."""

    loss_start: float
    view_loss: torch.Tensor
    image_loss: torch.Tensor
    silhouette_loss: torch.Tensor
    history: list
    updates: int
    stop_reason: str


def _start_fitting(grid: SDFGrid, settings: OptimSettings) -> _Fitting:
    """A copy of the grid's values to fit, and Adam over them (its step in voxels of this grid)."""
    voxel = float(grid.voxel_size.min())
    values = grid.values.detach().clone().requires_grad_(True)
    opt = torch.optim.Adam([values], lr=settings.lr * voxel, betas=settings.betas, eps=settings.eps)
    return _Fitting(values=values, lo=grid.bbox_min, hi=grid.bbox_max, opt=opt, voxel=voxel)


def _run_passes(fit: _Fitting, losses: ViewLosses, level: int, seed: int, progress: bool, description: str,
                t_start: float, max_passes: Optional[int] = None) -> _Passes:
    """Passes over the views until a stopping rule of ``losses.settings`` holds (``t_start``: the
    level's ``time.perf_counter()`` at its start, for ``max_seconds``; ``max_passes``: None for the
    settings' own)."""
    settings = losses.settings
    gen = torch.Generator().manual_seed(int(seed) * 1000 + level)
    max_passes = int(settings.for_level("max_passes", level) if max_passes is None else max_passes)
    max_seconds = settings.for_level("max_seconds", level)
    n_views = losses.cameras.batch_size
    history: list[dict] = []
    updates, stalls, stop = 0, 0, "max_passes"
    view_loss, img_v, sil_v = losses.all_views(fit.detached())
    loss_start = float(view_loss.mean())
    bar = tqdm(total=max_passes, desc=description or f"level {level + 1}", disable=not progress, leave=True,
               dynamic_ncols=True)
    try:
        for pass_index in range(max_passes):
            t_pass = time.perf_counter()
            mean = float(view_loss.mean())
            before = fit.values.detach().clone()
            order = torch.randperm(n_views, generator=gen) if settings.shuffle_views else torch.arange(n_views)
            pass_updates, timed_out = _update_views(fit, losses, view_loss, order, t_start, max_seconds)
            updates += pass_updates
            step = _end_pass(fit, losses, before)
            if losses.poses is not None:
                losses.poses.decay(settings.lr_decay)
            view_loss, img_v, sil_v = losses.all_views(fit.detached())
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
            converged = _convergence(settings, pass_index, new_mean, step, stalls)
            if converged is not None:
                stop = converged
                break
    finally:
        bar.close()
    return _Passes(loss_start=loss_start, view_loss=view_loss, image_loss=img_v, silhouette_loss=sil_v,
                   history=history, updates=updates, stop_reason=stop)


def _update_views(fit: _Fitting, losses: ViewLosses, view_loss: torch.Tensor, order: torch.Tensor,
                  t_start: float, max_seconds: Optional[float]) -> tuple[int, bool]:
    """One pass's updates, view by view in ``order`` (V,) long: a view whose loss in ``view_loss``
    (V,) is above the mean is hard (more updates); or, with ``settings.batch_steps``, that many
    steps on all views at once. Returns (updates made, whether the level's ``max_seconds`` ran out,
    which ends the pass early)."""
    if losses.settings.batch_steps > 0:
        return _update_all_views(fit, losses, t_start, max_seconds)
    mean = float(view_loss.mean())
    made = 0
    for v in order.tolist():
        made += _update_view(fit, losses, v, float(view_loss[v]) > mean, mean)
        if max_seconds is not None and time.perf_counter() - t_start > max_seconds:
            return made, True
    return made, False


def _update_all_views(fit: _Fitting, losses: ViewLosses, t_start: float,
                      max_seconds: Optional[float], chunk: int = 8) -> tuple[int, bool]:
    """``settings.batch_steps`` Adam steps, each on the mean data loss of every view (rendered
    ``chunk`` views at a time, their gradients summed) plus the regularisers. Returns (steps made,
    whether ``max_seconds`` ran out)."""
    settings, n_views = losses.settings, losses.cameras.batch_size
    for k in range(settings.batch_steps):
        fit.opt.zero_grad(set_to_none=True)
        for i in range(0, n_views, chunk):
            g = fit.grid()
            data, _, _ = losses.data_loss(g, torch.arange(i, min(i + chunk, n_views)))
            (data.sum() / n_views).backward()
        if settings.eikonal_weight > 0 or settings.laplacian_weight > 0:
            losses.regulariser(fit.grid())[0].backward()
        fit.opt.step()
        if losses.poses is not None:
            losses.poses.step()
        if max_seconds is not None and time.perf_counter() - t_start > max_seconds:
            return k + 1, True
    return settings.batch_steps, False


def _update_view(fit: _Fitting, losses: ViewLosses, view: int, hard: bool, mean: float) -> int:
    """Adam updates on one view (its loss plus the regularisers) until its budget is spent, an
    update raised its loss, or (a hard view) its loss fell below the pass's ``mean``; returns the
    number of updates made."""
    settings = losses.settings
    budget = settings.hard_view_updates if hard else settings.easy_view_updates
    previous = math.inf
    made = 0
    for k in range(budget):
        g = fit.grid()
        data, _, _ = losses.data_loss(g, torch.tensor([view]))
        total = data[0]
        if settings.eikonal_weight > 0 or settings.laplacian_weight > 0:
            total = total + losses.regulariser(g)[0]
        value = float(total.detach())
        if k > 0 and value > previous:
            break  # the last update raised this view's loss: move on
        if hard and k > 0 and float(data[0].detach()) < mean:
            break
        previous = value
        fit.opt.zero_grad(set_to_none=True)
        total.backward()
        fit.opt.step()
        if losses.poses is not None:
            losses.poses.step()
        made += 1
    return made


def _end_pass(fit: _Fitting, losses: ViewLosses, before: torch.Tensor) -> float:
    """After a pass: the learning rate decays, the grid is carved by the visual hull, cavities
    are filled and the grid re-distanced (where the settings say); returns the largest change of a
    value since ``before`` (the values at the pass's start), in voxels, before the re-distancing."""
    settings = losses.settings
    for group in fit.opt.param_groups:
        group["lr"] *= settings.lr_decay
    if settings.carve:
        with torch.no_grad():
            fit.values.copy_(losses.carve(fit.values[0], fit.lo, fit.hi, settings.carve_tolerance * fit.voxel)[None])
    if settings.fill_cavities:
        with torch.no_grad():
            fit.values.copy_(fill_cavities(fit.values[0]).unsqueeze(0))
    step = float((fit.values.detach() - before).abs().max()) / fit.voxel
    if settings.redistance:  # after the step is measured: it changes values, not the surface
        with torch.no_grad():
            fit.values.copy_(redistance(fit.values[0], fit.voxel).unsqueeze(0))
    return step


def _convergence(settings: OptimSettings, pass_index: int, mean: float, step: float, stalls: int) -> Optional[str]:
    """Which convergence rule stops the level after pass ``pass_index`` (mean view loss ``mean``,
    largest step ``step`` voxels, ``stalls`` passes in a row without enough improvement): "loss_tol",
    "step_tol", "plateau", or None (go on; never before ``min_passes``)."""
    if pass_index + 1 < settings.min_passes:
        return None
    if mean <= settings.loss_tol:
        return "loss_tol"
    if step <= settings.step_tol:
        return "step_tol"
    if stalls >= settings.patience:
        return "plateau"
    return None
