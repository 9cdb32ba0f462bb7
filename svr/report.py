"""The benchmark's report: an evaluation's per-category IoU as the paper's table (categories as
columns, mean last, the paper's reference rows for NMR ShapeNet, baselines and other rows scored on
the same images), its notes, and the files ``svr.evaluate`` and the demo write (``table.md``,
``table.csv``, ``iou.json``, ``per_object.csv``, ``per_image.csv``).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Mapping, Optional, Sequence, Union

import numpy as np

from sdfcommon.outputs import ensure_output_dir, write_csv, write_json, write_text

from .data.nmr import NMR_CATEGORIES
from .metrics import PAPER_SDFDIFF_IOU, PAPER_SDFDIFF_MEAN_IOU, IoUTable

if TYPE_CHECKING:
    from .evaluate import EvaluationResult

PathLike = Union[str, os.PathLike]
NMR_CATEGORY_IDS = frozenset(cid for cid, _ in NMR_CATEGORIES)


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



def format_iou(x: Optional[float], signed: bool = False) -> str:
    """An IoU as printed in the tables: 4 decimals (signed for differences), blank when unknown."""
    return "" if x is None or not math.isfinite(x) else (f"{x:+.4f}" if signed else f"{x:.4f}")


ExtraRows = Optional[Mapping[str, IoUTable]]


def _check_extra(extra_rows: ExtraRows) -> dict[str, IoUTable]:
    out = dict(extra_rows or {})
    for label, t in out.items():
        if not isinstance(t, IoUTable):
            raise TypeError(f"extra_rows[{label!r}] must be a svr.metrics.IoUTable, got {type(t).__name__}")
    return out


def table_rows(result: "EvaluationResult", extra_rows: ExtraRows = None,
               label: Optional[str] = None) -> tuple[list[str], list[list[str]]]:
    """The paper's layout as strings: header ``["method", <category names>..., "mean"]`` and rows
    (ours, ours coarse, the ``extra_rows``, the image counts, then the reference rows for NMR
    ShapeNet; blank cells where a value is not known).

    Args:
        extra_rows: more methods scored on the same images (e.g. a demo's baselines): label ->
            IoUTable (``svr.metrics.iou_table``), matched to the columns by category id.
        label: the main row's label (default "ours (<output>)").
    """
    cols = result.present
    table = result.table
    header = ["method"] + [table.rows[c].name for c in cols] + ["mean"]
    rows = [[label or f"ours ({result.output})"] + [format_iou(table.rows[c].iou) for c in cols] + [format_iou(table.mean)]]
    coarse = result.coarse_table
    if coarse is not None:
        rows.append(["ours (coarse)"] + [format_iou(coarse.rows[c].iou) for c in cols] + [format_iou(coarse.mean)])
    named = list(_check_extra(extra_rows).items())
    if result.baselines:
        from .baselines import LABELS

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


def table_notes(result: "EvaluationResult") -> list[str]:
    """The lines printed under the table (what the numbers are and where they come from)."""
    notes = []
    if not result.full_protocol:
        notes.append(f"Thinned run ({result.views_per_object} views per object or fewer objects): "
                     "not the benchmark protocol's number.")
    if result.baselines:
        from .baselines import DESCRIPTIONS, LABELS

        notes.append("Baselines, scored on the same images by the same protocol: " + "; ".join(
            f"{LABELS[n]}: {DESCRIPTIONS[n]}" for n in result.baselines) + ".")
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


def format_table(result: "EvaluationResult", extra_rows: ExtraRows = None, label: Optional[str] = None) -> str:
    """The markdown report: a title line, the table in the paper's layout (categories as columns,
    mean last; reference rows for NMR ShapeNet), then the notes. Columns are padded for terminals.
    ``extra_rows`` and ``label``: see ``table_rows``."""
    header, rows = table_rows(result, extra_rows, label)
    widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]

    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))) + " |"

    sep = "|" + "|".join(("-" * (w + 2)) if i == 0 else ("-" * (w + 1) + ":") for i, w in enumerate(widths)) + "|"
    n_obj = len(np.unique(np.stack([result.category, result.object_index], 1), axis=0)) if len(result.iou) else 0
    title = (f"3D IoU, {result.dataset}, split '{result.split}': {n_obj} objects x {result.views_per_object} views "
             f"= {len(result.iou)} images; checkpoint {result.checkpoint or '(in memory)'} ({result.stage} stage)")
    body = [line(header), sep] + [line(r) for r in rows]
    return "\n".join([title, ""] + body + [""] + [f"- {n}" for n in table_notes(result)]) + "\n"


def write_report(result: "EvaluationResult", output_dir: PathLike, extra_rows: ExtraRows = None,
                 label: Optional[str] = None) -> dict[str, Path]:
    """Writes ``table.md``, ``table.csv``, ``iou.json``, ``per_object.csv`` (worst first) and
    ``per_image.csv`` into ``output_dir``, each atomically (``sdfcommon.outputs``: temp file + ``os.replace``;
    non-finite numbers become JSON null). ``extra_rows`` (see ``table_rows``) also go into the JSON
    under ``"extra"``.

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
    files = {
        "markdown": write_text(folder / "table.md", format_table(result, extra_rows, label)),
        "csv": write_csv(folder / "table.csv", [dict(zip(header, r)) for r in rows], header),
        "json": write_json(folder / "iou.json", summary),
    }
    obj_columns = ["category_id", "category", "object_index", "views", "iou_mean", "iou_min", "worst_view"] + (
        ["iou_coarse_mean"] if result.iou_coarse is not None else []) + [f"iou_{n}_mean" for n in result.baselines]
    files["per_object"] = write_csv(folder / "per_object.csv", result.per_object(), obj_columns)
    img_columns = ["category_id", "category", "object_index", "view", "iou"] + (
        ["iou_coarse"] if result.iou_coarse is not None else []) + [f"iou_{n}" for n in result.baselines]
    img_rows = []
    for i in range(len(result.iou)):
        cid, name = result.categories[int(result.category[i])]
        row = {"category_id": cid, "category": name, "object_index": int(result.object_index[i]),
               "view": int(result.view[i]), "iou": float(result.iou[i])}
        if result.iou_coarse is not None:
            row["iou_coarse"] = float(result.iou_coarse[i])
        for n, values in result.baselines.items():
            row[f"iou_{n}"] = float(values[i])
        img_rows.append(row)
    files["per_image"] = write_csv(folder / "per_image.csv", img_rows, img_columns)
    return files


__all__ = ["ReferenceRow", "PAPER_REFERENCE_ROWS", "NMR_CATEGORY_IDS", "ExtraRows", "format_iou", "table_rows", "table_notes",
           "format_table", "write_report"]
