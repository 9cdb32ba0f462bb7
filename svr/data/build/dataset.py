"""The build of an NMR-format folder from meshes (``build_dataset``): the plan (which meshes; the
splits that id lists give), the per-object work in parallel processes (``build_object``: load,
render, voxelise; a mesh that fails becomes a skipped manifest row with a one-line reason), each
object's result written atomically into ``<out>/.build/objects`` so that a killed build continues
where it stopped, then the splits of the objects built (``ratio_splits``: a mesh that could not be
built takes no split's place) and the packing into the files ``svr.nmr.format`` reads
(``{cid}_{split}_images.npz`` / ``_voxels.npz`` with their memory-mappable ``.npy`` copies,
``metadata.json``) and ``manifest.csv``, one row per mesh. The same input and settings give the
same bytes, however the work was split, interrupted or ordered. ``out`` must be new, empty or a
build of this builder: its files are never mixed into another folder's.
"""
from __future__ import annotations

import collections
import dataclasses
import hashlib
import json
import logging
import re
import shutil
import signal
import zlib
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numba
import numpy as np
import torch
from tqdm.auto import tqdm

from sdfcommon.numerics.raycast import EmbreeCaster
from sdfcommon.tooling.outputs import (atomic_path, atomic_write, remove_stale_temporaries, write_csv, write_json,
                                       write_npz)
from sdfcommon.tooling.processes import default_workers, map_unordered
from svr.data.build.layouts import MIN_OBJECTS_PER_SPLIT_SET, MeshObject, find_objects, list_splits, ratio_splits
from svr.data.build.meshes import LoadedMesh, MeshError, MeshStatistics, analyse_mesh, load_mesh
from svr.data.build.rendering import render_mesh
from svr.data.build.settings import BuildSettings
from svr.data.build.voxels import VoxelResult, face_normals, solid_voxels
from svr.data.procedural.appearance import NMR_LIGHTING
from svr.data.procedural.generator import extra_cameras
from svr.nmr.format import SPLITS
from svr.nmr.voxels import voxels_to_sdf

# Bump when the renders, voxels, splits or file contents change: part of the plan a resumed build
# matches. 2: splits cut after the build, from the objects built, each split one from 3 on.
BUILDER_VERSION = 2
WORK_DIR = ".build"
MANIFEST_FILE = "manifest.csv"
METADATA_FILE = "metadata.json"
# From this many objects on, the files of the categories and splits are packed in parallel.
PARALLEL_PACK_OBJECTS = 1000
MANIFEST_COLUMNS = ("category_id", "object_id", "split", "index", "source", "triangles", "watertight", "components",
                    "inconsistent_edges", "leak_score", "status", "reason")
# What a folder this builder writes holds (besides hydra's .hydra/, the command's log and the
# temporaries of atomic writes a kill left): anything else in ``out`` is another folder's, and the
# build refuses to mix its files into it.
_BUILD_FILE = re.compile(r"^(metadata\.json|manifest\.csv|\.build|\.hydra|[^/]+\.log|\..+\.tmp|"
                         r"[A-Za-z0-9][A-Za-z0-9.+-]*_(train|val|test)_(images|voxels|sdf|extra_images|extra_cameras)"
                         r"\.np[yz])$")

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ObjectResult:
    """One object's arrays (None when it was skipped) and its manifest row (without ``index``).

    Attributes:
        images: (V, 4, H, W) uint8. voxels: (R, R, R) bool, NMR frame. sdf: (N, N, N) float32 in
            renderer.SDFGrid's layout over [-0.5, 0.5]^3, or None. extra_images (K, 4, H, W) uint8
            and extra_cameras (K, 2) float32: the extra views (``extra_views``), or None.
    """

    row: dict
    images: Optional[np.ndarray] = None
    voxels: Optional[np.ndarray] = None
    sdf: Optional[np.ndarray] = None
    extra_images: Optional[np.ndarray] = None
    extra_cameras: Optional[np.ndarray] = None


