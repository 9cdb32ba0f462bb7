"""The benchmark's results and report: ``EvaluationResult`` (per-image IoU of one model on one
split, its per-category tables, baselines and JSON summary) and the paper's table (categories as
columns, mean last, the paper's reference rows for NMR ShapeNet, baselines and other rows scored on
the same images), its notes, and the files ``svr.evaluate`` and the demo write (``table.md``,
``table.csv``, ``iou.json``, ``per_object.csv``, ``per_image.csv``).
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence, Union

import numpy as np

from sdfcommon.tooling.checks import check_instance
from sdfcommon.tooling.outputs import ensure_output_dir, write_csv, write_json, write_text
from svr.evaluation.baselines import DESCRIPTIONS, LABELS, READS
from svr.nmr.format import NMR_CATEGORIES, NMR_CATEGORY_IDS, NUM_VIEWS
from svr.nmr.metrics import PAPER_SDFDIFF_IOU, PAPER_SDFDIFF_MEAN_IOU, IoUTable, iou_table

PathLike = Union[str, os.PathLike]


@dataclass(frozen=True)
class ReferenceRow:
    """A published row of the paper's single-view table (3D IoU, NMR ShapeNet test split).

    Attributes:
        method: the row's label.
        mean: the published mean over the 13 categories.
        categories: per-category IoU by category id; empty where SPEC does not give them.
    """

    method: str
    mean: float
    categories: Mapping[str, float] = field(default_factory=dict)


# SPEC sections 3 and 5: the paper's table. Only SDFDiff's per-category values are in SPEC; the
# other rows show their means only.
PAPER_REFERENCE_ROWS: tuple[ReferenceRow, ...] = (
    ReferenceRow("NMR (paper)", 0.6015),
    ReferenceRow("SoftRas, silhouettes (paper)", 0.6234),
    ReferenceRow("SoftRas, full (paper)", 0.6464),
    ReferenceRow("SDFDiff (paper)", PAPER_SDFDIFF_MEAN_IOU, PAPER_SDFDIFF_IOU),
)

SIDE_VIEWS_DESCRIPTION = ("silhouette IoU of each prediction rendered from the two views 90 degrees either side "
                          "of its input view against those views' stored alpha (both at 0.5), mean of the two; "
                          "category = mean over its images, mean = unweighted mean over categories")



@dataclass(frozen=True)
class EvaluationResult:
    """Per-image benchmark IoU of one model on one split, and its tables.

    Per-image arrays have one entry per prediction (M = objects x views), in the order category,
    object, view.

    Attributes:
        split: "train", "val" or "test".
        dataset: a description of the data (kind and folder).
        categories: the data's (category id, name) pairs; ``category`` indexes them.
        is_nmr_shapenet: the data is real NMR ShapeNet (the paper's reference rows apply); procedural
            data with the same category ids is not.
        checkpoint: the model's file (None for a network given directly); stage: its training stage.
        output: which SDF the main row scores: "refined" or "coarse".
        category, object_index, view: (M,) int64.
        iou: (M,) float64 benchmark IoU of ``output``; iou_coarse: (M,) of the coarse SDF, or None.
        voxels: (M, 32, 32, 32) bool predicted voxels (NMR frame) of ``output``, if kept.
        side_iou: (M,) float64 silhouette IoU of ``output`` seen from the views 90 degrees either side
            of the input (``svr.nmr.side_views``), or None where not scored.
        baselines: baseline name (``svr.evaluation.baselines.BASELINES``) -> (M,) float64 IoU on the same images
            (``add_baselines``).
        baseline_side_iou: baseline name (``svr.evaluation.baselines.SIDE_BASELINES``) -> (M,) float64
            side-view silhouette IoU on the same images (``add_baselines``, where ``side_iou`` is scored).
        views_per_object: views evaluated per object (24 for the protocol).
        full_protocol: every view of every object was evaluated (no thinning).
        seconds: wall time.
        calibration: the model's calibration (``svr.inference.calibration.Calibration.describe``),
            None when its predictions were scored as the network made them.
        reads: what the model's predictions read besides the input image
            (``svr.evaluation.protocol.model_reads``: "nothing" or "the input camera (...)"), None
            where not known.
    """

    split: str
    dataset: str
    categories: tuple[tuple[str, str], ...]
    is_nmr_shapenet: bool
    checkpoint: Optional[str]
    stage: str
    output: str
    category: np.ndarray
    object_index: np.ndarray
    view: np.ndarray
    iou: np.ndarray
    iou_coarse: Optional[np.ndarray] = None
    voxels: Optional[np.ndarray] = None
    views_per_object: int = NUM_VIEWS
    full_protocol: bool = True
    seconds: float = 0.0
    baselines: Mapping[str, np.ndarray] = field(default_factory=dict)
    calibration: Optional[str] = None
    side_iou: Optional[np.ndarray] = None
    reads: Optional[str] = None
    baseline_side_iou: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def table(self) -> IoUTable:
        """Per-category IoU of ``output`` and their unweighted mean (``svr.nmr.metrics.iou_table``)."""
        return iou_table(self.iou, self.category, self.categories)

    @property
    def coarse_table(self) -> Optional[IoUTable]:
        return iou_table(self.iou_coarse, self.category, self.categories) if self.iou_coarse is not None else None

    @property
    def side_table(self) -> Optional[IoUTable]:
        """Per-category side-view silhouette IoU of ``output`` (None where not scored)."""
        return iou_table(self.side_iou, self.category, self.categories) if self.side_iou is not None else None

    def baseline_table(self, name: str) -> IoUTable:
        """Per-category IoU of a baseline on the same images."""
        return iou_table(self.baselines[name], self.category, self.categories)

    def baseline_side_table(self, name: str) -> IoUTable:
        """Per-category side-view silhouette IoU of a baseline on the same images."""
        return iou_table(self.baseline_side_iou[name], self.category, self.categories)

    def minus_retrieval(self) -> Optional[IoUTable]:
        """Per category, our IoU minus the retrieval baseline's (None without that baseline)."""
        if "retrieval" not in self.baselines:
            return None
        ours, ret = self.table, self.baseline_table("retrieval")
        rows = tuple(dataclasses.replace(a, iou=a.iou - b.iou) for a, b in zip(ours.rows, ret.rows))
        return IoUTable(rows, ours.mean - ret.mean)

    @property
    def present(self) -> list[int]:
        """Indices of the categories with at least one image: the table's columns, in the data's
        order, or in the paper's table order when every category is an NMR ShapeNet one."""
        cols = sorted(set(int(c) for c in np.unique(self.category)))
        if self.categories and all(c in NMR_CATEGORY_IDS for c, _ in self.categories):
            order = {cid: k for k, (cid, _) in enumerate(NMR_CATEGORIES)}
            cols.sort(key=lambda c: order[self.categories[c][0]])
        return cols

    @property
    def mean(self) -> float:
        return self.table.mean

    def index_of(self, category: int, object_index: int, view: int) -> int:
        """Position in the per-image arrays of (category index, object index, view).

        Raises:
            KeyError when that image was not evaluated.
        """
        hit = np.flatnonzero((self.category == category) & (self.object_index == object_index) & (self.view == view))
        if not len(hit):
            raise KeyError(f"(category {category}, object {object_index}, view {view}) was not evaluated")
        return int(hit[0])

    def per_object(self) -> list[dict[str, Any]]:
        """One row per object: mean and worst IoU over its views and the worst view; worst objects first."""
        rows = []
        keys = np.stack([self.category, self.object_index], axis=1)
        uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        for n, (c, o) in enumerate(uniq):
            sel = np.flatnonzero(inverse == n)
            worst = sel[int(np.argmin(self.iou[sel]))]
            cid, name = self.categories[int(c)]
            row = {"category_id": cid, "category": name, "object_index": int(o), "views": len(sel),
                   "iou_mean": float(self.iou[sel].mean()), "iou_min": float(self.iou[worst]),
                   "worst_view": int(self.view[worst])}
            if self.iou_coarse is not None:
                row["iou_coarse_mean"] = float(self.iou_coarse[sel].mean())
            if self.side_iou is not None:
                row["side_iou_mean"] = float(self.side_iou[sel].mean())
            for name, values in self.baselines.items():
                row[f"iou_{name}_mean"] = float(values[sel].mean())
            for name, values in self.baseline_side_iou.items():
                row[f"side_iou_{name}_mean"] = float(values[sel].mean())
            rows.append(row)
        rows.sort(key=lambda r: (r["iou_mean"], r["category_id"], r["object_index"]))
        return rows

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: ``{"split", "categories": {name: iou}, "mean", ...}`` (present categories)."""
        table = self.table
        rows = [table.rows[c] for c in self.present]
        out: dict[str, Any] = {
            "split": self.split,
            "dataset": self.dataset,
            "checkpoint": self.checkpoint,
            "stage": self.stage,
            "output": self.output,
            "categories": {r.name: r.iou for r in rows},
            "mean": table.mean,
            "images": {r.name: r.images for r in rows},
            "category_ids": {r.name: r.category_id for r in rows},
            "num_images": int(len(self.iou)),
            "num_objects": int(len(np.unique(np.stack([self.category, self.object_index], 1), axis=0)))
            if len(self.iou) else 0,
            "views_per_object": self.views_per_object,
            "full_protocol": self.full_protocol,
            "calibration": self.calibration,
            "reads": self.reads,
            "protocol": "marching cubes of each view's SDF -> NMR 32^3 voxelisation (dilated surface, "
                        "vertices, 6-connected fill) -> IoU per image; category = mean over its images; "
                        "mean = unweighted mean over categories",
            "seconds": self.seconds,
        }

        def summary(t: IoUTable) -> dict[str, Any]:
            return {"categories": {t.rows[c].name: t.rows[c].iou for c in self.present}, "mean": t.mean}

        coarse = self.coarse_table
        if coarse is not None:
            out["coarse"] = summary(coarse)
        side = self.side_table
        if side is not None:
            out["side_views"] = {"description": SIDE_VIEWS_DESCRIPTION, **summary(side)}
            if self.baseline_side_iou:
                out["side_views"]["baselines"] = {name: {"label": LABELS[name], **summary(self.baseline_side_table(name))}
                                                  for name in self.baseline_side_iou}
        if self.baselines:
            out["baselines"] = {name: {"label": LABELS[name], "description": DESCRIPTIONS[name],
                                       "reads": READS[name], **summary(self.baseline_table(name))}
                                for name in self.baselines}
        minus = self.minus_retrieval()
        if minus is not None:
            out["ours_minus_retrieval"] = summary(minus)
        if self.is_nmr_shapenet:
            out["reference"] = {r.method: {"mean": r.mean, "categories": {
                name: r.categories[cid] for cid, name in self.categories if cid in r.categories}}
                for r in PAPER_REFERENCE_ROWS}
        return out


def format_iou(x: Optional[float], signed: bool = False) -> str:
    """An IoU as printed in the tables: 4 decimals (signed for differences), blank when unknown."""
    return "" if x is None or not math.isfinite(x) else (f"{x:+.4f}" if signed else f"{x:.4f}")


ExtraRows = Optional[Mapping[str, IoUTable]]


def _iou_row(label: str, table: IoUTable, cols: Sequence[int]) -> list[str]:
    """A table row: the label, the IoU of the categories ``cols`` (indices into ``table.rows``), the mean."""
    return [label] + [format_iou(table.rows[c].iou) for c in cols] + [format_iou(table.mean)]


def _check_extra(extra_rows: ExtraRows) -> dict[str, IoUTable]:
    out = dict(extra_rows or {})
    for label, t in out.items():
        check_instance(t, f"extra_rows[{label!r}]", IoUTable, "a svr.nmr.metrics.IoUTable")
    return out


def table_rows(result: EvaluationResult, extra_rows: ExtraRows = None,
               label: Optional[str] = None) -> tuple[list[str], list[list[str]]]:
    """The paper's layout as strings: header ``["method", <category names>..., "mean"]`` and rows
    (ours, ours coarse, the ``extra_rows``, the image counts, then the reference rows for NMR
    ShapeNet; blank cells where a value is not known).

    Args:
        extra_rows: more methods scored on the same images (e.g. a demo's baselines): label ->
            IoUTable (``svr.nmr.metrics.iou_table``), matched to the columns by category id.
        label: the main row's label (default "ours (<output>)").
    """
    cols = result.present
    table = result.table
    header = ["method"] + [table.rows[c].name for c in cols] + ["mean"]
    rows = [_iou_row(label or f"ours ({result.output})", table, cols)]
    coarse = result.coarse_table
    if coarse is not None:
        rows.append(_iou_row("ours (coarse)", coarse, cols))
    named = list(_check_extra(extra_rows).items())
    if result.baselines:
        named += [(LABELS[name], result.baseline_table(name)) for name in result.baselines]
    minus = result.minus_retrieval()
    if minus is not None:
        named.append(("ours - retrieval", minus))
    for name, extra in named:
        by_id = {r.category_id: r.iou for r in extra.rows}
        rows.append([name] + [format_iou(by_id.get(table.rows[c].category_id), signed=extra is minus)
                              for c in cols] + [format_iou(extra.mean, signed=extra is minus)])
    rows.append(["images"] + [str(table.rows[c].images) for c in cols] + [str(len(result.iou))])
    if result.is_nmr_shapenet:
        for ref in PAPER_REFERENCE_ROWS:
            rows.append([ref.method] + [format_iou(ref.categories.get(table.rows[c].category_id)) for c in cols]
                        + [format_iou(ref.mean)])
    return header, rows


def table_notes(result: EvaluationResult) -> list[str]:
    """The lines printed under the table (what the numbers are and where they come from)."""
    notes = []
    if not result.full_protocol:
        notes.append(f"Thinned run ({result.views_per_object} views per object or fewer objects): "
                     "not the benchmark protocol's number.")
    if result.calibration is not None:
        notes.append(f"Our predictions are calibrated ({result.calibration}; chosen on the validation split, "
                     "docs/svr_evaluation.md).")
    if result.baselines:
        notes.append("Baselines, scored on the same images by the same protocol: " + "; ".join(
            f"{LABELS[n]}: {DESCRIPTIONS[n]}" for n in result.baselines) + ".")
    if result.reads is not None or result.baselines:
        reads = ([f"ours: {result.reads}"] if result.reads is not None else []) + [
            f"{LABELS[n]}: {READS[n]}" for n in result.baselines]
        notes.append("What each row reads at test time besides the input image (the input camera: the NMR "
                     "view the image was taken from; methods published on NMR ShapeNet read the image "
                     "only): " + "; ".join(reads) + ".")
    if result.is_nmr_shapenet:
        per_category = float(np.mean(list(PAPER_SDFDIFF_IOU.values())))
        notes.append("Reference rows: the SDFDiff paper's table (NMR ShapeNet test split, SPEC sections 3 and 5). "
                     "Only SDFDiff's per-category values are known here; the NMR and SoftRas rows give "
                     "their means only.")
        notes.append(f"SDFDiff (paper): the printed mean is {PAPER_SDFDIFF_MEAN_IOU:.4f}, but its 13 per-category "
                     f"values average {per_category:.4f}; the row shows the printed one.")
        if len(result.present) < len(NMR_CATEGORY_IDS):
            notes.append(f"Our mean is over the {len(result.present)} categories evaluated; the reference means "
                         "are over all 13.")
        if result.split != "test":
            notes.append(f"The reference rows are test-split numbers; this is the {result.split} split.")
    else:
        notes.append("The paper's reference rows belong to real NMR ShapeNet and are not shown: numbers on "
                     "other data, procedural data with the same categories included, are not comparable to them.")
    return notes


def _markdown(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    """A markdown table's lines, columns padded for terminals (the first left-aligned, the rest right)."""
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]

    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))) + " |"

    sep = "|" + "|".join(("-" * (w + 2)) if i == 0 else ("-" * (w + 1) + ":") for i, w in enumerate(widths)) + "|"
    return [line(header), sep] + [line(r) for r in rows]


