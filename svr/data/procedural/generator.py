"""A procedural single-view dataset in the exact NMR ShapeNet layout: the 13 NMR ShapeNet
categories (and two extras) as parametric CSG shapes (``svr.data.procedural.categories``), each in
several styles, random but reproducible from a seed and normalised like ShapeNet (centred on the
bounding box, longest side 1), rendered from the NMR cameras on their analytic SDF
(``render_shape``) and voxelised in the NMR frame (``voxelize_shape``). ``generate_procedural_dataset``
writes a dataset (its docstring lists what each object gets and how a killed generation resumes),
and ``ensure_procedural_dataset`` does it once into a cache folder named by a hash of the
settings and reuses it afterwards.
"""
from __future__ import annotations

import dataclasses
import fcntl
import functools
import hashlib
import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numba
import numpy as np
import torch
from tqdm.auto import tqdm

import renderer
from sdfcommon.tooling.checks import check_int, check_shape
from sdfcommon.tooling.outputs import remove_stale_temporaries, write_json, write_npz
from sdfcommon.tooling.processes import default_workers, map_unordered
from svr.data.procedural.appearance import NEUTRAL_COLOUR, NMR_LIGHTING, Lighting, colour_rng, draw_colours
from svr.data.procedural.categories import (ALL_CATEGORIES, EXTRA_CATEGORIES, NMR_PROCEDURAL_CATEGORIES,
                                            ProceduralCategory, make_shape, procedural_category, style_of)
from svr.data.procedural.csg import CSGShape, surface_normals_and_parts, trace_rays
from svr.data.types import ShadingModel
from svr.nmr.format import IMAGE_SHAPE, NUM_VIEWS, SPLITS, VOXEL_SHAPE, extra_view_files, nmr_file
from svr.nmr.views import view_cameras, view_rows
from svr.nmr.voxels import NMR_VOXEL_RESOLUTION, nmr_voxel_centres, voxelize_sdf_protocol

# Bump when the shapes, renders or file contents change: it is part of the cache key.
GENERATOR_VERSION = 4

IMAGE_SIZE = 64


def object_seed(seed: int, category_id: str, split: str, index: int) -> list[int]:
    """The seed of one object: independent of how many objects and which other categories are made."""
    return [int(seed), int(category_id), SPLITS.index(split), int(index)]


# ---------------------------------------------------------------------------------------------
# Rendering and voxels


@functools.lru_cache(maxsize=4)
def _nmr_rays(image_size: int, num_views: int = NUM_VIEWS) -> tuple[np.ndarray, np.ndarray]:
    """Eyes (V, 3) and unit ray directions (V, H, W, 3), float64, of the NMR cameras."""
    cams = renderer.Cameras.nmr(list(range(num_views)), image_size=image_size, dtype=torch.float64)
    _, d = cams.rays()
    return cams.eye.numpy().copy(), d.numpy().copy()


