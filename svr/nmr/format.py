"""The NMR ShapeNet single-view format (SPEC section 5; docs/data.md): its categories, splits and
views, its files, their validation and the one-time preparation. A root folder holds, per category id
``cid`` and split (train, val, test), ``{cid}_{split}_images.npz`` (key ``arr_0``, uint8
(N, 24, 4, 64, 64): per object 24 views, view k at azimuth -15 k degrees as
``renderer.Cameras.nmr`` places it, channels R, G, B, alpha) and ``{cid}_{split}_voxels.npz``
(key ``arr_0``, bool (N, 32, 32, 32), solid, in the NMR voxel frame of ``svr.nmr.voxels``:
``vox[i, j, k]`` at world ``((j - 15.5)/31, (i - 15.5)/31, (15.5 - k)/31)``), and, for procedural
data, a ``metadata.json`` (category names and the shading model). ``prepare_nmr`` converts the
compressed files once into uncompressed ``{cid}_{split}_images.npy`` / ``_voxels.npy`` beside
them (or in ``prepared_dir``), which ``svr.data.datasets.NMRDataset`` opens with ``mmap_mode="r"`` so that every
worker process reads the same page-cache copy instead of holding its own (the train images are
about 12 GB decompressed); without them it decompresses the npz into memory.
"""
from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np
import torch
from tqdm.auto import tqdm

from renderer import NMR_NUM_VIEWS as NUM_VIEWS
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.outputs import atomic_path

PathLike = Union[str, os.PathLike]

NMR_CATEGORIES: tuple[tuple[str, str], ...] = (
    ("02691156", "airplane"), ("02828884", "bench"), ("02933112", "cabinet"), ("02958343", "car"),
    ("03001627", "chair"), ("03211117", "display"), ("03636649", "lamp"), ("03691459", "speaker"),
    ("04090263", "rifle"), ("04256520", "sofa"), ("04379243", "table"), ("04401088", "phone"),
    ("04530566", "vessel"),
)
NMR_CATEGORY_IDS = frozenset(cid for cid, _ in NMR_CATEGORIES)
SPLITS = ("train", "val", "test")
IMAGE_SHAPE = (NUM_VIEWS, 4, 64, 64)
VOXEL_SHAPE = (32, 32, 32)
KINDS = ("images", "voxels")
_ITEM = {"images": (IMAGE_SHAPE, np.dtype(np.uint8)), "voxels": (VOXEL_SHAPE, np.dtype(np.bool_))}
BACKGROUND_MODES = ("composite", "invert", "keep")


