"""Which meshes a folder holds and where each goes: ``find_objects`` reads the three layouts
(ShapeNetCore v1 ``<synset>/<id>/model.obj``, v2 ``<synset>/<id>/models/model_normalized.obj``, flat
``<category>/<name>.{obj,off,ply,stl,glb,gltf}``), names categories by synset id or folder name
(``category_pairs``: the 13 NMR categories by both, a ShapeNet ``taxonomy.json`` beside them when
there is one) and the splits: ``list_splits`` takes them from PTN/NMR-style id lists
``{cid}_{split}ids.txt`` where given, ``ratio_splits`` puts the other objects (the builder: those it
could build) in train, val or test by a seeded shuffle and ``split_counts``, which gives each split
at least one object from 3 objects of a category on; ``assign_splits`` is the two in turn.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from svr.data.build.meshes import MESH_SUFFIXES
from svr.nmr.format import NMR_CATEGORIES, SPLITS

LAYOUTS = ("auto", "shapenet_v1", "shapenet_v2", "flat")
_MODEL_FILE = {"shapenet_v1": Path("model.obj"), "shapenet_v2": Path("models") / "model_normalized.obj"}
# What each layout expects, for the messages.
LAYOUT_PATTERNS = {"shapenet_v1": "<synset>/<id>/model.obj", "shapenet_v2": "<synset>/<id>/models/model_normalized.obj",
                   "flat": f"<category>/<name>.{{{','.join(s[1:] for s in MESH_SUFFIXES)}}}"}
# From this many objects of a category on, ratio splits give train, val and test one object each at least.
MIN_OBJECTS_PER_SPLIT_SET = len(SPLITS)
_SAFE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9.+-]*$")


@dataclass(frozen=True)
class MeshObject:
    """One mesh of the input.

    Attributes:
        category_id: the category's id (a ShapeNet synset id or the flat layout's folder name).
        object_id: the object's id (ShapeNet's model id or the file's stem).
        path: the mesh file. split: "train", "val" or "test", or "" before ``assign_splits``.
    """

    category_id: str
    object_id: str
    path: Path
    split: str = ""


def _known_names(root: Path) -> dict[str, str]:
    """id -> name: the NMR categories and, when the input has one, ShapeNet's taxonomy.json."""
    names = dict(NMR_CATEGORIES)
    taxonomy = root / "taxonomy.json"
    if taxonomy.is_file():
        try:
            for entry in json.loads(taxonomy.read_text()):
                sid, name = str(entry["synsetId"]), str(entry["name"]).split(",")[0].strip()
                names.setdefault(sid, name)
        except (ValueError, KeyError, TypeError) as err:
            raise ValueError(f"{taxonomy} is not a ShapeNet taxonomy ({err})") from None
    return names


def _has_objects(folder: Path, layout: str) -> bool:
    """Whether a category folder holds a mesh of ``layout`` (not "auto")."""
    if layout == "flat":
        return any(p.is_file() and p.suffix.lower() in MESH_SUFFIXES for p in folder.iterdir())
    return any((sub / _MODEL_FILE[layout]).is_file() for sub in folder.iterdir() if sub.is_dir())


def _layout_of(folder: Path) -> Optional[str]:
    """The layout of one category folder (ShapeNet's before flat), or None when it holds no mesh."""
    return next((layout for layout in LAYOUTS[1:] if _has_objects(folder, layout)), None)


def _objects_of(folder: Path, layout: str, cid: str) -> list[MeshObject]:
    if layout == "flat":
        files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
        stems = [p.stem for p in files]
        if len(set(stems)) != len(stems):
            dup = sorted({s for s in stems if stems.count(s) > 1})[0]
            raise ValueError(f"{folder}: two meshes named {dup!r} (object ids are file names without suffix)")
        return [MeshObject(cid, p.stem, p) for p in files]
    rel = _MODEL_FILE[layout]
    return [MeshObject(cid, sub.name, sub / rel) for sub in sorted(p for p in folder.iterdir() if p.is_dir())
            if (sub / rel).exists()]


