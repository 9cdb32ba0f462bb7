"""Multi-view reconstruction end to end: target -> views -> coarse-to-fine fit -> mesh -> error.
``reconstruct()`` runs it and owns the output folder's layout (its docstring lists the files),
with every file written atomically (sdfcommon.tooling.outputs) and a checkpoint after each
finished level, so that a rerun resumes after the last.
"""
from __future__ import annotations

import hashlib
import json
import logging
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np
import torch
import trimesh

from renderer import Cameras, Scene, SDFGrid, TraceSettings, render
from sdfcommon.tooling import outputs
from sdfcommon.numerics.meshing import sdf_to_mesh
from sdfcommon.tooling.checks import check_float, check_instance, check_int, check_positive
from sdfcommon.tooling.hardware import check_backend
from sdfcommon.tooling.pictures import labelled_grid
from sdfcommon.tooling.serialization import load_torch

from .metrics import NORMALISATION, surface_distances
from .optimize import (CameraPoses, LevelReport, OptimSettings, ViewLosses, fill_cavities, optimise_level,
                       residual_carve, shrink)
from .schedule import Schedule
from .targets import NORMAL_MODES, Target, TargetImages, make_target

log = logging.getLogger("mvr")

# Seeds go to numpy (which takes [0, 2^32 - 1]) and, combined with a level, to torch's generators.
MAX_SEED = 2**32 - 1
LEVEL_COLUMNS = ("level", "resolution", "image_size", "passes", "updates", "seconds", "loss_start", "loss_end",
                 "image_loss", "silhouette_loss", "eikonal", "laplacian", "stop_reason")


@dataclass(frozen=True)
class RigSettings:
    """The 26-view cube rig (paper section 5): camera distance from the origin and full vertical
    field of view (the authors' code: distance 5 from a [-2, 2]^3 box, 60 degrees)."""

    distance: float = 3.0
    fov_deg: float = 56.0

    def __post_init__(self) -> None:
        check_positive(self.distance, "rig distance")
        if not 0 < self.fov_deg < 180:
            raise ValueError(f"rig fov_deg must be in (0, 180), got {self.fov_deg!r}")

    def cameras(self, image_size: int) -> Cameras:
        """The 26 cameras at the given image size."""
        return Cameras.cube_rig(self.distance, fov_deg=self.fov_deg, image_size=image_size)


@dataclass(frozen=True)
class GridSettings:
    """The SDF grid's box ``[-half_size, half_size]^3`` and the initial sphere's radius (world)."""

    half_size: float = 1.0
    init_radius: float = 0.6

    def __post_init__(self) -> None:
        check_positive(self.half_size, "grid half_size")
        if not 0 < self.init_radius < self.half_size:
            raise ValueError(f"grid init_radius must be in (0, half_size={self.half_size}), got {self.init_radius!r}")


@dataclass(frozen=True)
class TargetSettings:
    """How the target is prepared (see mvr.targets): the normalised extent (longest bbox side,
    world), the shading normals ("smooth"/"face"), the meshing resolution of built-in shapes, and
    how many boundary edges of a mesh file's holes may be closed (0: such a mesh is refused)."""

    extent: float = 1.6
    normals: str = "smooth"
    mesh_resolution: int = 192
    max_hole_edges: int = 0

    def __post_init__(self) -> None:
        check_positive(self.extent, "extent")
        if self.normals not in NORMAL_MODES:
            raise ValueError(f"normals must be one of {', '.join(NORMAL_MODES)}, got {self.normals!r}")
        check_int(self.mesh_resolution, "mesh_resolution", minimum=16)
        check_int(self.max_hole_edges, "max_hole_edges", minimum=0)


@dataclass(frozen=True)
class NoiseSettings:
    """The paper's robustness experiments. ``image_std``: standard deviation of Gaussian noise added
    to every target pixel (and to the target coverage used by the silhouette loss); ``camera_std``:
    standard deviation (world units, per axis) of a Gaussian offset of each camera position that the
    optimiser believes in (the targets are made from the true cameras)."""

    image_std: float = 0.0
    camera_std: float = 0.0

    def __post_init__(self) -> None:
        check_float(self.image_std, "noise image_std", minimum=0)
        check_float(self.camera_std, "noise camera_std", minimum=0)