def check_split(split: str) -> str:
    """``split``, or a ValueError naming it unless it is one of ``SPLITS``."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    return split


def nmr_file(root: PathLike, category_id: str, split: str, kind: str, ext: str = "npz") -> Path:
    """``<root>/{cid}_{split}_{kind}.{ext}``; kind is "images" or "voxels", ext "npz" or "npy"."""
    check_split(split)
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    return Path(root) / f"{category_id}_{split}_{kind}.{ext}"


def _npz_member(zf: zipfile.ZipFile, path: Path) -> str:
    names = zf.namelist()
    if "arr_0.npy" in names:
        return "arr_0.npy"
    arrays = [n for n in names if n.endswith(".npy")]
    if len(arrays) == 1:
        return arrays[0]
    raise ValueError(f"{path}: expected one array under the key 'arr_0', found {[n[:-4] for n in arrays]}")


def read_npz_header(path: PathLike) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype of the array in an NMR npz file, reading only its header.

    Raises:
        FileNotFoundError naming the file if it is missing; ValueError naming it if it is not a
        readable npz (truncated or corrupt) or holds no single array.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"missing NMR data file: {path}")
    try:
        with zipfile.ZipFile(path) as zf:
            with zf.open(_npz_member(zf, path)) as f:
                shape, _, dtype = _read_npy_header(f, path)
    except (zipfile.BadZipFile, EOFError, OSError) as err:
        raise ValueError(f"{path} is truncated or corrupt (not a readable npz file: {err})") from None
    return shape, dtype


def _read_npy_header(f, path: Path):
    try:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
    except ValueError as err:
        raise ValueError(f"{path} is truncated or corrupt (bad array header: {err})") from None
    return tuple(shape), fortran, np.dtype(dtype)


def _check_item(path: Path, kind: str, shape: tuple[int, ...], dtype: np.dtype) -> None:
    item, want = _ITEM[kind]
    if len(shape) != 1 + len(item) or tuple(shape[1:]) != item:
        raise ValueError(f"{path} has shape {shape}; expected (N, {', '.join(map(str, item))})")
    if kind == "images" and dtype != want:
        raise ValueError(f"{path} has dtype {dtype}; expected uint8 images")
    if kind == "voxels" and not (dtype == np.bool_ or np.issubdtype(dtype, np.integer)):
        raise ValueError(f"{path} has dtype {dtype}; expected bool (or 0/1 integer) voxels")


def check_npz(path: PathLike, kind: str) -> int:
    """Validates an NMR npz file's header; returns its number of objects N.

    Raises:
        FileNotFoundError / ValueError naming the file (missing, truncated, wrong shape or dtype).
    """
    path = Path(path)
    shape, dtype = read_npz_header(path)
    _check_item(path, kind, shape, dtype)
    return int(shape[0])


def open_prepared(path: PathLike, kind: str, num_objects: Optional[int] = None) -> np.ndarray:
    """Opens a prepared ``.npy`` read-only and memory-mapped, after checking its header and size.

    Returns:
        (N, 24, 4, 64, 64) uint8 or (N, 32, 32, 32) bool memmap.
    Raises:
        FileNotFoundError / ValueError naming the file.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"missing prepared NMR file: {path}")
    with open(path, "rb") as f:
        shape, fortran, dtype = _read_npy_header(f, path)
        offset = f.tell()
    _check_item(path, kind, shape, dtype)
    if kind == "voxels" and dtype != np.bool_:
        raise ValueError(f"{path} has dtype {dtype}; prepared voxels must be bool (re-run prepare_nmr)")
    if fortran:
        raise ValueError(f"{path} is stored in Fortran order; prepared arrays must be C-ordered")
    need = offset + int(np.prod(shape)) * dtype.itemsize
    size = path.stat().st_size
    if size < need:
        raise ValueError(f"{path} is truncated: {size} bytes, its header needs {need}")
    if num_objects is not None and shape[0] != num_objects:
        raise ValueError(f"{path} holds {shape[0]} objects but its npz source holds {num_objects}; "
                         f"re-run prepare_nmr with overwrite=True")
    return np.load(path, mmap_mode="r")


def extra_view_files(root: PathLike, category_id: str, split: str) -> tuple[Path, Path]:
    """The optional extra views of a category and split (not part of NMR ShapeNet: the procedural
    data and the mesh builder write them on request): ``{cid}_{split}_extra_images.npy``, uint8
    (N, K, 4, 64, 64) as the 24 views, and ``{cid}_{split}_extra_cameras.npy``, float32 (N, K, 2):
    each view's azimuth and elevation in degrees (the NMR convention: the eye at
    ``(d cos e sin a, d sin e, -d cos e cos a)``, view k of the 24 at azimuth ``-15 k`` and
    elevation 30), at the NMR distance and field of view."""
    check_split(split)
    return (Path(root) / f"{category_id}_{split}_extra_images.npy",
            Path(root) / f"{category_id}_{split}_extra_cameras.npy")


def open_extra_views(root: PathLike, category_id: str, split: str,
                     num_objects: int) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """The extra views of a category and split (``extra_view_files``), memory-mapped, or None when
    it has none.

    Raises:
        ValueError naming the file: one of the pair missing, or a shape, dtype or object count that
        does not match.
    """
    images_path, cameras_path = extra_view_files(root, category_id, split)
    if not images_path.exists() and not cameras_path.exists():
        return None
    for path in (images_path, cameras_path):
        if not path.is_file():
            raise ValueError(f"{path} is missing while its pair is present: extra views need both files")
    try:
        images = np.load(images_path, mmap_mode="r")
        cameras = np.load(cameras_path, mmap_mode="r")
    except (ValueError, OSError) as err:
        raise ValueError(f"{images_path.parent}: unreadable extra views of {category_id} {split} ({err})") from None
    if images.dtype != np.uint8 or images.ndim != 5 or images.shape[0] != num_objects \
            or tuple(images.shape[2:]) != IMAGE_SHAPE[1:]:
        raise ValueError(f"{images_path} must be uint8 ({num_objects}, K, 4, 64, 64), got {images.dtype} "
                         f"{tuple(images.shape)}")
    if cameras.dtype != np.float32 or tuple(cameras.shape) != (num_objects, images.shape[1], 2):
        raise ValueError(f"{cameras_path} must be float32 ({num_objects}, {images.shape[1]}, 2), got "
                         f"{cameras.dtype} {tuple(cameras.shape)}")
    return images, cameras