@dataclass(frozen=True)
class BuildReport:
    """What a build made: the folder, the objects built, skipped (reason -> count) and left out
    (not named by the split lists), whether it was already there, the categories ((id, name)
    pairs), the objects per category and split ({cid: {split: n}}) and warnings (one line each:
    a category with an empty split)."""

    out: Path
    built: int
    skipped: dict
    left_out: int
    already_built: bool = False
    categories: tuple = ()
    sizes: dict = dataclasses.field(default_factory=dict)
    warnings: tuple = ()


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split())
    return text[:300] if isinstance(err, MeshError) else f"{type(err).__name__}: {text[:300]}"


def build_mesh(mesh: LoadedMesh, settings: BuildSettings) -> tuple[MeshStatistics, np.ndarray, VoxelResult,
                                                                     Optional[np.ndarray]]:
    """Renders and voxelises one normalised mesh.

    Returns:
        (its statistics, (V, 4, H, W) uint8 images, its voxels, the (N, N, N) float32 SDF grid in
        renderer.SDFGrid's layout over [-0.5, 0.5]^3 or None).
    Raises:
        MeshError when no camera sees the mesh.
    """
    stats, images, vox, sdf, _ = _build_mesh(mesh, settings)
    return stats, images, vox, sdf


def object_extra_cameras(obj: MeshObject, settings: BuildSettings) -> np.ndarray:
    """(K, 2) float32 (azimuth, elevation) of an object's extra views, drawn from the build's seed and
    the object's category and id (``svr.data.procedural.generator.extra_cameras``' distribution)."""
    key = zlib.crc32(f"{obj.category_id}/{obj.object_id}".encode())
    return extra_cameras([settings.seed, key], settings.extra_views)


def _build_mesh(mesh: LoadedMesh, settings: BuildSettings, cameras: Optional[np.ndarray] = None
                ) -> tuple[MeshStatistics, np.ndarray, VoxelResult, Optional[np.ndarray], Optional[np.ndarray]]:
    """``build_mesh``, and the renders from ``cameras`` ((K, 2) azimuth, elevation; None: none)."""
    stats, oriented = analyse_mesh(mesh.vertices, mesh.faces)
    caster = EmbreeCaster(mesh.vertices, mesh.faces)
    normals = face_normals(mesh.vertices, mesh.faces)
    images = render_mesh(mesh, caster, normals, settings.image_size, settings.supersample, settings.views,
                         settings.distance, settings.elevation, NMR_LIGHTING)
    if not images[:, 3].any():
        raise MeshError("the mesh is invisible from every camera")
    extra = None
    if cameras is not None and len(cameras):
        extra = render_mesh(mesh, caster, normals, settings.image_size, settings.supersample, len(cameras),
                            settings.distance, settings.elevation, NMR_LIGHTING, cameras=cameras)
    faces = oriented if settings.orient else mesh.faces
    # The votes need the faces' orientation; the BVH does not (the same triangles either way).
    vote_normals = face_normals(mesh.vertices, faces) if settings.orient else normals
    vox = solid_voxels(caster, mesh.vertices, faces, vote_normals, settings.voxel_resolution, settings.ray_directions)
    sdf = None
    if settings.sdf_resolution:
        fine = solid_voxels(caster, mesh.vertices, faces, vote_normals, settings.sdf_resolution,
                            settings.ray_directions)
        sdf = voxels_to_sdf(fine.voxels, pad=0)[0].astype(np.float32)
    return stats, images, vox, sdf, extra