@dataclass(frozen=True)
class ScoringSettings:
    """How the result is scored and shown (configs/mvr.yaml's ``evaluation``): surface samples per
    mesh for the Hausdorff and Chamfer distances, and the views shown in views.png."""

    samples: int = 50_000
    views: Sequence[int] = (0, 2, 4, 6, 12, 18)

    def __post_init__(self) -> None:
        check_int(self.samples, "eval samples", minimum=1)
        views = tuple(int(v) for v in self.views)
        if not views or min(views) < 0 or max(views) > 25:
            raise ValueError(f"eval views must be a non-empty list of view indices in [0, 25], got {list(self.views)!r}")
        object.__setattr__(self, "views", views)


@dataclass(frozen=True)
class ReconstructionResult:
    """What ``reconstruct`` produced (the files are in ``out_dir``)."""

    out_dir: Path
    grid: SDFGrid
    mesh: object
    metrics: dict
    levels: list = field(default_factory=list)


def default_scene() -> Scene:
    """Grey material lit by a light at each camera plus ambient, black background. The light falls
    off as 1/distance^2 (intensity 7.2: 0.8 at the rig's distance 3), as in the authors' code: the
    falloff makes brightness depend on depth, the cue that carves concavities no silhouette shows
    (a head light without falloff shades a surface moved along the view the same;
    docs/mvr_real_scans.md measures both)."""
    return Scene(effects=("silhouette", "shading"), lights=(), camera_light=7.2, camera_light_falloff=True,
                 ambient=0.2, albedo=(1.0,), background=0.0)