def find_objects(root: Path, layout: str = "auto",
                 categories: Optional[Sequence[str]] = None) -> tuple[list[tuple[str, str]], list[MeshObject]]:
    """The categories and meshes of an input folder.

    Args:
        root: the folder whose subfolders are categories. layout: one of ``LAYOUTS`` ("auto":
            each category folder's own). categories: ids or names to keep (None: every folder
            that holds meshes).
    Returns:
        ((id, name) per category in the order asked for, else sorted by id; the meshes, by
        category then object id).
    Raises:
        FileNotFoundError when ``root`` is missing; ValueError for an unknown layout or category,
        an unusable folder name or a folder without meshes.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    root = Path(root).expanduser()
    if not root.is_dir():
        raise FileNotFoundError(f"input folder does not exist: {root}")
    names = _known_names(root)
    found: dict[str, tuple[Path, str]] = {}
    for folder in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        if layout == "auto":
            kind = _layout_of(folder)
        else:  # a folder counts when it holds an object of the layout asked for
            kind = layout if _has_objects(folder, layout) else None
        if kind is not None:
            found[folder.name] = (folder, kind)
    if not found and layout != "auto":
        raise ValueError(f"input: no objects found for layout={layout} in {root} (it expects "
                         f"{LAYOUT_PATTERNS[layout]}); layout=auto tells the layouts apart")
    if not found:
        raise ValueError(f"input: no category folder with meshes in {root} (layouts: ShapeNetCore v1 "
                         f"{LAYOUT_PATTERNS['shapenet_v1']}, v2 {LAYOUT_PATTERNS['shapenet_v2']}, flat "
                         f"{LAYOUT_PATTERNS['flat']})")
    by_name = {names.get(k, k): k for k in found}
    if categories is None:
        chosen = sorted(found)
    else:
        chosen = []
        for key in categories:
            key = str(key)
            folder = key if key in found else by_name.get(key)
            if folder is None:
                raise ValueError(f"categories: unknown category {key!r}; {root} holds "
                                 f"{sorted(f'{k} ({names[k]})' if k in names else k for k in found)}")
            chosen.append(folder)
        if len(set(chosen)) != len(chosen):
            raise ValueError(f"categories must not repeat, got {list(categories)}")
    pairs, objects = [], []
    for folder_name in chosen:
        if not _SAFE_NAME.match(folder_name):
            raise ValueError(f"{found[folder_name][0]}: a category folder name must be letters, digits, "
                             f"'.', '+' or '-' (it names the output files)")
        name = names.get(folder_name)
        if name is None:
            # A flat layout's folder named like an NMR category ("chair") takes that category's id.
            ids = {n: c for c, n in NMR_CATEGORIES}
            cid, name = ids.get(folder_name, folder_name), folder_name
        else:
            cid = folder_name
        pairs.append((cid, name))
        objects.extend(_objects_of(found[folder_name][0], found[folder_name][1], cid))
    return pairs, objects


def _read_id_list(path: Path) -> list[str]:
    """Object ids of a PTN/NMR list file: one per line, ``<id>`` or ``<synset>/<id>``."""
    return [line.strip().split("/")[-1] for line in path.read_text().splitlines() if line.strip()]


def check_split_ratios(ratios: Sequence[float]) -> tuple[float, float, float]:
    """``ratios`` (train, val, test) as floats, each > 0, summing to 1.

    Raises:
        ValueError: ``"split_ratios must be three numbers > 0 (train, val, test) that sum to 1, got ..."``.
    """
    values = list(ratios) if isinstance(ratios, (list, tuple)) else None
    if values is None or len(values) != 3 or not all(
            not isinstance(r, bool) and isinstance(r, (int, float)) and math.isfinite(r) and r > 0 for r in values) \
            or abs(sum(values) - 1.0) > 1e-6:
        raise ValueError(f"split_ratios must be three numbers > 0 (train, val, test) that sum to 1, got {ratios!r}")
    return float(values[0]), float(values[1]), float(values[2])


def split_counts(n: int, ratios: Sequence[float] = (0.7, 0.1, 0.2)) -> tuple[int, int, int]:
    """(train, val, test) object counts of a category of ``n`` objects.

    val and test are ``n`` times their ratio rounded (half up); from ``MIN_OBJECTS_PER_SPLIT_SET``
    (3) objects on each is at least 1 and train keeps at least 1 (the larger of val and test gives
    one back); train takes the rest. Below 3: 1 object is train, 2 are train and test.
    """
    _, r_val, r_test = check_split_ratios(ratios)
    if n < MIN_OBJECTS_PER_SPLIT_SET:
        return (n, 0, 0) if n < 2 else (n - 1, 0, 1)
    n_val = max(1, math.floor(n * r_val + 0.5))
    n_test = max(1, math.floor(n * r_test + 0.5))
    while n - n_val - n_test < 1:
        if n_val >= n_test:
            n_val -= 1
        else:
            n_test -= 1
    return n - n_val - n_test, n_val, n_test


def _by_category(objects: Sequence[MeshObject]) -> dict[str, list[MeshObject]]:
    by_cat: dict[str, list[MeshObject]] = {}
    for obj in objects:
        by_cat.setdefault(obj.category_id, []).append(obj)
    return by_cat


def _with_split(obj: MeshObject, split: str) -> MeshObject:
    return MeshObject(obj.category_id, obj.object_id, obj.path, split)


def list_splits(objects: Sequence[MeshObject],
                id_lists: Optional[Path] = None) -> tuple[list[MeshObject], list[MeshObject]]:
    """The splits that id lists give: a category with ``{cid}_{split}ids.txt`` files in ``id_lists``
    takes its objects' splits from them and its objects no list names are left out; the objects of
    other categories (all of them when ``id_lists`` is None) keep split "" (for ``ratio_splits``).

    Returns:
        (objects, in the input's order, with their split or ""; objects left out).
    Raises:
        FileNotFoundError when ``id_lists`` is not a folder.
    """
    if id_lists is not None and not Path(id_lists).is_dir():
        raise FileNotFoundError(f"split_lists folder does not exist: {id_lists}")
    kept, left_out = [], []
    for cid, objs in _by_category(objects).items():
        lists = {s: Path(id_lists) / f"{cid}_{s}ids.txt" for s in SPLITS} if id_lists is not None else {}
        lists = {s: p for s, p in lists.items() if p.is_file()}
        if not lists:
            kept.extend(_with_split(o, "") for o in objs)
            continue
        where: dict[str, str] = {}
        for split, path in lists.items():
            for oid in _read_id_list(path):
                where.setdefault(oid, split)
        for obj in objs:
            if obj.object_id in where:
                kept.append(_with_split(obj, where[obj.object_id]))
            else:
                left_out.append(obj)
    return kept, left_out


def ratio_splits(objects: Sequence[MeshObject], seed: int = 0,
                 ratios: Sequence[float] = (0.7, 0.1, 0.2)) -> list[MeshObject]:
    """Each object of split "" placed by ratios: per category, shuffled with ``seed`` (and the
    category id) and cut by ``split_counts`` (val first, then test, the rest train); objects that
    already have a split keep it.

    Returns:
        the objects sorted by category, split (train, val, test) and object id.
    """
    check_split_ratios(ratios)
    placed = [o for o in objects if o.split]
    for cid, objs in _by_category([o for o in objects if not o.split]).items():
        order = np.random.default_rng([int(seed), *cid.encode()]).permutation(len(objs))
        _, n_val, n_test = split_counts(len(objs), ratios)
        for rank, k in enumerate(order):
            placed.append(_with_split(objs[k], "val" if rank < n_val else "test" if rank < n_val + n_test else "train"))
    placed.sort(key=lambda o: (o.category_id, SPLITS.index(o.split), o.object_id))
    return placed


def assign_splits(objects: Sequence[MeshObject], seed: int = 0, ratios: Sequence[float] = (0.7, 0.1, 0.2),
                  id_lists: Optional[Path] = None) -> tuple[list[MeshObject], list[MeshObject]]:
    """Each object with its split: ``list_splits``, then ``ratio_splits`` for the categories
    without lists.

    Returns:
        (objects with a split, objects left out because no list names them).
    """
    check_split_ratios(ratios)
    kept, left_out = list_splits(objects, id_lists)
    return ratio_splits(kept, seed, ratios), left_out


__all__ = ["LAYOUTS", "LAYOUT_PATTERNS", "MIN_OBJECTS_PER_SPLIT_SET", "MeshObject", "find_objects",
           "check_split_ratios", "split_counts", "list_splits", "ratio_splits", "assign_splits"]
