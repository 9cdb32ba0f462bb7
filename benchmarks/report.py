"""Shared pieces of the accuracy-versus-time study: Pareto fronts, plots, tables, machine info."""
from __future__ import annotations

import os
import platform
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence


@dataclass
class Point:
    """One measured setting: its label, cost (seconds) and error (lower is better for both)."""

    label: str
    seconds: float
    error: float
    default: bool = False
    extra: dict = field(default_factory=dict)


def pareto_front(points: Sequence[Point]) -> list[bool]:
    """For each point, whether no other point is at least as fast and as accurate and better in one."""
    flags = []
    for p in points:
        dominated = any(
            (q.seconds <= p.seconds and q.error <= p.error) and (q.seconds < p.seconds or q.error < p.error)
            for q in points
        )
        flags.append(not dominated)
    return flags


def atomic_write_text(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def plot_tradeoff(points: Sequence[Point], path: Path, title: str, xlabel: str, ylabel: str,
                  logx: bool = True, logy: bool = True) -> None:
    """Error against time, the Pareto front joined and marked, the default setting highlighted."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    front = pareto_front(points)
    fig, ax = plt.subplots(figsize=(6.0, 4.2), dpi=110)
    for p, on in zip(points, front):
        ax.scatter(p.seconds, p.error, s=70 if p.default else 30, marker="*" if p.default else "o",
                   color="tab:red" if p.default else ("tab:blue" if on else "tab:gray"), zorder=3)
        ax.annotate(p.label, (p.seconds, p.error), textcoords="offset points", xytext=(4, 4), fontsize=7)
    fp = sorted((p for p, on in zip(points, front) if on), key=lambda p: p.seconds)
    if len(fp) > 1:
        ax.plot([p.seconds for p in fp], [p.error for p in fp], color="tab:blue", lw=1, label="Pareto front")
    ax.scatter([], [], marker="*", color="tab:red", s=70, label="default")
    if logx:
        ax.set_xscale("log")
    if logy and all(p.error > 0 for p in points):
        ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".png")
    os.close(fd)
    fig.savefig(tmp, format="png")
    plt.close(fig)
    os.replace(tmp, path)


def markdown_table(points: Sequence[Point], columns: Sequence[tuple[str, str]],
                   setting_name: str = "setting") -> str:
    """A markdown table: the setting, the given columns (header, key in ``extra`` or an attribute),
    and whether the point is on the Pareto front; the default's row in bold."""
    front = pareto_front(points)
    head = "| " + " | ".join([setting_name, *[c[0] for c in columns], "Pareto"]) + " |"
    sep = "|" + "---|" * (len(columns) + 2)
    rows = [head, sep]
    for p, on in zip(points, front):
        cells = []
        for _, key in columns:
            v = getattr(p, key) if hasattr(p, key) else p.extra.get(key, "")
            cells.append(_fmt(v))
        label = f"**{p.label}** (default)" if p.default else p.label
        rows.append("| " + " | ".join([label, *cells, "yes" if on else ""]) + " |")
    return "\n".join(rows)


def _fmt(v) -> str:
    if isinstance(v, float):
        if v == 0:
            return "0"
        if abs(v) >= 100:
            return f"{v:.0f}"
        if abs(v) >= 0.01:
            return f"{v:.4g}"
        return f"{v:.3e}"
    return str(v)


def machine_info(extra: Optional[dict] = None) -> str:
    """A markdown list of the machine and library versions."""
    import numpy
    import torch

    lines = [
        f"- machine: {platform.machine()}, {os.cpu_count()} CPU cores, {platform.platform()}",
        f"- python {platform.python_version()}, torch {torch.__version__}, numpy {numpy.__version__}",
    ]
    try:
        import numba

        lines.append(f"- numba {numba.__version__}")
    except ImportError:
        pass
    lines.append(f"- torch threads: {torch.get_num_threads()}; CUDA: "
                 f"{torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'none'}")
    for k, v in (extra or {}).items():
        lines.append(f"- {k}: {v}")
    return "\n".join(lines)