def _fingerprint(settings: dict) -> str:
    return hashlib.sha1(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _checkpoint_path(out_dir: Path, number: int) -> Path:
    """Where level ``number`` (1 for the first, as the log counts) is checkpointed."""
    return out_dir / "checkpoints" / f"level_{number:02d}.pt"


def _level_checkpoints(out_dir: Path) -> list[Path]:
    """The level checkpoints in ``out_dir``, in level order."""
    folder = Path(out_dir) / "checkpoints"
    return sorted(folder.glob("level_*.pt")) if folder.is_dir() else []


def stage_count(schedule: Schedule, optim: OptimSettings) -> int:
    """The levels a run fits in all, as its checkpoints number them: the schedule's, once per round
    of ``optim.camera_rounds``, then one per round of the residual carve (``optim.carve_rounds``)."""
    return len(schedule.grid_resolutions()) * optim.camera_rounds + optim.carve_rounds()


def finished_levels(out_dir: Union[str, Path]) -> int:
    """The number of the last level checkpointed in ``out_dir`` (its ``checkpoints/level_NN.pt``),
    the level a rerun resumes after; 0 where there is none."""
    numbers = [int(p.stem[len("level_"):]) for p in _level_checkpoints(Path(out_dir))
               if p.stem[len("level_"):].isdigit()]
    return max(numbers, default=0)


def _load_resume_point(out_dir: Path, fingerprint: str, n_levels: int) -> Optional[_ResumePoint]:
    """The last finished level's checkpoint in ``out_dir``, or None where there is none.

    Raises:
        ValueError: the checkpoint is unreadable, not mvr's, of other settings or beyond the schedule.
    """
    found = _level_checkpoints(out_dir)
    if not found:
        return None
    try:
        ckpt = load_torch(found[-1], "cpu", what="level checkpoint")
    except ValueError as exc:  # a truncated or foreign file
        raise ValueError(f"{exc}; delete it or use resume=false") from None
    if not isinstance(ckpt, dict) or not {"fingerprint", "level", "values", "bbox_min", "bbox_max",
                                          "reports"} <= set(ckpt):
        raise ValueError(f"{found[-1]}: not a level checkpoint of mvr; delete it or use resume=false")
    if ckpt.get("fingerprint") != fingerprint:
        raise ValueError(
            f"out_dir {str(out_dir)!r} holds checkpoints of a run with other settings ({found[-1].name}); "
            f"use another out_dir, or resume=false to start this one afresh")
    if ckpt.get("poses") is not None:
        CameraPoses.check_state(ckpt["poses"], f"checkpoint {str(found[-1])!r}")
    number = int(ckpt["level"])
    if not 1 <= number <= n_levels:
        raise ValueError(f"checkpoint {str(found[-1])!r} is for level {number}, not one of the schedule's levels "
                         f"1 to {n_levels}; use another out_dir, or resume=false to start this one afresh")
    return _ResumePoint(next_level=number, values=ckpt["values"], bbox_min=ckpt["bbox_min"],
                        bbox_max=ckpt["bbox_max"], reports=[LevelReport(**r) for r in ckpt["reports"]],
                        checkpoint=found[-1], poses=ckpt.get("poses"))


def perturbed_cameras(cameras: Cameras, offsets: torch.Tensor) -> Cameras:
    """The same cameras with their eyes moved by ``offsets`` (V, 3), still looking at the origin."""
    eye = cameras.eye.double() + offsets.double()
    return Cameras.look_at(eye, at=(0.0, 0.0, 0.0), up=cameras.up.double(), fov_deg=cameras.fov_deg.double(),
                           image_size=cameras.image_size, dtype=cameras.dtype)


def _comparison_image(targets: torch.Tensor, renders: torch.Tensor, views: Sequence[int],
                      margin: int = 4) -> np.ndarray:
    """Rows target / render / |difference| of (K, H, W, C) images, one column per view of ``views``
    (K indices, the column labels), cropped to the pixels where either image differs from its corner
    pixel (the background); a labelled (H', W', 3) array (``sdfcommon.tooling.pictures.labelled_grid``)."""
    background = targets[:, :1, :1, :]
    busy = ((targets - background).abs().amax(dim=(0, 3)) > 0) | ((renders - background).abs().amax(dim=(0, 3)) > 0)
    rows, cols = torch.nonzero(busy, as_tuple=True)
    if rows.numel():
        h, w = busy.shape
        r0, r1 = max(int(rows.min()) - margin, 0), min(int(rows.max()) + margin + 1, h)
        c0, c1 = max(int(cols.min()) - margin, 0), min(int(cols.max()) + margin + 1, w)
        targets, renders = targets[:, r0:r1, c0:c1], renders[:, r0:r1, c0:c1]
    tiles = torch.stack([targets, renders, (targets - renders).abs()]).detach().float()
    if tiles.shape[-1] == 1:
        tiles = tiles[..., 0]
    return labelled_grid(tiles.numpy(), ["target", "render", "|difference|"], [f"view {v}" for v in views])


def reconstruct(
    target: Union[str, Path, Target],
    out_dir: Union[str, Path],
    *,
    rig: RigSettings = RigSettings(),
    grid: GridSettings = GridSettings(),
    target_settings: TargetSettings = TargetSettings(),
    schedule: Schedule = Schedule(),
    optim: OptimSettings = OptimSettings(),
    noise: NoiseSettings = NoiseSettings(),
    evaluation: ScoringSettings = ScoringSettings(),
    scene: Optional[Scene] = None,
    trace: TraceSettings = TraceSettings(),
    backend: str = "auto",
    seed: int = 0,
    resume: bool = True,
    progress: bool = True,
) -> ReconstructionResult:
    """Reconstructs a target's SDF from its 26 rendered views and measures the error.

    Args:
        target: a built-in shape name (mvr.shapes.SHAPES), a mesh file path, or a prepared Target.
        out_dir: the output folder, created if needed; it receives ``grid.npz`` (the final SDF
            grid: values (N, N, N) float32, bbox_min, bbox_max), ``mesh.ply`` and ``mesh.obj``
            (its zero level set by marching cubes, world coordinates), ``target.ply`` (the
            normalised target mesh the error is measured against), ``views.png`` (a few views:
            target, our render, |difference|, in rows), ``levels.json`` (per level: resolution,
            image size, passes, updates, losses, seconds, history), ``levels.csv`` (the same
            without the per-pass history), ``metrics.json`` (hausdorff_rel, chamfer_rel,
            seconds, ... and the normalisation used), ``settings.json`` (every setting of the
            run) and ``checkpoints/level_NN.pt`` (the grid after each finished level; levels are
            numbered from 1, as the log, levels.json and levels.csv count them).
        rig, grid, target_settings, schedule, optim, noise, evaluation: the settings (plain objects).
        scene: lights, material and effects (None: ``default_scene()``); it must ask for "shading",
            and for "silhouette" when ``optim.silhouette_weight > 0``.
        trace: the renderer's march settings; backend: the renderer's march backend.
        seed: seeds the noise, the view order and the surface samples; an integer in [0, 2^32 - 1].
        resume: continue after the last level checkpointed in out_dir (with the same settings;
            metrics.json's ``resumed_from_level`` names that level); False starts afresh (old
            checkpoints are replaced).
        progress: tqdm bars per level.
    Returns:
        ReconstructionResult (final grid, mesh, metrics dict, level reports).
    Raises:
        ValueError, TypeError, FileNotFoundError: settings or a target that are refused (before
            anything is written).
    """
    t_run = time.perf_counter()
    scene = default_scene() if scene is None else scene
    check_run_settings(scene=scene, optim=optim, target_settings=target_settings, grid=grid, backend=backend,
                       seed=seed)
    plan = _plan_run(target, out_dir, rig=rig, grid=grid, target_settings=target_settings, schedule=schedule,
                     optim=optim, noise=noise, evaluation=evaluation, scene=scene, trace=trace, backend=backend,
                     seed=seed)
    # Everything that can refuse the run (the resume point, the target) comes before the first
    # file is written or an old checkpoint removed.
    state = _load_resume_point(plan.out, plan.fingerprint, plan.stages) if resume else None
    t0 = time.perf_counter()
    tgt = target if isinstance(target, Target) else make_target(
        plan.spec, target_settings.extent, target_settings.normals, target_settings.mesh_resolution,
        target_settings.max_hole_edges)
    seconds_target = time.perf_counter() - t0
    _prepare_out_dir(plan, resume)
    log.info("target %s: %d faces, bbox diagonal %.4f", tgt.source, len(tgt.mesh.faces), tgt.diagonal)

    fit = _fit_levels(plan, tgt, state, progress)
    return _evaluate_and_write(plan, tgt, fit, state, seconds_target, t_run)


@dataclass(frozen=True)
class _RunPlan:
    """What the steps of one run need: the settings ``reconstruct`` got (how views are made, what
    is fitted, how it is scored), and what follows from them: ``spec`` (the target as named: a
    shape, a file, a Target's source), ``fingerprinted`` (the settings that shape the optimisation,
    written to settings.json; a resumed run must match their ``fingerprint``), the grid resolution
    of each level and the grid's box ``[lo, hi]`` ((3,) float32 world)."""

    out: Path
    spec: str
    rig: RigSettings
    scene: Scene
    trace: TraceSettings
    backend: str
    init_radius: float
    schedule: Schedule
    optim: OptimSettings
    noise: NoiseSettings
    seed: int
    evaluation: ScoringSettings
    fingerprinted: dict
    fingerprint: str
    resolutions: list
    lo: torch.Tensor
    hi: torch.Tensor

    @property
    def stages(self) -> int:
        """The levels fitted in all (``stage_count``)."""
        return stage_count(self.schedule, self.optim)


@dataclass(frozen=True)
class _ResumePoint:
    """The last finished level's checkpoint (``checkpoint``): the next level to fit (its 0-based
    index, which is the number of the level finished), the grid (values (1, N, N, N), its box) and
    the reports of the levels done."""

    next_level: int
    values: torch.Tensor
    bbox_min: torch.Tensor
    bbox_max: torch.Tensor
    reports: list
    checkpoint: Path
    poses: Optional[dict] = None


@dataclass(frozen=True)
class _Fit:
    """What the levels produced: the fitted grid, every level's report (resumed ones first), the
    last level's (true) cameras, the seconds spent rendering target images, and the cameras the
    optimiser believed in at the end (corrected where ``optim.cameras`` refined them)."""

    grid: SDFGrid
    reports: list
    cameras: Cameras
    seconds_images: float
    believed: Optional[Cameras] = None


@dataclass(frozen=True)
class _Seconds:
    """Where a run's time went (seconds; ``run_start``: its ``time.perf_counter()`` at the start)."""

    target: float
    images: float
    levels: float
    evaluation: float
    run_start: float


def check_run_settings(*, scene: Scene, optim: OptimSettings, target_settings: TargetSettings,
                       grid: GridSettings, backend: str, seed: int) -> None:
    """Refuses the settings of a run that no settings object checks itself: those that do not fit
    together, the scene's light intensities (``renderer.Scene`` takes any), the march backend (a
    name the renderer knows that runs here: ``sdfcommon.tooling.hardware.check_backend``) and the
    seed. ``reconstruct`` calls it before any
    work, and the command when it builds its settings (``mvr.settings.MVRSettings``).

    Raises:
        ValueError, TypeError: naming the setting by its key in configs/mvr.yaml.
    """
    check_int(seed, "seed", minimum=0, maximum=MAX_SEED)
    check_instance(scene, "scene", Scene, "a renderer.Scene")
    if scene.camera_light is not None:
        check_float(scene.camera_light, "scene.camera_light", minimum=0)
    check_float(scene.ambient, "scene.ambient", minimum=0)
    for k, light in enumerate(scene.lights):
        check_float(light.intensity, f"scene.lights[{k}].intensity", minimum=0)
    check_backend(backend)
    if not scene.wants("shading"):
        raise ValueError("scene.effects must include 'shading' (the image loss compares shaded images)")
    if optim.silhouette_weight > 0 and not scene.wants("silhouette"):
        raise ValueError("scene.effects must include 'silhouette' when optim.silhouette_weight > 0")
    if target_settings.extent >= 2 * grid.half_size:
        raise ValueError(f"target extent {target_settings.extent} does not fit the grid box of side "
                         f"{2 * grid.half_size}")


def _plan_run(target: Union[str, Path, Target], out_dir: Union[str, Path], *, rig: RigSettings,
              grid: GridSettings, target_settings: TargetSettings, schedule: Schedule, optim: OptimSettings,
              noise: NoiseSettings, evaluation: ScoringSettings, scene: Scene, trace: TraceSettings,
              backend: str, seed: int) -> _RunPlan:
    """The run's plan (``_RunPlan``) from ``reconstruct``'s arguments."""
    spec = target.source if isinstance(target, Target) else str(target)
    # What shapes the optimisation (the fingerprint a resumed run must match); evaluation is not.
    fingerprinted = {
        "target": spec, "rig": asdict(rig), "grid": asdict(grid), "target_settings": asdict(target_settings),
        "schedule": asdict(schedule), "optim": asdict(optim), "noise": asdict(noise),
        "scene": repr(scene), "trace": asdict(trace), "seed": seed,
    }
    return _RunPlan(out=Path(out_dir), spec=spec, rig=rig, scene=scene, trace=trace, backend=backend,
                    init_radius=grid.init_radius, schedule=schedule, optim=optim, noise=noise, seed=seed,
                    evaluation=evaluation, fingerprinted=fingerprinted, fingerprint=_fingerprint(fingerprinted),
                    resolutions=schedule.grid_resolutions(), lo=torch.full((3,), -grid.half_size),
                    hi=torch.full((3,), grid.half_size))


def _prepare_out_dir(plan: _RunPlan, resume: bool) -> None:
    """Makes the output folder, clears what a killed run or (``resume=False``) an earlier one left,
    and writes settings.json."""
    out = plan.out
    out.mkdir(parents=True, exist_ok=True)
    outputs.remove_stale_temporaries(out)  # what a run killed mid-write (kill -9) left
    if not resume:
        for old in (out / "checkpoints").glob("level_*.pt") if (out / "checkpoints").is_dir() else []:
            old.unlink()
    outputs.write_json(out / "settings.json", {**plan.fingerprinted, "evaluation": asdict(plan.evaluation),
                                               "backend": plan.backend, "fingerprint": plan.fingerprint})


def _initial_grid(plan: _RunPlan) -> SDFGrid:
    """The initial sphere at the first level's resolution."""
    radius = plan.init_radius
    return SDFGrid.from_function(lambda p: p.norm(dim=-1) - radius, plan.resolutions[0], plan.lo, plan.hi)


def _starting_grid(plan: _RunPlan, state: Optional[_ResumePoint]) -> tuple[int, SDFGrid, list[LevelReport]]:
    """(first level to fit, its starting grid, the reports so far): the initial sphere at the first
    level's resolution, or the resume point's grid."""
    if state is None:
        return 0, _initial_grid(plan), []
    grid = SDFGrid(state.values, state.bbox_min, state.bbox_max)
    log.info("resuming after level %d of %d (%d^3) from %s", state.next_level, plan.stages,
             grid.resolution[0], state.checkpoint)
    return state.next_level, grid, state.reports


def _fit_levels(plan: _RunPlan, tgt: Target, state: Optional[_ResumePoint], progress: bool) -> _Fit:
    """Fits the grid level by level, coarse to fine, from the start or the resume point; each
    finished level is checkpointed and levels.json/csv rewritten. With ``optim.camera_rounds`` > 1
    the schedule runs that many times (its stages numbered on across the rounds, as the
    checkpoints are); each later round starts again from the sphere with the cameras as refined so
    far."""
    cam_offsets = _camera_offsets(plan)
    start, current, reports = _starting_grid(plan, state)
    poses = CameraPoses(26, plan.optim.camera_lr) if plan.optim.cameras else None
    if poses is not None and state is not None and state.poses is not None:
        poses.load(state.poses)
    seconds_images = 0.0
    cams_true = plan.rig.cameras(16)
    n_levels, rounds = len(plan.resolutions), plan.optim.camera_rounds
    rendered: dict[int, TargetImages] = {}  # each level's target views, rendered once for all rounds
    for stage in range(start, plan.stages):
        refit = stage >= n_levels * rounds  # a residual carve and refit after the schedule (optim.residual_carve)
        round_index, level = (rounds - 1, n_levels - 1) if refit else divmod(stage, n_levels)
        res = plan.resolutions[level]
        if level == 0 and stage > 0:  # a later round: the sphere again (the cameras keep their step)
            current = _initial_grid(plan)
        if current.resolution[0] != res:
            current = current.resample(res)
        if plan.optim.erodes(level, n_levels) and not refit:  # grow the surface back from inside: a bridged concavity opens
            current = SDFGrid(shrink(current.values[0], float(current.voxel_size.min()), plan.optim.erosion,
                                     plan.optim.erosion_keep)[None], current.bbox_min, current.bbox_max)
        size = plan.schedule.image_size_for(cams_true, plan.lo, plan.hi, res)
        cams_true = plan.rig.cameras(size)
        if level not in rendered:
            t0 = time.perf_counter()
            rendered[level] = tgt.render(cams_true, plan.scene)
            seconds_images += time.perf_counter() - t0
        views = rendered[level]
        refine = poses is not None and level >= n_levels - plan.optim.camera_levels
        losses = _level_losses(plan, views, cams_true, cam_offsets, level, poses if refine else None,
                               corrected=poses if round_index > 0 and not refine else None)
        desc = f"level {level + 1}/{n_levels} {res}^3 {size}px"
        if rounds > 1:
            desc = f"round {round_index + 1}/{rounds} {desc}"
        if refit:
            o, k = plan.optim, stage - n_levels * rounds
            desc = f"residual carve {k + 1}/{o.carve_rounds()}, refit {res}^3 {size}px"
            current = residual_carve(current, losses, o.residual_carve, o.residual_carve_views,
                                     o.residual_carve_threshold, o.residual_carve_edge)
            losses.settings = replace(o, lr=o.lr * o.refit_lr_scale, batch_steps=o.refit_batch_steps)
            current, report = optimise_level(current, losses, n_levels + k, plan.seed, progress, desc,
                                             max_passes=o.refit_passes)
        else:
            current, report = optimise_level(current, losses, level, plan.seed, progress, desc,
                                             max_passes=plan.optim.passes(level, n_levels))
        reports.append(report)
        log.info("%s: %d passes, %d updates, loss %.3e -> %.3e, %.1fs (%s)", desc, report.passes, report.updates,
                 report.loss_start, report.loss_end, report.seconds, report.stop_reason)
        _save_level(plan, stage, current, reports, poses)
    believed = _believed_cameras(plan, cams_true, cam_offsets)
    if poses is not None:
        believed = _corrected_cameras(believed, poses)
    return _Fit(grid=current, reports=reports, cameras=cams_true, seconds_images=seconds_images, believed=believed)


def _camera_offsets(plan: _RunPlan) -> torch.Tensor:
    """(26, 3) the seeded offsets of the camera noise (zero without it)."""
    gen = torch.Generator().manual_seed(int(plan.seed))
    return torch.randn(26, 3, generator=gen, dtype=torch.float64) * plan.noise.camera_std


def _believed_cameras(plan: _RunPlan, cams_true: Cameras, cam_offsets: torch.Tensor) -> Cameras:
    """The cameras the optimiser is given: the true ones moved by ``cam_offsets`` (26, 3) where there
    is camera noise."""
    return perturbed_cameras(cams_true, cam_offsets) if plan.noise.camera_std > 0 else cams_true


def _corrected_cameras(cameras: Cameras, poses: CameraPoses) -> Cameras:
    """All V ``cameras`` with ``poses``' corrections as they stand, detached (no gradient to them)."""
    with torch.no_grad():
        return poses.apply(cameras, torch.arange(cameras.batch_size)).detach()


def _level_losses(plan: _RunPlan, views: TargetImages, cams_true: Cameras, cam_offsets: torch.Tensor,
                  level: int, poses: Optional[CameraPoses] = None,
                  corrected: Optional[CameraPoses] = None) -> ViewLosses:
    """One level's losses: the target views with the image noise of ``plan.noise`` (seeded per
    level), seen from the cameras the optimiser believes in (``_believed_cameras``), corrected by
    ``poses`` where the cameras are refined, or by ``corrected``'s corrections held fixed."""
    images, masks = views.images, views.masks.float()
    if plan.noise.image_std > 0:
        g = torch.Generator().manual_seed(int(plan.seed) * 7919 + level)
        images = images + plan.noise.image_std * torch.randn(images.shape, generator=g)
        masks = masks + plan.noise.image_std * torch.randn(masks.shape, generator=g)
    cameras = _believed_cameras(plan, cams_true, cam_offsets)
    if corrected is not None:
        cameras = _corrected_cameras(cameras, corrected)
    return ViewLosses(cameras, images, masks, plan.scene, plan.trace, plan.backend, plan.optim, poses)


def _save_level(plan: _RunPlan, level: int, grid: SDFGrid, reports: list[LevelReport],
                poses: Optional[CameraPoses] = None) -> None:
    """The finished level's checkpoint (the point a rerun resumes from; with the cameras'
    corrections where they are refined) and levels.json/csv (``level``: its 0-based index, counted on
    across the rounds of ``optim.camera_rounds``; the checkpoint is numbered ``level + 1``, as the log
    counts)."""
    outputs.write_torch(_checkpoint_path(plan.out, level + 1), {
        "fingerprint": plan.fingerprint, "level": level + 1, "values": grid.values.detach().clone(),
        "bbox_min": grid.bbox_min, "bbox_max": grid.bbox_max,
        "reports": [asdict(r) for r in reports], "poses": poses.state() if poses is not None else None})
    _write_levels(plan.out, reports)


def _evaluate_and_write(plan: _RunPlan, tgt: Target, fit: _Fit, state: Optional[_ResumePoint],
                        seconds_target: float, t_run: float) -> ReconstructionResult:
    """The run's end: the final grid and meshes, views.png, the surface distances and metrics.json
    (``t_run``: the run's ``time.perf_counter()`` at its start)."""
    t_eval = time.perf_counter()
    final, mesh = _write_final_grid(plan.out, fit, tgt, plan.optim.fill_cavities)
    backend_used = _write_views_picture(plan, tgt, fit.cameras, final)
    metrics = _score_surface(mesh, tgt, plan.evaluation.samples, plan.seed)
    seconds = _Seconds(target=seconds_target, images=fit.seconds_images,
                       levels=float(sum(r.seconds for r in fit.reports)),
                       evaluation=time.perf_counter() - t_eval, run_start=t_run)
    metrics.update(_describe_run(seconds, state, fit.reports, final, mesh, tgt, backend_used))
    metrics.update(_camera_errors(plan, tgt, fit))
    outputs.write_json(plan.out / "metrics.json", metrics)
    log.info("hausdorff_rel %s chamfer_rel %s in %.1fs -> %s", metrics.get("hausdorff_rel"),
             metrics.get("chamfer_rel"), metrics["seconds"], plan.out)
    return ReconstructionResult(out_dir=plan.out, grid=final, mesh=mesh, metrics=metrics, levels=fit.reports)


def _write_final_grid(out: Path, fit: _Fit, tgt: Target, fill: bool) -> tuple[SDFGrid, trimesh.Trimesh]:
    """The final grid (cavities filled when ``fill``) and its mesh, written with the target mesh
    (grid.npz, mesh.ply, mesh.obj, target.ply, levels.json/csv); returns (grid, mesh)."""
    values = fill_cavities(fit.grid.values[0]) if fill else fit.grid.values[0].detach()
    final = SDFGrid(values.unsqueeze(0), fit.grid.bbox_min, fit.grid.bbox_max)
    mesh = sdf_to_mesh(values, final.bbox_min.numpy(), final.bbox_max.numpy())
    outputs.write_npz(out / "grid.npz", values=values.numpy().astype(np.float32),
                      bbox_min=final.bbox_min.numpy(), bbox_max=final.bbox_max.numpy())
    # With its vertex normals whichever way the run went (trimesh writes them only once computed,
    # which shading the target views does: a resumed run that renders no view would lack them).
    outputs.atomic_write(out / "target.ply", lambda f: f.write(tgt.mesh.export(file_type="ply", vertex_normal=True)))
    if len(mesh.faces):
        outputs.write_mesh(out / "mesh.ply", mesh)
        outputs.write_mesh(out / "mesh.obj", mesh)
    _write_levels(out, fit.reports)
    return final, mesh


def _write_views_picture(plan: _RunPlan, tgt: Target, cameras: Cameras, final: SDFGrid) -> str:
    """views.png: target, render and |difference| of ``plan.evaluation.views`` at the image size
    the schedule gives the final grid (from the last level's ``cameras``); returns the march
    backend the render used."""
    size = plan.schedule.image_size_for(cameras, plan.lo, plan.hi, final.resolution[0])
    shown = list(plan.evaluation.views)
    cams_show = plan.rig.cameras(size)[shown]
    with torch.no_grad():
        rendered = render(final, cams_show, plan.scene, plan.trace, plan.backend)
    target_show = tgt.render(cams_show, plan.scene).images
    outputs.write_png(plan.out / "views.png", _comparison_image(target_show, rendered.image, shown))
    return rendered.trace.backend


def _score_surface(mesh: trimesh.Trimesh, tgt: Target, samples: int, seed: int) -> dict:
    """The metrics' first entries: the target, and the surface distances between the mesh and the
    target's (``surface_distances``; None where the reconstruction has no surface)."""
    metrics: dict = {"target": tgt.name, "source": tgt.source}
    if len(mesh.faces):
        dist = surface_distances(mesh, tgt.mesh, samples, seed)
        metrics.update(dist.to_dict())
    else:
        metrics.update({"hausdorff_rel": None, "chamfer_rel": None, "hausdorff": None, "chamfer": None,
                        "normalisation": NORMALISATION, "error": "the reconstruction has no surface"})
    return metrics


def _describe_run(seconds: _Seconds, state: Optional[_ResumePoint], reports: list[LevelReport], final: SDFGrid,
                  mesh: trimesh.Trimesh, tgt: Target, backend_used: str) -> dict:
    """The metrics' other entries: where the time went, the levels, the final grid and mesh."""
    return {
        "seconds": seconds.target + seconds.images + seconds.levels + seconds.evaluation,
        "seconds_target": seconds.target, "seconds_target_images": seconds.images,
        "seconds_optimisation": seconds.levels, "seconds_evaluation": seconds.evaluation,
        "seconds_this_run": time.perf_counter() - seconds.run_start,
        "resumed_from_level": state.next_level if state is not None else None,
        "levels": len(reports), "resolutions": [r.resolution for r in reports],
        "image_sizes": [r.image_size for r in reports], "updates": int(sum(r.updates for r in reports)),
        "final_resolution": final.resolution[0],
        "voxel_size": float(final.voxel_size.max()),
        "voxel_size_rel": float(final.voxel_size.max()) / tgt.diagonal,
        "mesh_faces": int(len(mesh.faces)),
        "mesh_watertight": bool(mesh.is_watertight) if len(mesh.faces) else False,
        "mesh_components": int(len(mesh.split(only_watertight=False))) if len(mesh.faces) else 0,
        "mesh_genus": (2 - int(mesh.euler_number)) / 2 if len(mesh.faces) else None,
        "target_genus": (2 - int(tgt.mesh.euler_number)) / 2,
        "target_holes_closed": tgt.holes_closed,
        "backend": backend_used,
        "threads": torch.get_num_threads(),
    }


def _camera_errors(plan: _RunPlan, tgt: Target, fit: _Fit) -> dict:
    """Where the optimiser's cameras are not the true ones (camera noise) or were refined, as given
    (``_given``) and at the end (``_final``): the mean distance of their eyes from the true eyes
    (world), the mean angle between their viewing directions (degrees), and the mean distance
    between where the target's vertices project in the true and the believed images (pixels, at
    the last level's size): the part of the error the images show."""
    if plan.noise.camera_std == 0 and not plan.optim.cameras:
        return {}
    given = _believed_cameras(plan, fit.cameras, _camera_offsets(plan))
    vertices = torch.as_tensor(np.asarray(tgt.mesh.vertices), dtype=torch.float64)
    vertices = vertices[torch.randperm(len(vertices), generator=torch.Generator().manual_seed(0))[:2000]]
    true = fit.cameras.to(dtype=torch.float64)
    true_pix = true.project(vertices)[0]
    out = {}
    for name, cams in (("given", given), ("final", fit.believed if fit.believed is not None else given)):
        cams = cams.to(dtype=torch.float64)
        cos = (cams.forward * true.forward).sum(-1).clamp(-1.0, 1.0)
        out[f"camera_eye_error_{name}"] = float((cams.eye - true.eye).norm(dim=-1).mean())
        out[f"camera_angle_error_deg_{name}"] = float(torch.rad2deg(torch.acos(cos)).mean())
        out[f"camera_reprojection_px_{name}"] = float((cams.project(vertices)[0] - true_pix).norm(dim=-1).mean())
    return out


def _write_levels(out: Path, reports: list[LevelReport]) -> None:
    rows = [asdict(r) for r in reports]
    outputs.write_json(out / "levels.json", rows)
    outputs.write_csv(out / "levels.csv", rows, LEVEL_COLUMNS)