def _camera_rays(image_size: int, cameras: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eyes (K, 3) and unit ray directions (K, H, W, 3), float64, of K cameras at the NMR distance
    and field of view, given as rows of (azimuth, elevation) in degrees (NMR's convention)."""
    cams = view_cameras(view_rows(cameras), image_size, torch.float64)
    _, d = cams.rays()
    return cams.eye.numpy().copy(), d.numpy().copy()


# Extra training views (``ProceduralSettings.extra_views``): any azimuth, elevations in this range.
EXTRA_ELEVATION_DEG = (10.0, 50.0)


def extra_cameras(seed: list[int], count: int) -> np.ndarray:
    """(count, 2) float32 (azimuth, elevation) in degrees of an object's extra views, drawn from
    its seed (independent of its shape's and colours' draws): azimuth uniform in [0, 360),
    elevation uniform in ``EXTRA_ELEVATION_DEG``."""
    rng = np.random.default_rng([*seed, 0xE7])
    az = rng.uniform(0.0, 360.0, count)
    el = rng.uniform(*EXTRA_ELEVATION_DEG, count)
    return np.stack([az, el], axis=1).astype(np.float32)


@numba.njit(cache=True)
def _interior_pixels(hit, t, normals, depth_k, cos_min):
    """(V, H, W) bool: hit pixels whose 8 neighbours hit at a depth within ``depth_k * t`` and with a
    normal within ``acos(cos_min)`` (a smooth patch seen by the whole pixel)."""
    v, h, w = hit.shape
    out = np.zeros((v, h, w), dtype=np.bool_)
    for a in range(v):
        for r in range(1, h - 1):
            for c in range(1, w - 1):
                if not hit[a, r, c]:
                    continue
                ok = True
                for dr in range(-1, 2):
                    for dc in range(-1, 2):
                        rr, cc = r + dr, c + dc
                        if not hit[a, rr, cc] or abs(t[a, rr, cc] - t[a, r, c]) >= depth_k * t[a, r, c]:
                            ok = False
                        elif (normals[a, rr, cc, 0] * normals[a, r, c, 0] + normals[a, rr, cc, 1] * normals[a, r, c, 1]
                              + normals[a, rr, cc, 2] * normals[a, r, c, 2]) <= cos_min:
                            ok = False
                out[a, r, c] = ok
    return out


def render_shape(shape: CSGShape, colours: Optional[np.ndarray] = None, lighting: Lighting = NMR_LIGHTING,
                 supersample: int = 3, image_size: int = IMAGE_SIZE, num_views: int = NUM_VIEWS,
                 adaptive: bool = True, cameras: Optional[np.ndarray] = None) -> np.ndarray:
    """The NMR views of an analytic shape, anti-aliased.

    Adaptive supersampling: every pixel's centre ray is traced first. A pixel whose centre ray
    certifies (cone tracing with the sphere-tracing balls) that no ray through the pixel meets the
    shape is background; a hit pixel whose 8 neighbours hit the same smooth surface (similar depth
    and normal) takes its centre sample; every other pixel (silhouettes, creases, depth edges)
    averages S x S rays through the centres of an S x S sub-pixel grid, each starting where the
    centre ray's certificate ends.

    Args:
        shape: a normalised CSGShape (world frame, y up).
        colours: (P, 3) albedo in [0, 1] per part of ``shape.parts`` (``svr.data.procedural.appearance
            .draw_colours``); None: every part ``NEUTRAL_COLOUR``.
        lighting: the light (``NMR_LIGHTING``: NMR's recipe); the background is white.
        supersample: S, rays per pixel side.
        adaptive: False supersamples every pixel (the reference the adaptive rule is tested against).
        cameras: instead of the NMR views, (K, 2) rows of (azimuth, elevation) in degrees
            (``svr.nmr.format.extra_view_files``' convention) at the NMR distance and field of view.
    Returns:
        (V, 4, H, W) uint8 RGBA: RGB composited on the background, alpha = coverage.
    """
    s = check_int(supersample, "supersample", minimum=1)
    if colours is None:
        colours = np.tile(NEUTRAL_COLOUR, (len(shape.parts), 1))
    colours = np.asarray(colours, dtype=np.float64)
    check_shape(colours, "colours", f"{len(shape.parts)}, 3")
    if cameras is None:
        eyes, dirs = _nmr_rays(image_size, num_views)
        _, sub_dirs = _nmr_rays(image_size * s, num_views)
    else:
        eyes, dirs = _camera_rays(image_size, cameras)
        _, sub_dirs = _camera_rays(image_size * s, cameras)
    v, h, w = dirs.shape[:3]
    pixel_angle = 2.0 * math.tan(math.radians(15.0)) / image_size
    hit_threshold = 0.25 * pixel_angle / s
    delta = 1.05 * pixel_angle / math.sqrt(2.0)  # half-diagonal of a pixel (+5%)
    lo, hi = shape.bounds
    # The certificate needs a box margin above 2 delta t: the eyes are 2.732 from the centre and the
    # normalised shape lies within 0.87 of it, so t < 4.
    margin = 2.0 * delta * 4.0 + 0.01
    lo, hi = np.asarray(lo) - margin, np.asarray(hi) + margin

    # pass 1: centre rays
    n_pix = v * h * w
    view_of = np.repeat(np.arange(v), h * w)
    d1 = dirs.reshape(-1, 3)
    res = trace_rays(shape, eyes, d1, hit_threshold, (lo, hi), view_of, None, delta)
    hit1, t_hit1, t_cert, clear = res.hit, res.t, res.t_certified, res.clear
    normals1 = np.zeros((n_pix, 3))
    parts1 = np.zeros(n_pix, dtype=np.int64)
    points1 = eyes[view_of[hit1]] + t_hit1[hit1, None] * d1[hit1]
    normals1[hit1], parts1[hit1] = surface_normals_and_parts(shape, points1)

    # interior pixels: hit, and so are the 8 neighbours, on a smooth patch at similar depth
    interior = _interior_pixels(hit1.reshape(v, h, w), t_hit1.reshape(v, h, w), normals1.reshape(v, h, w, 3),
                                3.0 * pixel_angle, 0.97).reshape(-1)
    if not adaptive:
        interior[:] = False
        clear = np.zeros_like(clear)
    refine = ~clear & ~interior

    # pass 2: S x S rays per refined pixel, starting at the centre ray's certified distance
    pix = np.nonzero(refine)[0]
    pv, pr, pc = np.unravel_index(pix, (v, h, w))
    sd = sub_dirs.reshape(v, h, s, w, s, 3)
    d2 = sd[pv, pr, :, pc, :, :].reshape(-1, 3)  # (P * S * S, 3)
    view2 = np.repeat(pv, s * s)
    res = trace_rays(shape, eyes, d2, hit_threshold, (lo, hi), view2, np.repeat(t_cert[pix], s * s))
    hit2, t_hit2 = res.hit, res.t

    # shading of every sample that hit
    use1 = interior & hit1
    p_sub = eyes[view2[hit2]] + t_hit2[hit2, None] * d2[hit2]
    n_sub, part_sub = surface_normals_and_parts(shape, p_sub)
    albedo = colours[np.concatenate([parts1[use1], part_sub])]
    rgb = lighting.shade(np.concatenate([normals1[use1], n_sub]), albedo)
    bg = np.ones(3)

    out = np.zeros((n_pix, 4))
    out[:, :3] = bg
    out[use1, :3] = rgb[: int(use1.sum())]
    out[use1, 3] = 1.0
    samples = np.tile(bg, (len(d2), 1))
    samples[hit2] = rgb[int(use1.sum()):]
    out[pix, :3] = samples.reshape(len(pix), s * s, 3).mean(1)
    out[pix, 3] = hit2.reshape(len(pix), s * s).mean(1)
    img = out.reshape(v, h, w, 4).transpose(0, 3, 1, 2)
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)


def sample_near_surface(shape: CSGShape, axis: np.ndarray, block: int = 4) -> np.ndarray:
    """The SDF on the grid ``axis``^3 (ij order), exact wherever marching cubes reads it.

    The grid is cut into blocks of ``block``^3 points and the SDF sampled at each block's centre
    first. A block whose centre value exceeds, in magnitude, the distance to its farthest point plus
    one grid step lies entirely on one side of the surface at more than a step from it (the SDF is
    1-Lipschitz), so its points take the centre's value: right in sign, and never the end of an edge
    that the surface crosses. Every other block is sampled point by point. The marching-cubes mesh
    is then the one of the full grid, at a fraction of the samples (about a quarter for the
    procedural shapes at 96^3).
    """
    axis = np.asarray(axis, dtype=np.float64)
    n = len(axis)
    if n % block or n < 2 * block:
        return shape.sdf_numpy(np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1))
    step = (axis[-1] - axis[0]) / (n - 1)
    centres = axis[::block] + (block - 1) / 2 * step
    coarse = shape.sdf_numpy(np.stack(np.meshgrid(centres, centres, centres, indexing="ij"), -1))
    reach = math.sqrt(3.0) * (block - 1) / 2 * step + 1.01 * step
    values = coarse.repeat(block, 0).repeat(block, 1).repeat(block, 2)
    near = np.argwhere(np.abs(coarse) <= reach)
    offsets = np.stack(np.meshgrid(*[np.arange(block)] * 3, indexing="ij"), -1).reshape(-1, 3)
    idx = (near[:, None, :] * block + offsets[None]).reshape(-1, 3)
    values[idx[:, 0], idx[:, 1], idx[:, 2]] = shape.sdf_numpy(axis[idx])
    return values