def build_object(obj: MeshObject, settings: BuildSettings, source: str) -> ObjectResult:
    """Loads, renders and voxelises one mesh file; any failure gives a skipped row instead of an
    exception.

    Args:
        obj: the mesh. settings: the build's settings. source: its path as the manifest shows it.
    """
    row = {"category_id": obj.category_id, "object_id": obj.object_id, "split": obj.split, "source": source}
    cameras = object_extra_cameras(obj, settings) if settings.extra_views else None
    try:
        stats, images, vox, sdf, extra = _build_mesh(load_mesh(obj.path), settings, cameras)
    except Exception as err:  # noqa: BLE001 - any failure of one mesh is that mesh's skipped row
        row.update(status="skipped", reason=_one_line(err))
        return ObjectResult(row)
    row.update(triangles=stats.triangles, watertight=stats.watertight, components=stats.components,
               inconsistent_edges=round(stats.inconsistent_edges, 6), leak_score=round(vox.leak_score, 6),
               status="ok", reason="")
    return ObjectResult(row, images, vox.voxels, sdf, extra, cameras)


def _object_files(work: Path, obj: MeshObject) -> tuple[Path, Path]:
    """(arrays .npz, manifest row .json) of an object's result in the work folder."""
    folder = work / "objects" / obj.category_id
    return folder / f"{obj.object_id}.npz", folder / f"{obj.object_id}.json"


def _build_and_store(job: tuple[MeshObject, str], settings: BuildSettings, work: Path) -> dict:
    """A worker's job (a mesh and its manifest path): ``build_object``, then its arrays and row
    written atomically (the row last: it marks the object done). Returns the row."""
    obj, source = job
    result = build_object(obj, settings, source)
    arrays_file, row_file = _object_files(work, obj)
    if result.images is not None:
        arrays = {"images": result.images, "voxels": result.voxels}
        if result.sdf is not None:
            arrays["sdf"] = result.sdf
        if result.extra_images is not None:
            arrays["extra_images"], arrays["extra_cameras"] = result.extra_images, result.extra_cameras
        atomic_write(arrays_file, lambda f: np.savez(f, **arrays))
    write_json(row_file, result.row)
    return result.row


def _worker_init() -> None:
    # The processes already share the cores: numba's and torch's own threads would oversubscribe them.
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    # Ctrl+C reaches the terminal's whole process group: the parent alone stops the build (its
    # one line), and ends the workers.
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _plan(settings: BuildSettings, input_dir: Path, objects: list[MeshObject], left_out: list[MeshObject],
          pairs: list[tuple[str, str]]) -> dict:
    record = {**settings.data_record(), "input": str(input_dir)}
    return {"builder_version": BUILDER_VERSION, "settings": record, "categories": [list(p) for p in pairs],
            "objects": [[o.category_id, o.object_id, str(o.path.relative_to(input_dir)), o.split] for o in objects],
            "left_out": [[o.category_id, o.object_id] for o in left_out]}


def _plan_key(plan: dict) -> str:
    return hashlib.sha256(json.dumps(plan, sort_keys=True).encode()).hexdigest()[:16]


def _check_out(out: Path, key: str, overwrite: bool) -> bool:
    """Whether ``out`` already holds this build (True), after refusing a folder that holds files
    of something else and another build (unless ``overwrite``)."""
    foreign = sorted(p.name for p in out.iterdir() if not _BUILD_FILE.match(p.name))
    meta_file = out / METADATA_FILE
    meta = {}
    if meta_file.is_file():
        try:
            meta = json.loads(meta_file.read_text())
        except ValueError:
            meta = {}
        if not (isinstance(meta, dict) and meta.get("source") == "meshes" and "plan" in meta):
            foreign.insert(0, METADATA_FILE)
    if foreign:
        listed = ", ".join(foreign[:3]) + (", ..." if len(foreign) > 3 else "")
        raise ValueError(f"out: {out} is not empty and is no build of this command (it holds {listed}); choose a "
                         f"new or empty folder")
    if meta_file.is_file():
        if meta.get("plan") == key:
            return True
        if not overwrite:
            raise ValueError(f"out: {out} holds another build (other meshes or settings); choose another "
                             f"folder or set overwrite=true to replace it")
        meta_file.unlink()
        for kind in ("images", "voxels", "sdf", "extra_images", "extra_cameras"):  # the old build's, any categories
            for old in out.glob(f"*_*_{kind}.np[yz]"):
                old.unlink()
    elif any(out.glob("*_*_*.np[yz]")) and not (out / WORK_DIR).is_dir():
        raise ValueError(f"out: {out} holds NMR files this builder did not make (no {METADATA_FILE}); choose a new "
                         f"or empty folder")
    return False