def format_table(result: EvaluationResult, extra_rows: ExtraRows = None, label: Optional[str] = None) -> str:
    """The markdown report: a title line, the table in the paper's layout (categories as columns,
    mean last; reference rows for NMR ShapeNet), then the notes, then (where scored) the side-view
    silhouette IoU in the same layout. ``extra_rows`` and ``label``: see ``table_rows``."""
    header, rows = table_rows(result, extra_rows, label)
    n_obj = len(np.unique(np.stack([result.category, result.object_index], 1), axis=0)) if len(result.iou) else 0
    title = (f"3D IoU, {result.dataset}, split '{result.split}': {n_obj} objects x {result.views_per_object} views "
             f"= {len(result.iou)} images; checkpoint {result.checkpoint or '(in memory)'} ({result.stage} stage)")
    lines = [title, ""] + _markdown(header, rows) + [""] + [f"- {n}" for n in table_notes(result)]
    side = result.side_table
    if side is not None:
        side_rows = [_iou_row(label or f"ours ({result.output})", side, result.present)]
        side_rows += [_iou_row(LABELS[name], result.baseline_side_table(name), result.present)
                      for name in result.baseline_side_iou]
        note = (" Baselines: a retrieved training object shows its stored silhouettes in those views, a "
                "category's mean shape its render." if result.baseline_side_iou else "")
        lines += ["", f"Side views: {SIDE_VIEWS_DESCRIPTION}.{note}", ""] + _markdown(header, side_rows)
    return "\n".join(lines) + "\n"