VOXEL_RULES = ("centre", "protocol")


def voxelize_shape(shape: CSGShape, resolution: int = NMR_VOXEL_RESOLUTION, rule: str = "centre",
                   mesh_resolution: int = 96) -> np.ndarray:
    """Solid voxels in the NMR frame.

    Args:
        rule: "centre" (SPEC section 5's definition): occupied iff the analytic SDF is negative at
            the voxel centre ``((j - c)/(R-1), (i - c)/(R-1), (c - k)/(R-1))``. "protocol": the
            benchmark's voxelisation (``svr.nmr.voxels.voxelize_sdf_protocol``) of a marching-cubes
            mesh of the analytic SDF sampled at ``mesh_resolution``^3: surface voxels included, so
            thin parts come out about one voxel thicker, as the protocol makes predictions.
    Returns:
        (R, R, R) bool.
    """
    if rule == "centre":
        pts = nmr_voxel_centres(resolution, dtype=torch.float64).numpy()
        return shape.sdf_numpy(pts) < 0.0
    if rule == "protocol":
        half = 0.5 + 2.0 / (resolution - 1)
        values = sample_near_surface(shape, np.linspace(-half, half, mesh_resolution))
        return voxelize_sdf_protocol(values, -half, half, resolution=resolution)
    raise ValueError(f"rule must be one of {VOXEL_RULES}, got {rule!r}")