@dataclass(frozen=True)
class _PackJob:
    """The files of one category and split: its objects built (in order) and where they go."""

    category_id: str
    split: str
    objects: tuple[MeshObject, ...]
    out: Path
    work: Path


def _pack_files(job: _PackJob, kinds: tuple, extra_kinds: tuple = ()) -> None:
    """Writes ``{cid}_{split}_{kind}.npy`` (memory-mappable) then ``.npz`` for each kind, and for the
    train split the extra views' ``.npy`` files of ``extra_kinds`` (``svr.nmr.format.extra_view_files``)."""
    for kind, item, dtype in kinds + (extra_kinds if job.split == "train" else ()):
        npy = job.out / f"{job.category_id}_{job.split}_{kind}.npy"
        with atomic_path(npy) as tmp:
            arr = np.lib.format.open_memmap(tmp, mode="w+", dtype=dtype, shape=(len(job.objects), *item))
            for i, obj in enumerate(job.objects):
                with np.load(_object_files(job.work, obj)[0]) as z:
                    arr[i] = z[kind]
            arr.flush()
            del arr
        if not kind.startswith("extra_"):
            write_npz(job.out / f"{job.category_id}_{job.split}_{kind}.npz", arr_0=np.load(npy, mmap_mode="r"))


def _pack(out: Path, work: Path, settings: BuildSettings, pairs: list[tuple[str, str]], placed: list[MeshObject],
          unplaced: list[MeshObject], left_out: list[MeshObject], rows: dict, plan: dict, key: str,
          workers: int) -> dict:
    """Writes the NMR files (each category and split by one of ``workers`` processes: compressing
    them is most of the work), the manifest and metadata.json (last) from the per-object results.

    Args:
        placed: the objects built, with their splits. unplaced: the objects skipped (their rows
            keep the split a list gave them, else none). left_out: those no split list names.
    """
    v, s, r = settings.views, settings.image_size, settings.voxel_resolution
    kinds = [("images", (v, 4, s, s), np.uint8), ("voxels", (r, r, r), np.bool_)]
    if settings.sdf_resolution:
        n = settings.sdf_resolution
        kinds.append(("sdf", (n, n, n), np.float32))
    k = settings.extra_views
    extra_kinds = (("extra_images", (k, 4, s, s), np.uint8), ("extra_cameras", (k, 2), np.float32)) if k else ()
    manifest, sizes, jobs = [], {}, []
    for cid, _ in pairs:
        sizes[cid] = {}
        for split in SPLITS:
            members = [o for o in placed if o.category_id == cid and o.split == split]
            sizes[cid][split] = len(members)
            jobs.append(_PackJob(cid, split, tuple(members), out, work))
            manifest.extend({**rows[(cid, o.object_id)], "split": split, "index": i} for i, o in enumerate(members))
        manifest.extend({**rows[(cid, o.object_id)], "index": ""} for o in unplaced if o.category_id == cid)
        for o in left_out:
            if o.category_id == cid:
                manifest.append({"category_id": cid, "object_id": o.object_id, "split": "",
                                 "source": str(o.path.relative_to(Path(plan["settings"]["input"]))),
                                 "status": "left_out", "reason": "no split list names it"})
    jobs.sort(key=lambda j: -len(j.objects))  # the largest first: the last to finish is a small one
    if sum(len(j.objects) for j in jobs) < PARALLEL_PACK_OBJECTS:
        workers = 0  # starting processes would cost more than it saves
    for _ in map_unordered(_pack_files, jobs, min(workers, len(jobs)), (tuple(kinds), extra_kinds),
                           initializer=_worker_init):
        pass
    write_csv(out / MANIFEST_FILE, manifest, MANIFEST_COLUMNS)
    meta = {
        "format": "nmr-shapenet",
        "source": "meshes",
        "builder_version": BUILDER_VERSION,
        "plan": key,
        "categories": [list(p) for p in pairs],
        "sizes": sizes,
        "image_shape": [v, 4, s, s],
        "voxel_shape": [r, r, r],
        "objects": {"built": len(placed), "skipped": len(unplaced), "left_out": len(left_out)},
        "warnings": empty_split_warnings(pairs, sizes, manifest),
        "settings": plan["settings"],
        "lighting": dataclasses.asdict(NMR_LIGHTING),
    }
    write_json(out / METADATA_FILE, meta)
    return meta