def read_npz(path: PathLike, kind: str) -> np.ndarray:
    """The whole array of one NMR npz file, decompressed into memory: uint8 images, or bool voxels.

    Raises:
        ValueError naming the file when it is truncated or corrupt.
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as zf:
            key = _npz_member(zf, path)[:-4]
        with np.load(path) as z:
            arr = z[key]
    except (zipfile.BadZipFile, EOFError, OSError) as err:
        raise ValueError(f"{path} is truncated or corrupt ({err})") from None
    return arr.astype(bool) if kind == "voxels" else arr


def _stream_npz_to_npy(src: Path, dst: Path, kind: str, chunk_objects: int) -> int:
    """Copies the array of an npz member into ``dst`` (.npy) chunk by chunk, never holding it whole;
    written to a temporary file first, then renamed (``sdfcommon.tooling.outputs.atomic_path``)."""
    item, want = _ITEM[kind]
    try:
        with atomic_path(dst) as tmp, zipfile.ZipFile(src) as zf, zf.open(_npz_member(zf, src)) as f:
            shape, fortran, dtype = _read_npy_header(f, src)
            _check_item(src, kind, shape, dtype)
            if fortran:
                raise ValueError(f"{src} holds a Fortran-ordered array; expected C order (as numpy.savez writes)")
            n = int(shape[0])
            out = np.lib.format.open_memmap(tmp, mode="w+", dtype=want, shape=(n, *item))
            per = int(np.prod(item)) * dtype.itemsize
            for start in range(0, n, chunk_objects):
                k = min(chunk_objects, n - start)
                buf = f.read(k * per)
                if len(buf) != k * per:
                    raise ValueError(f"{src} is truncated: its array ends after {start} of {n} objects")
                block = np.frombuffer(buf, dtype=dtype).reshape(k, *item)
                out[start:start + k] = block != 0 if kind == "voxels" else block
            out.flush()
            del out
    except (zipfile.BadZipFile, EOFError) as err:
        raise ValueError(f"{src} is truncated or corrupt ({err})") from None
    return n


def prepare_nmr(root: PathLike, prepared_dir: Optional[PathLike] = None,
                categories: Optional[Sequence[str]] = None, splits: Sequence[str] = SPLITS,
                overwrite: bool = False, chunk_objects: int = 64, progress: bool = True) -> list[Path]:
    """One-time conversion of the compressed NMR files into memory-mappable ``.npy`` files.

    For each category and split, both npz files are validated first (present, readable, right
    shapes and dtypes, the same N), then copied chunk by chunk into ``<prepared_dir>/{cid}_{split}_
    {images,voxels}.npy`` (voxels as bool), each written to a temporary file and renamed, so a
    killed run never leaves a partial ``.npy``. Files that exist with the right shape are kept
    unless ``overwrite``.

    Args:
        root: folder with the npz files. prepared_dir: output folder (default: root).
        categories: category ids (default: the 13 NMR categories, or metadata.json's).
        splits: which splits.
    Returns:
        the prepared paths.
    Raises:
        FileNotFoundError / ValueError naming the offending file.
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"NMR data folder does not exist: {root}")
    out_dir = Path(prepared_dir) if prepared_dir is not None else root
    out_dir.mkdir(parents=True, exist_ok=True)
    cats = [c for c, _ in resolve_categories(root, categories)]
    for split in splits:
        if split not in SPLITS:
            raise ValueError(f"splits must be among {SPLITS}, got {split!r}")
    jobs = []
    for cid in cats:
        for split in splits:
            n_img = check_npz(nmr_file(root, cid, split, "images"), "images")
            n_vox = check_npz(nmr_file(root, cid, split, "voxels"), "voxels")
            if n_img != n_vox:
                raise ValueError(f"{nmr_file(root, cid, split, 'images')} holds {n_img} objects but "
                                 f"{nmr_file(root, cid, split, 'voxels')} holds {n_vox}")
            jobs.append((cid, split, n_img))
    written = []
    for cid, split, n in tqdm(jobs, desc="preparing NMR arrays", disable=not progress):
        for kind in KINDS:
            dst = nmr_file(out_dir, cid, split, kind, "npy")
            if dst.exists() and not overwrite:
                try:
                    open_prepared(dst, kind, n)
                    written.append(dst)
                    continue
                except ValueError:
                    pass  # stale or damaged: rewrite it
            _stream_npz_to_npy(nmr_file(root, cid, split, kind), dst, kind, chunk_objects)
            written.append(dst)
    return written


def read_metadata(root: PathLike) -> dict:
    """``<root>/metadata.json`` as a dict ({} when absent)."""
    path = Path(root) / "metadata.json"
    if not path.exists():
        return {}
    try:
        return json.loads(path.read_text())
    except ValueError as err:
        raise ValueError(f"{path} is not valid JSON: {err}") from None


