"""Validation IoU against training time of a run (all its stages, resumed parts included), run as
``python -m benchmarks.training_curve RUN [--baseline NAME=IOU ...] [--final NAME=IOU ...] [--out PATH]``.
It reads ``<run>/<stage>/csv/metrics*.csv`` (the CSV logger's files; a resumed stage's earlier parts
are kept as ``metrics.<k>.csv``) for every stage of the run's ``config.yaml`` schedule, and writes
``<out>.md`` (one row per validation: stage, step, cumulative hours, validation IoU, the coarse
stage's IoU where the refiner ran) and ``<out>.png`` (IoU against cumulative hours, one line per
stage, a dashed line per ``--baseline NAME=IOU``, a star at the curve's end per ``--final
NAME=IOU``). The time is the ``val/train_seconds`` the training logs (wall time of the stage so far,
validation included, over resumes); stages add up.
"""
from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import Optional

from benchmarks.common import atomic_write_text, save_figure
from svr.models.checkpoint_layout import STAGES


def _float(value: str) -> Optional[float]:
    try:
        return float(value) if value not in ("", None) else None
    except ValueError:
        return None


def read_curve(run_dir: Path) -> list[dict]:
    """The validation rows of every stage, in training order, with cumulative seconds."""
    rows: list[dict] = []
    offset = 0.0
    for stage in STAGES:
        folder = run_dir / stage / "csv"
        # metrics.<k>.csv are the earlier parts (k in order), metrics.csv the latest
        parts = [p for p in folder.glob("metrics.*.csv") if p.name.split(".")[1].isdigit()]
        files = sorted(parts, key=lambda p: int(p.name.split(".")[1]))
        if (folder / "metrics.csv").is_file():
            files.append(folder / "metrics.csv")
        stage_rows = []
        for path in files:
            with path.open(newline="") as fh:
                for rec in csv.DictReader(fh):
                    iou = _float(rec.get("val/iou", ""))
                    if iou is None:
                        continue
                    stage_rows.append({"stage": stage, "step": int(float(rec["step"])), "iou": iou,
                                       "iou_coarse": _float(rec.get("val/iou_coarse", "")),
                                       "seconds": _float(rec.get("val/train_seconds", ""))})
        stage_rows.sort(key=lambda r: r["step"])
        for r in stage_rows:
            r["hours"] = (offset + r["seconds"]) / 3600 if r["seconds"] is not None else None
        if stage_rows and stage_rows[-1]["seconds"] is not None:
            offset += stage_rows[-1]["seconds"]
        rows += stage_rows
    return rows


def markdown(rows: list[dict], baselines: dict[str, float], finals: Optional[dict[str, float]] = None) -> str:
    lines = ["| stage | step | hours | val IoU | coarse IoU |", "|---|---:|---:|---:|---:|"]
    for r in rows:
        hours = f"{r['hours']:.2f}" if r["hours"] is not None else "n/a"
        coarse = f"{r['iou_coarse']:.4f}" if r["stage"] != "coarse" and r["iou_coarse"] is not None else ""
        lines.append(f"| {r['stage']} | {r['step']} | {hours} | {r['iou']:.4f} | {coarse} |")
    if rows and baselines:
        best = max(r["iou"] for r in rows)
        lines.append("")
        for name, value in baselines.items():
            lines.append(f"- {name}: {value:.4f}; best validation IoU minus {name}: {best - value:+.4f}")
    for name, value in (finals or {}).items():
        lines.append(f"- {name} (the finished run): {value:.4f}"
                     + "".join(f"; minus {b}: {value - v:+.4f}" for b, v in baselines.items()))
    return "\n".join(lines)


def plot(rows: list[dict], baselines: dict[str, float], path: Path, title: str,
         finals: Optional[dict[str, float]] = None) -> None:
    import matplotlib  # heavy: only the plot needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: as above

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=110)
    for stage in STAGES:
        pts = [(r["hours"], r["iou"]) for r in rows if r["stage"] == stage and r["hours"] is not None]
        if pts:
            ax.plot(*zip(*pts), marker="o", ms=3, label=stage)
    for i, (name, value) in enumerate(baselines.items()):
        ax.axhline(value, ls="--", lw=1, color=f"C{i + 3}", label=name)
    end = max((r["hours"] for r in rows if r["hours"] is not None), default=None)
    for i, (name, value) in enumerate((finals or {}).items()):
        if end is not None:
            ax.plot([end], [value], marker="*", ms=11, ls="none", color=f"C{i + 7}", label=name)
    ax.set_xlabel("training time (hours, validation included)")
    ax.set_ylabel("validation IoU (benchmark mean)")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def _baseline(text: str) -> tuple[str, float]:
    name, sep, value = text.rpartition("=")
    try:
        if not sep or not name:
            raise ValueError
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--baseline must be NAME=IOU (e.g. retrieval=0.83), got {text!r}") from None


EXAMPLES = """\
example:
  python -m benchmarks.training_curve outputs/bench --baseline retrieval=0.83 --out docs/bench_curve
"""


def main(argv: Optional[list[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, epilog=EXAMPLES,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path, help="a training run folder (holds config.yaml and <stage>/csv/)")
    parser.add_argument("--baseline", type=_baseline, action="append", default=[], metavar="NAME=IOU")
    parser.add_argument("--final", type=_baseline, action="append", default=[], metavar="NAME=IOU",
                        help="a score of the finished run (e.g. its test IoU), a star at the curve's end")
    parser.add_argument("--out", type=Path, default=None, help="output path without suffix (default RUN/curve)")
    parser.add_argument("--title", default=None)
    args = parser.parse_args(argv)
    if not args.run_dir.is_dir():
        parser.error(f"run_dir {args.run_dir}: no such folder")
    rows = read_curve(args.run_dir)
    if not rows:
        parser.error(f"run_dir {args.run_dir}: no validation rows in <stage>/csv/metrics*.csv")
    baselines = dict(args.baseline)
    out = args.out or args.run_dir / "curve"
    out.parent.mkdir(parents=True, exist_ok=True)

    text = markdown(rows, baselines, dict(args.final))
    atomic_write_text(out.with_suffix(".md"), text + "\n")
    plot(rows, baselines, out.with_suffix(".png"), args.title or f"{args.run_dir}", dict(args.final))
    print(text)
    print(f"wrote {out.with_suffix('.md')} and {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