def empty_split_warnings(pairs: list[tuple[str, str]], sizes: dict, manifest: list[dict]) -> list[str]:
    """One line per category with an empty split (training on it does not validate on that
    category, evaluation does not score it).

    Args:
        pairs: (id, name) per category. sizes: {cid: {split: objects}}. manifest: the rows.
    """
    warnings = []
    for cid, name in pairs:
        empty = [split for split in SPLITS if not sizes[cid][split]]
        if not empty:
            continue
        rows = [m for m in manifest if m["category_id"] == cid]
        built = sum(sizes[cid].values())
        skipped = sum(1 for m in rows if m["status"] == "skipped")
        warnings.append(f"category {cid} ({name}) has no {'/'.join(empty)} objects ({built} built, {skipped} "
                        f"skipped): with split_ratios a category needs {MIN_OBJECTS_PER_SPLIT_SET} meshes that build "
                        f"for one in each split")
    return warnings


def build_progress(out: Path) -> tuple[int, int]:
    """(objects done, objects planned) of an unfinished build in ``out`` (its ``out/.build``);
    (0, 0) before it has a plan."""
    work = Path(out) / WORK_DIR
    try:
        planned = len(json.loads((work / "plan.json").read_text())["objects"])
    except (OSError, ValueError, KeyError, TypeError):
        return 0, 0
    return sum(1 for _ in (work / "objects").rglob("*.json")), planned