# ---------------------------------------------------------------------------------------------
# The dataset on disk


@dataclass(frozen=True)
class ProceduralSettings:
    """What the procedural dataset holds. Every field is part of the cache key.

    Attributes:
        categories: category names or ids (``ALL_CATEGORIES``); empty = the 13 NMR ShapeNet
            categories (``NMR_PROCEDURAL_CATEGORIES``), in the paper's table order.
        train, val, test: objects per category in each split (not all three 0).
        seed: the dataset's seed (objects are reproducible from it).
        supersample: rays per pixel side for anti-aliasing.
        voxel_rule: how the ground-truth voxels are made (``voxelize_shape``): "protocol" (the
            default: the benchmark's own voxelisation of the exact shape's mesh, so the exact shape
            on the model's grid scores about 1 under ``svr.nmr.metrics.iou_protocol``) or "centre"
            (SPEC 5's definition, centre inside; there an exact prediction scores about 0.6).
        extra_views: K extra views of each training object besides the 24 (``extra_cameras``: any
            azimuth, elevation 10 to 50 degrees), in ``svr.nmr.format.extra_view_files``; 0 (the
            default) makes none and leaves the cache key as it was without the field.
    """

    categories: tuple[str, ...] = ()
    train: int = 32
    val: int = 4
    test: int = 6
    seed: int = 0
    supersample: int = 3
    voxel_rule: str = "protocol"
    extra_views: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.categories, str):
            raise ValueError(f"categories must be a list of names or ids, got the string {self.categories!r}")
        cats = tuple(self.categories) if self.categories else tuple(c.name for c in NMR_PROCEDURAL_CATEGORIES)
        names = tuple(procedural_category(str(c)).name for c in cats)
        if len(set(names)) != len(names):
            raise ValueError(f"categories must not repeat, got {list(cats)}")
        object.__setattr__(self, "categories", names)
        for split in SPLITS:
            check_int(getattr(self, split), f"{split} (objects per category)", minimum=0)
        if self.train == self.val == self.test == 0:
            raise ValueError("train, val and test are all 0: the dataset would hold no objects")
        check_int(self.supersample, "supersample", minimum=1)
        check_int(self.seed, "seed")
        if self.voxel_rule not in VOXEL_RULES:
            raise ValueError(f"voxel_rule must be one of {VOXEL_RULES}, got {self.voxel_rule!r}")
        check_int(self.extra_views, "extra_views", minimum=0)

    def sizes(self) -> dict[str, int]:
        return {split: getattr(self, split) for split in SPLITS}

    def num_objects(self) -> int:
        """Objects in the dataset, all categories and splits."""
        return sum(self.sizes().values()) * len(self.categories)

    def array_bytes(self) -> int:
        """Bytes of the dataset's uint8 images and bool voxels as arrays (the .npy files; the
        compressed .npz copies add a few per cent)."""
        extra = self.train * len(self.categories) * self.extra_views * (math.prod(IMAGE_SHAPE[1:]) + 8)
        return self.num_objects() * (math.prod(IMAGE_SHAPE) + math.prod(VOXEL_SHAPE)) + extra

    def category_pairs(self) -> list[tuple[str, str]]:
        """(id, name) per category, in the dataset's order."""
        return [(procedural_category(n).category_id, n) for n in self.categories]

    def key(self) -> str:
        """A short hash of the settings and the generator version (the cache folder's suffix)."""
        blob = json.dumps({**self.to_json(), "version": GENERATOR_VERSION}, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()[:12]

    def to_json(self) -> dict:
        out = {**dataclasses.asdict(self), "categories": list(self.categories)}
        if not self.extra_views:
            del out["extra_views"]  # a dataset without them keeps its key and metadata
        return out


METADATA_FILE = "metadata.json"
# Objects per work item of a generation: the unit that is written, marked done and resumed.
CHUNK_OBJECTS = 8


def read_settings(root: Union[str, os.PathLike]) -> ProceduralSettings:
    """The ProceduralSettings recorded in ``<root>/metadata.json`` (a generated dataset).

    Raises:
        ValueError naming the file when it is missing, unreadable or not a procedural dataset.
    """
    path = Path(root) / METADATA_FILE
    try:
        meta = json.loads(path.read_text())
        s = meta["settings"]
        return ProceduralSettings(tuple(s["categories"]), int(s["train"]), int(s["val"]), int(s["test"]),
                                  int(s["seed"]), int(s["supersample"]), str(s["voxel_rule"]),
                                  int(s.get("extra_views", 0)))
    except FileNotFoundError:
        raise ValueError(f"{path} is missing: {Path(root)} is not a generated procedural dataset") from None
    except (ValueError, KeyError, TypeError) as err:
        raise ValueError(f"{path}: not the metadata of a procedural dataset ({err})") from None


def is_procedural_dataset(root: Union[str, os.PathLike]) -> bool:
    """Whether ``root`` holds a generated procedural dataset (its metadata.json records the settings
    that rebuild every object's analytic shape), as opposed to real NMR ShapeNet."""
    try:
        read_settings(root)
    except ValueError:
        return False
    return True


def dataset_shape(root: Union[str, os.PathLike], category_id: str, split: str, index: int) -> CSGShape:
    """The exact (analytic) shape of object ``index`` of a category and split of a generated
    dataset, rebuilt from its recorded seed (for the oracle baseline, ``svr.evaluation.baselines``)."""
    settings = read_settings(root)
    names = dict(settings.category_pairs())
    if category_id not in names:
        raise ValueError(f"category {category_id!r} is not in the dataset {root} ({list(names)})")
    if split not in SPLITS or not 0 <= int(index) < getattr(settings, split):
        raise ValueError(f"no object {index} in split {split!r} of {root}")
    return make_shape(names[category_id], object_seed(settings.seed, category_id, split, int(index)))


def render_dataset_object(root: Union[str, os.PathLike], category_id: str, split: str, index: int,
                          cameras: np.ndarray) -> np.ndarray:
    """Renders of object ``index`` of a generated dataset from any (K, 2) cameras (azimuth,
    elevation in degrees; ``render_shape``), in the object's own colours, light and anti-aliasing,
    as its stored views were made: (K, 4, 64, 64) uint8."""
    settings = read_settings(root)
    shape = dataset_shape(root, category_id, split, index)
    seed = object_seed(settings.seed, category_id, split, int(index))
    return render_shape(shape, draw_colours(colour_rng(seed), shape.parts), NMR_LIGHTING, settings.supersample,
                        cameras=np.asarray(cameras, dtype=np.float64).reshape(-1, 2))


@dataclass(frozen=True)
class _Chunk:
    """One work item: objects ``start .. stop - 1`` of a category and split."""

    category_id: str
    name: str
    split: str
    start: int
    stop: int

    @property
    def marker(self) -> str:
        return f"{self.category_id}_{self.split}_{self.start:06d}.done"


def _extra_count(settings: ProceduralSettings, split: str) -> int:
    return settings.extra_views if split == "train" else 0


def _make_chunk(chunk: _Chunk, settings: ProceduralSettings) -> tuple[np.ndarray, ...]:
    """Renders and voxelises one chunk: ((n, 24, 4, 64, 64) uint8, (n, 32, 32, 32) bool), then with
    extra views ((n, K, 4, 64, 64) uint8, (n, K, 2) float32 cameras)."""
    n = chunk.stop - chunk.start
    k_extra = _extra_count(settings, chunk.split)
    images = np.zeros((n, *IMAGE_SHAPE), dtype=np.uint8)
    voxels = np.zeros((n, *VOXEL_SHAPE), dtype=bool)
    extra_images = np.zeros((n, k_extra, *IMAGE_SHAPE[1:]), dtype=np.uint8)
    cameras = np.zeros((n, k_extra, 2), dtype=np.float32)
    for k, i in enumerate(range(chunk.start, chunk.stop)):
        seed = object_seed(settings.seed, chunk.category_id, chunk.split, i)
        shape = make_shape(chunk.name, seed)
        colours = draw_colours(colour_rng(seed), shape.parts)
        images[k] = render_shape(shape, colours, NMR_LIGHTING, settings.supersample)
        voxels[k] = voxelize_shape(shape, rule=settings.voxel_rule)
        if k_extra:
            cameras[k] = extra_cameras(seed, k_extra)
            extra_images[k] = render_shape(shape, colours, NMR_LIGHTING, settings.supersample, cameras=cameras[k])
    return (images, voxels, extra_images, cameras) if k_extra else (images, voxels)


def _worker_init() -> None:
    # The processes already share the cores: numba's own threads would only oversubscribe them.
    numba.set_num_threads(1)
    torch.set_num_threads(1)


def _open_arrays(folder: Path, settings: ProceduralSettings) -> dict[tuple[str, str], tuple[np.ndarray, ...]]:
    """The (images, voxels) .npy memory maps of every category and split in a partial folder, then
    the extra views' (images, cameras) where the split has them, created on first use (their final
    names: they become the prepared arrays of ``prepare_nmr``)."""
    arrays = {}
    for cid, _ in settings.category_pairs():
        for split in SPLITS:
            n = getattr(settings, split)
            k_extra = _extra_count(settings, split)
            files = [(nmr_file(folder, cid, split, "images", "npy"), IMAGE_SHAPE, np.uint8),
                     (nmr_file(folder, cid, split, "voxels", "npy"), VOXEL_SHAPE, np.bool_)]
            if k_extra:
                extra_images, extra_cams = extra_view_files(folder, cid, split)
                files += [(extra_images, (k_extra, *IMAGE_SHAPE[1:]), np.uint8), (extra_cams, (k_extra, 2), np.float32)]
            group = []
            for path, item, dtype in files:
                mode = "r+" if path.exists() else "w+"
                group.append(np.lib.format.open_memmap(path, mode=mode, dtype=dtype, shape=(n, *item)))
            arrays[(cid, split)] = tuple(group)
    return arrays


def generate_procedural_dataset(out_dir: Union[str, os.PathLike], settings: ProceduralSettings = ProceduralSettings(),
                                progress: bool = True, workers: int = 0) -> Path:
    """Renders and voxelises every object and writes the NMR layout into ``out_dir``.

    Each object gets 24 RGBA views, uint8 (24, 4, 64, 64), from the NMR cameras
    (``renderer.Cameras.nmr``: elevation 30, distance 2.732, field of view 30), sphere-traced on the
    *analytic* SDF and anti-aliased by supersampling (S x S rays per pixel, S = 3 by default, where
    NMR's own renderer used 2 x 2; ``render_shape`` gives the adaptive rule), its parts in the
    colours of ``svr.data.procedural.appearance.draw_colours`` (drawn from the object's seed) under
    NMR's light (``NMR_LIGHTING``), on a white background: like NMR ShapeNet, no single albedo or
    light is known to training. It also gets solid
    voxels, bool (32, 32, 32), in the NMR voxel frame: by default (``voxel_rule="protocol"``) the
    benchmark's own voxelisation of a fine marching-cubes mesh of the analytic SDF
    (``voxelize_shape``), so that the exact shape scores about 1 under the benchmark protocol; with
    ``voxel_rule="centre"``, ``vox[i, j, k]`` is occupied iff the analytic SDF is negative at the
    world point ``((j - 15.5)/31, (i - 15.5)/31, (15.5 - k)/31)``. The folder holds
    ``{cid}_{split}_images.npz`` and ``{cid}_{split}_voxels.npz`` (key ``arr_0``, as NMR ShapeNet), a
    ``metadata.json`` (categories, settings, lighting), and the memory-mapped ``.npy`` copies
    that ``svr.nmr.format.prepare_nmr`` makes of real NMR data. With ``settings.extra_views`` = K
    each training object also gets K views from ``extra_cameras`` (any azimuth, elevation 10 to 50
    degrees), rendered the same way, in the two ``.npy`` files of ``svr.nmr.format.extra_view_files``.

    The work goes into ``.<name>.partial`` beside ``out_dir`` in chunks of ``CHUNK_OBJECTS``
    objects: each chunk is written into the memory-mapped ``.npy`` arrays, flushed, then marked
    done, so a killed generation continues with the chunks not yet marked when it is started again
    with the same settings (a different generator or settings start afresh). When every chunk is
    done, the compressed NMR files and ``metadata.json`` are added and the folder is renamed to
    ``out_dir`` (which must not exist yet): the dataset appears whole or not at all. A lock file
    beside it keeps two processes from generating the same folder at once (the second waits).

    Args:
        workers: processes rendering chunks in parallel (0: this process alone).
    Returns:
        the folder.
    """
    check_int(workers, "workers", minimum=0)
    out = Path(out_dir)
    if out.exists():
        raise FileExistsError(f"{out} already exists; remove it or use ensure_procedural_dataset")
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.parent / f".{out.name}.partial"
    with open(out.parent / f".{out.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes, also when the process dies
        if out.exists():  # another process finished it while this one waited
            return out
        meta = {
            "format": "nmr-shapenet",
            "source": "procedural",
            "generator_version": GENERATOR_VERSION,
            "categories": [[cid, name] for cid, name in settings.category_pairs()],
            "sizes": settings.sizes(),
            "settings": settings.to_json(),
            "lighting": dataclasses.asdict(NMR_LIGHTING),
        }
        plan = partial / "plan.json"
        done_dir = partial / "done"

        def start_afresh() -> None:
            shutil.rmtree(partial, ignore_errors=True)
            done_dir.mkdir(parents=True)
            write_json(plan, meta)

        if not (plan.exists() and json.loads(plan.read_text()) == meta):
            start_afresh()  # nothing yet, or another generator's or settings' leftovers
        remove_stale_temporaries(partial)
        try:
            arrays = _open_arrays(partial, settings)
        except (ValueError, OSError):  # an array file cut short while it was being created
            start_afresh()
            arrays = _open_arrays(partial, settings)
        chunks = [_Chunk(cid, name, split, a, min(a + CHUNK_OBJECTS, getattr(settings, split)))
                  for cid, name in settings.category_pairs() for split in SPLITS
                  for a in range(0, getattr(settings, split), CHUNK_OBJECTS)]
        todo = [c for c in chunks if not (done_dir / c.marker).exists()]
        total = settings.num_objects()
        bar = tqdm(total=total, initial=total - sum(c.stop - c.start for c in todo), unit="obj",
                   desc=f"procedural dataset -> {out.name}", disable=not progress)

        def store(chunk: _Chunk, result: tuple[np.ndarray, ...]) -> None:
            for array, part in zip(arrays[(chunk.category_id, chunk.split)], result, strict=True):
                array[chunk.start:chunk.stop] = part
                array.flush()
            (done_dir / chunk.marker).touch()
            bar.update(chunk.stop - chunk.start)

        for chunk, result in map_unordered(_make_chunk, todo, workers if len(todo) > 1 else 0, (settings,),
                                           initializer=_worker_init):
            store(chunk, result)
        bar.close()
        arrays.clear()  # closes the memory maps before the folder is renamed
        for cid, _ in settings.category_pairs():
            for split in SPLITS:
                for kind in ("images", "voxels"):
                    npz = nmr_file(partial, cid, split, kind)
                    if not npz.exists():
                        write_npz(npz, arr_0=np.load(nmr_file(partial, cid, split, kind, "npy"), mmap_mode="r"))
        write_json(partial / METADATA_FILE, meta)
        shutil.rmtree(done_dir)
        plan.unlink()
        os.replace(partial, out)
    # A process waiting for the lock finds the dataset when it gets it; a later one never needs it.
    (out.parent / f".{out.name}.lock").unlink(missing_ok=True)
    return out


def procedural_dataset_dir(cache_dir: Union[str, os.PathLike], settings: ProceduralSettings) -> Path:
    """The cache folder of a settings: ``<cache_dir>/procedural-<hash>``."""
    return Path(cache_dir) / f"procedural-{settings.key()}"


def ensure_procedural_dataset(cache_dir: Union[str, os.PathLike], settings: ProceduralSettings = ProceduralSettings(),
                              progress: bool = True, workers: int = 0) -> Path:
    """The dataset's folder under ``cache_dir``, generated on first use (or continued, when an
    earlier generation was killed) and reused afterwards."""
    out = procedural_dataset_dir(cache_dir, settings)
    if (out / METADATA_FILE).exists():
        return out
    try:
        return generate_procedural_dataset(out, settings, progress=progress, workers=workers)
    except FileExistsError:
        if (out / METADATA_FILE).exists():  # another process finished it first
            return out
        raise


def load_shading(root: Union[str, os.PathLike]) -> Optional[ShadingModel]:
    """The shading model recorded in ``<root>/metadata.json``, or None (e.g. NMR ShapeNet)."""
    path = Path(root) / METADATA_FILE
    if not path.exists():
        return None
    try:
        meta = json.loads(path.read_text())
    except ValueError as err:
        raise ValueError(f"{path} is not valid JSON: {err}") from None
    sh = meta.get("shading")
    if sh is None:
        return None
    try:
        return ShadingModel(light_direction=tuple(sh["light_direction"]), light_intensity=float(sh["light_intensity"]),
                            ambient=float(sh["ambient"]), albedo=tuple(sh["albedo"]), background=tuple(sh["background"]))
    except (KeyError, TypeError) as err:
        raise ValueError(f"{path}: malformed 'shading' entry ({err})") from None


__all__ = [
    "GENERATOR_VERSION", "ALL_CATEGORIES", "NMR_PROCEDURAL_CATEGORIES", "EXTRA_CATEGORIES",
    "ProceduralCategory", "ProceduralSettings", "make_shape", "style_of", "object_seed", "procedural_category",
    "render_shape", "extra_cameras", "EXTRA_ELEVATION_DEG",
    "voxelize_shape", "sample_near_surface", "VOXEL_RULES", "generate_procedural_dataset", "ensure_procedural_dataset",
    "procedural_dataset_dir", "load_shading", "read_settings", "is_procedural_dataset", "dataset_shape",
    "render_dataset_object",
    "default_workers",
]