def is_nmr_shapenet(root: PathLike, category_ids: Sequence[str]) -> bool:
    """Whether a folder is real NMR ShapeNet, whose rows the paper's table holds: only the 13
    benchmark category ids, and no ``metadata.json`` (the procedural generator and the mesh builder
    each write one, with the same ids where the categories match)."""
    return (bool(category_ids) and all(c in NMR_CATEGORY_IDS for c in category_ids)
            and not (Path(root) / "metadata.json").exists())


def resolve_categories(root: PathLike, categories: Optional[Sequence[str]] = None) -> list[tuple[str, str]]:
    """(id, name) pairs for a category selection.

    Args:
        categories: ids or names; None = every category of ``metadata.json`` if the folder has
            one, else the 13 NMR categories.
    """
    meta = read_metadata(root)
    known = [tuple(c) for c in meta.get("categories", [])] or list(NMR_CATEGORIES)
    if categories is None:
        return [(str(c), str(n)) for c, n in known]
    if isinstance(categories, str):
        categories = [categories]
    by_id = {c: n for c, n in known}
    by_name = {n: c for c, n in known}
    out = []
    for key in categories:
        key = str(key)
        if key in by_id:
            out.append((key, by_id[key]))
        elif key in by_name:
            out.append((by_name[key], key))
        elif key.isdigit():
            out.append((key, key))  # an id we have no name for
        else:
            raise ValueError(f"unknown category {key!r}; expected ids or names among {known}")
    if len({c for c, _ in out}) != len(out):
        raise ValueError(f"categories must not repeat, got {list(categories)}")
    return out


def images_to_float(images: np.ndarray, black_background: str = "composite") -> torch.Tensor:
    """uint8 RGBA (..., 4, H, W) -> float32 in [0, 1], with RGB on a white background.

    Images whose fully transparent pixels (alpha 0) are dark on average have a black background.
    ``black_background`` says what is done to them: "composite" treats RGB as composited over black
    and recomposites it over white (``rgb + 1 - alpha``), "invert" takes ``1 - rgb`` (for files whose
    colours were stored inverted), "keep" leaves them. Images without transparent pixels are kept.
    """
    if black_background not in BACKGROUND_MODES:
        raise ValueError(f"black_background must be one of {BACKGROUND_MODES}, got {black_background!r}")
    x = torch.from_numpy(np.ascontiguousarray(images)).float().div_(255.0)
    if black_background == "keep":
        return x
    rgb, alpha = x[..., :3, :, :], x[..., 3:, :, :]
    clear = (alpha == 0).float()
    n_clear = clear.sum(dim=(-3, -2, -1))
    mean_bg = (rgb * clear).sum(dim=(-3, -2, -1)) / (3.0 * n_clear.clamp(min=1))
    dark = ((n_clear > 0) & (mean_bg < 0.5))[..., None, None, None]
    if black_background == "composite":
        fixed = (rgb + (1.0 - alpha)).clamp_(0.0, 1.0)
    else:
        fixed = 1.0 - rgb
    x[..., :3, :, :] = torch.where(dark, fixed, rgb)
    return x


def check_view_ids(views: Optional[Sequence[int]], name: str = "views", allow_empty: bool = True) -> tuple[int, ...]:
    """NMR view indices: distinct ints in [0, NUM_VIEWS) (the dataset's 24 views).

    Raises:
        ValueError naming ``name``.
    """
    if views is None or isinstance(views, (str, bytes)) or not isinstance(views, Sequence):
        raise ValueError(f"{name} must be a list of NMR view indices in [0, {NUM_VIEWS}), got {views!r}")
    out = tuple(check_int(v, f"{name}[{i}]", 0, NUM_VIEWS - 1) for i, v in enumerate(views))
    if not out and not allow_empty:
        raise ValueError(f"{name} must hold at least one NMR view index in [0, {NUM_VIEWS})")
    if len(set(out)) != len(out):
        raise ValueError(f"{name} must not repeat a view, got {list(views)!r}")
    return out


__all__ = [
    "check_view_ids", "extra_view_files", "open_extra_views",
    "NMR_CATEGORIES", "NMR_CATEGORY_IDS", "SPLITS", "check_split", "NUM_VIEWS", "IMAGE_SHAPE", "VOXEL_SHAPE", "nmr_file", "read_npz_header",
    "check_npz", "read_npz", "open_prepared", "prepare_nmr", "read_metadata", "is_nmr_shapenet", "resolve_categories", "images_to_float",
]