def build_dataset(settings: BuildSettings) -> BuildReport:
    """Builds ``settings.out`` from the meshes of ``settings.input`` (see the module docstring).

    A build whose ``out`` already holds the same build does nothing; one killed before it finished
    continues with the objects not yet done (their results are in ``<out>/.build``); one made with
    other settings or meshes is refused unless ``overwrite``; an ``out`` that holds anything else
    is refused.

    Returns:
        BuildReport.
    Raises:
        FileNotFoundError / ValueError naming the setting or file (missing input, unknown category,
        no objects of the layout, an out folder that holds something else).
    """
    input_dir = Path(settings.input).expanduser().resolve()
    out = Path(settings.out).expanduser()
    if out.resolve() == input_dir or input_dir in out.resolve().parents:
        raise ValueError(f"out must be a folder outside input (a later build would read it as a category), "
                         f"got out={settings.out} inside input={settings.input}")
    pairs, found = find_objects(input_dir, settings.layout, settings.categories)
    split_lists = Path(settings.split_lists).expanduser() if settings.split_lists else None
    objects, left_out = list_splits(found, split_lists)
    plan = _plan(settings, input_dir, objects, left_out, pairs)
    key = _plan_key(plan)
    out.mkdir(parents=True, exist_ok=True)
    if _check_out(out, key, settings.overwrite):
        meta = json.loads((out / METADATA_FILE).read_text())
        return BuildReport(out, meta["objects"]["built"], {}, meta["objects"]["left_out"], already_built=True,
                           categories=tuple(pairs), sizes=meta["sizes"], warnings=tuple(meta.get("warnings", ())))
    work = out / WORK_DIR
    plan_file = work / "plan.json"
    if not (plan_file.is_file() and json.loads(plan_file.read_text()) == plan):
        shutil.rmtree(work, ignore_errors=True)  # another build's leftovers
        write_json(plan_file, plan)
    remove_stale_temporaries(out)  # a killed build's, in out (the packing) and .build
    sources = {(o.category_id, o.object_id): str(o.path.relative_to(input_dir)) for o in objects}
    rows = {}
    todo = []
    for obj in objects:
        arrays_file, row_file = _object_files(work, obj)
        if row_file.is_file():
            row = json.loads(row_file.read_text())
            if row["status"] != "ok" or arrays_file.is_file():
                rows[(obj.category_id, obj.object_id)] = row
                continue
        todo.append((obj, sources[(obj.category_id, obj.object_id)]))
    workers = default_workers() if settings.workers is None else settings.workers
    workers = min(workers, len(todo))
    log.info("building %s from %s: %d meshes in %d categories, %d of them done before, %d left out; %d worker "
             "processes", out, input_dir, len(objects), len(pairs), len(objects) - len(todo), len(left_out), workers)
    bar = tqdm(total=len(objects), initial=len(objects) - len(todo), unit="obj", desc=f"building {out.name}",
               disable=not settings.progress, smoothing=0.1)
    skipped = collections.Counter(r["reason"] for r in rows.values() if r["status"] != "ok")
    died = ("the worker process died while building it (a crash in a mesh library, or out of memory); "
            "removing its manifest row file in .build/objects retries it")

    def record(obj: MeshObject, row: dict) -> None:
        rows[(obj.category_id, obj.object_id)] = row
        if row["status"] != "ok":
            skipped[row["reason"]] += 1
            log.info("skipped %s: %s", row["source"], row["reason"])
            bar.set_postfix(skipped=sum(skipped.values()), refresh=False)
        bar.update(1)

    try:
        while todo:
            try:
                for (obj, _), row in map_unordered(_build_and_store, todo, workers, (settings, work),
                                                   initializer=_worker_init):
                    record(obj, row)
                todo = []
            except BrokenProcessPool:
                # A worker died: the objects it may have held (those in flight) are built again one
                # by one, each in a process of its own; one that kills that too is a skipped row.
                todo = [job for job in todo if (job[0].category_id, job[0].object_id) not in rows]
                suspects, todo = todo[:2 * workers], todo[2 * workers:]
                for job in suspects:
                    try:
                        (_, row), = map_unordered(_build_and_store, [job], 1, (settings, work), initializer=_worker_init)
                    except BrokenProcessPool:
                        row = {"category_id": job[0].category_id, "object_id": job[0].object_id,
                               "split": job[0].split, "source": job[1], "status": "skipped", "reason": died}
                        write_json(_object_files(work, job[0])[1], row)
                    record(job[0], row)
    finally:
        bar.close()
    built = [o for o in objects if rows[(o.category_id, o.object_id)]["status"] == "ok"]
    placed = ratio_splits(built, settings.seed, settings.split_ratios)
    unplaced = [o for o in objects if rows[(o.category_id, o.object_id)]["status"] != "ok"]
    meta = _pack(out, work, settings, pairs, placed, unplaced, left_out, rows, plan, key,
                 default_workers() if settings.workers is None else settings.workers)
    if not settings.keep_work:
        shutil.rmtree(work, ignore_errors=True)
    return BuildReport(out, len(placed), dict(skipped), len(left_out), categories=tuple(pairs), sizes=meta["sizes"],
                       warnings=tuple(meta["warnings"]))


__all__ = ["BUILDER_VERSION", "MANIFEST_COLUMNS", "ObjectResult", "BuildReport", "build_mesh", "build_object",
           "build_dataset", "empty_split_warnings", "build_progress"]
