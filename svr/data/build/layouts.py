"""Which meshes a folder holds and where each goes: ``find_objects`` reads the three layouts
(ShapeNetCore v1 ``<synset>/<id>/model.obj``, v2 ``<synset>/<id>/models/model_normalized.obj``, flat
``<category>/<name>.{obj,off,ply,stl,glb,gltf}``), names categories by synset id or folder name
(``category_pairs``: the 13 NMR categories by both, a ShapeNet ``taxonomy.json`` beside them when
there is one) and ``assign_splits`` puts each object in train, val or test, from PTN/NMR-style id
lists ``{cid}_{split}ids.txt`` when given, else by a seeded shuffle and ratios.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from svr.data.build.meshes import MESH_SUFFIXES
from svr.nmr.format import NMR_CATEGORIES, SPLITS

LAYOUTS = ("auto", "shapenet_v1", "shapenet_v2", "flat")
_MODEL_FILE = {"shapenet_v1": Path("model.obj"), "shapenet_v2": Path("models") / "model_normalized.obj"}
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


def _layout_of(folder: Path) -> Optional[str]:
    """The layout of one category folder, or None when it holds no mesh."""
    for sub in sorted(p for p in folder.iterdir() if p.is_dir()):
        for layout, rel in _MODEL_FILE.items():
            if (sub / rel).is_file():
                return layout
    if any(p.is_file() and p.suffix.lower() in MESH_SUFFIXES for p in folder.iterdir()):
        return "flat"
    return None


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
        kind = _layout_of(folder) if layout == "auto" else layout
        if kind is not None:
            found[folder.name] = (folder, kind)
    if not found:
        raise ValueError(f"input: no category folder with meshes in {root} (layouts: ShapeNetCore v1 "
                         f"<synset>/<id>/model.obj, v2 <synset>/<id>/models/model_normalized.obj, flat "
                         f"<category>/<name>.{{{','.join(s[1:] for s in MESH_SUFFIXES)}}})")
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


def assign_splits(objects: Sequence[MeshObject], seed: int = 0, ratios: Sequence[float] = (0.7, 0.1, 0.2),
                  id_lists: Optional[Path] = None) -> tuple[list[MeshObject], list[MeshObject]]:
    """Each object with its split.

    With ``id_lists`` (a folder holding ``{cid}_{split}ids.txt`` for some categories and splits) a
    category that has lists takes its splits from them and its other objects are left out; a
    category without lists, and every category when ``id_lists`` is None, is shuffled with
    ``seed`` (and the category id) and cut by ``ratios`` (train, val, test; rounded, the rest
    to train).

    Returns:
        (objects with a split, objects left out because no list names them).
    """
    if len(ratios) != 3 or any(r < 0 for r in ratios) or not sum(ratios) > 0:
        raise ValueError(f"split_ratios must be three non-negative numbers (train, val, test), got {list(ratios)}")
    if id_lists is not None and not Path(id_lists).is_dir():
        raise FileNotFoundError(f"split_lists folder does not exist: {id_lists}")
    by_cat: dict[str, list[MeshObject]] = {}
    for obj in objects:
        by_cat.setdefault(obj.category_id, []).append(obj)
    kept, left_out = [], []
    for cid, objs in by_cat.items():
        lists = {s: Path(id_lists) / f"{cid}_{s}ids.txt" for s in SPLITS} if id_lists is not None else {}
        lists = {s: p for s, p in lists.items() if p.is_file()}
        if lists:
            where = {}
            for split, path in lists.items():
                for oid in _read_id_list(path):
                    where.setdefault(oid, split)
            for obj in objs:
                if obj.object_id in where:
                    kept.append(MeshObject(obj.category_id, obj.object_id, obj.path, where[obj.object_id]))
                else:
                    left_out.append(obj)
            continue
        order = np.random.default_rng([int(seed), *cid.encode()]).permutation(len(objs))
        total = float(sum(ratios))
        n_val = int(round(len(objs) * ratios[1] / total))
        n_test = int(round(len(objs) * ratios[2] / total))
        n_test = min(n_test, len(objs) - n_val)
        for rank, k in enumerate(order):
            split = "val" if rank < n_val else "test" if rank < n_val + n_test else "train"
            kept.append(MeshObject(objs[k].category_id, objs[k].object_id, objs[k].path, split))
    kept.sort(key=lambda o: (o.category_id, SPLITS.index(o.split), o.object_id))
    return kept, left_out


__all__ = ["LAYOUTS", "MeshObject", "find_objects", "assign_splits"]