def write_report(result: EvaluationResult, output_dir: PathLike, extra_rows: ExtraRows = None,
                 label: Optional[str] = None, fields: Optional[Mapping[str, Any]] = None) -> dict[str, Path]:
    """Writes ``table.md``, ``table.csv``, ``iou.json``, ``per_object.csv`` (worst first) and
    ``per_image.csv`` into ``output_dir``, each atomically (``sdfcommon.tooling.outputs``: temp file + ``os.replace``;
    non-finite numbers become JSON null). ``extra_rows`` (see ``table_rows``) also go into the JSON
    under ``"extra"``; ``fields`` are more top-level entries of the JSON (plain values; a name of the
    result's own is refused).

    Returns:
        {kind: path}. Raises ValueError naming ``output_dir`` when it cannot be written.
    """
    folder = ensure_output_dir(output_dir, "output_dir")
    header, rows = table_rows(result, extra_rows, label)
    summary = result.to_dict()
    extra = _check_extra(extra_rows)
    if extra:
        summary["extra"] = {name: {"categories": {r.name: r.iou for r in t.rows if r.images > 0}, "mean": t.mean}
                            for name, t in extra.items()}
    for name, value in (fields or {}).items():
        if name in summary:
            raise ValueError(f"fields: {name!r} is an entry of the result itself")
        summary[name] = value
    files = {
        "markdown": write_text(folder / "table.md", format_table(result, extra_rows, label)),
        "csv": write_csv(folder / "table.csv", [dict(zip(header, r)) for r in rows], header),
        "json": write_json(folder / "iou.json", summary),
    }
    obj_columns = ["category_id", "category", "object_index", "views", "iou_mean", "iou_min", "worst_view"] + (
        ["iou_coarse_mean"] if result.iou_coarse is not None else []) + (
        ["side_iou_mean"] if result.side_iou is not None else []) + [f"iou_{n}_mean" for n in result.baselines] + [
        f"side_iou_{n}_mean" for n in result.baseline_side_iou]
    files["per_object"] = write_csv(folder / "per_object.csv", result.per_object(), obj_columns)
    img_columns = ["category_id", "category", "object_index", "view", "iou"] + (
        ["iou_coarse"] if result.iou_coarse is not None else []) + (
        ["side_iou"] if result.side_iou is not None else []) + [f"iou_{n}" for n in result.baselines] + [
        f"side_iou_{n}" for n in result.baseline_side_iou]
    img_rows = []
    for i in range(len(result.iou)):
        cid, name = result.categories[int(result.category[i])]
        row = {"category_id": cid, "category": name, "object_index": int(result.object_index[i]),
               "view": int(result.view[i]), "iou": float(result.iou[i])}
        if result.iou_coarse is not None:
            row["iou_coarse"] = float(result.iou_coarse[i])
        if result.side_iou is not None:
            row["side_iou"] = float(result.side_iou[i])
        for n, values in result.baselines.items():
            row[f"iou_{n}"] = float(values[i])
        for n, values in result.baseline_side_iou.items():
            row[f"side_iou_{n}"] = float(values[i])
        img_rows.append(row)
    files["per_image"] = write_csv(folder / "per_image.csv", img_rows, img_columns)
    return files


__all__ = ["EvaluationResult", "ReferenceRow", "PAPER_REFERENCE_ROWS", "NMR_CATEGORY_IDS", "ExtraRows", "format_iou", "table_rows", "table_notes",
           "format_table", "write_report"]
