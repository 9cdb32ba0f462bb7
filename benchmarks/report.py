"""Shared pieces of the benchmarks: Pareto fronts, plots, tables, a reading of the results,
machine info, and the one way they run a multi-view reconstruction (``run_mvr``)."""
from __future__ import annotations

import io
import math
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy
import torch

from mvr import reconstruct
from mvr.settings import compose_config, reconstruct_kwargs
from sdfcommon.tooling.outputs import atomic_write, write_text


@dataclass
class Point:
    """One measured setting: its label, cost (seconds) and error (lower is better for both), and
    optionally ``error_interval``, the (low, high) interval of the error (drawn as an error bar)."""

    label: str
    seconds: float
    error: float
    default: bool = False
    extra: dict = field(default_factory=dict)
    error_interval: Optional[tuple[float, float]] = None


def pareto_front(points: Sequence[Point]) -> list[bool]:
    """For each point, whether no other point is at least as fast and as accurate and better in one
    (a point with a non-finite time or error is never on the front and dominates nothing)."""
    ok = [math.isfinite(p.seconds) and math.isfinite(p.error) for p in points]
    flags = []
    for p, p_ok in zip(points, ok):
        dominated = any(
            q_ok and (q.seconds <= p.seconds and q.error <= p.error) and (q.seconds < p.seconds or q.error < p.error)
            for q, q_ok in zip(points, ok)
        )
        flags.append(p_ok and not dominated)
    return flags


def atomic_write_text(path: Path, text: str) -> None:
    """Writes UTF-8 text to ``path`` atomically (``sdfcommon.tooling.outputs.write_text``)."""
    write_text(path, text)


def run_mvr(target: str, out_dir: Path, overrides: Sequence[str] = ()) -> dict:
    """One multi-view reconstruction in this process, with the settings of
    ``python -m mvr target=<target> out_dir=<out_dir> progress=false <overrides>`` (configs/mvr.yaml,
    composed and instantiated as the command does). The caller sets the process-wide runtime first
    (``mvr.configure_runtime``, as the command does from ``runtime.*``).

    Returns:
        the run's metrics (what it writes to ``<out_dir>/metrics.json``).
    """
    cfg = compose_config([f"target={target}", f"out_dir={out_dir}", "progress=false", *overrides])
    return reconstruct(target, out_dir, **reconstruct_kwargs(cfg)).metrics


def plot_tradeoff(points: Sequence[Point], path: Path, title: str, xlabel: str, ylabel: str,
                  logx: bool = True, logy: bool = True,
                  curves: Optional[Mapping[str, Sequence[tuple[float, float]]]] = None,
                  figsize: tuple[float, float] = (6.0, 4.2)) -> None:
    """Error against time, the Pareto front joined and marked, the default setting highlighted.

    Args:
        points: the settings measured (x: ``seconds``, y: ``error``; an error bar where the point
            has an ``error_interval``).
        path: the PNG to write (atomically).
        logx, logy: log axes, where the values span at least a factor of 3 (else linear).
        curves: optional thin lines behind the points, label -> [(seconds, error), ...] (e.g. a
            training run's validation error over time; its end is usually the run's point).
        figsize: the figure's (width, height) in inches (larger where many points need labels).
    """
    import matplotlib  # heavy: only the plots need it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy: as above
    from matplotlib import ticker  # heavy: as above

    front = pareto_front(points)
    fig, ax = plt.subplots(figsize=figsize, dpi=110)
    for curve in (curves or {}).values():
        if len(curve) > 1:
            ax.plot([c[0] for c in curve], [c[1] for c in curve], color="tab:gray", lw=0.7, alpha=0.5, zorder=1)
    # Labels alternate above and below their points, in order of time, so that neighbours collide less.
    rank = {id(p): i for i, p in enumerate(sorted(points, key=lambda p: (p.seconds, p.error)))}
    for p, on in zip(points, front):
        if p.error_interval is not None:
            lo, hi = p.error_interval
            ax.errorbar(p.seconds, p.error, yerr=[[max(p.error - lo, 0.0)], [max(hi - p.error, 0.0)]], fmt="none",
                         ecolor="tab:red" if p.default else "tab:gray", elinewidth=0.8, capsize=2, zorder=2)
        ax.scatter(p.seconds, p.error, s=70 if p.default else 30, marker="*" if p.default else "o",
                   color="tab:red" if p.default else ("tab:blue" if on else "tab:gray"), zorder=3)
        ax.annotate(p.label, (p.seconds, p.error), textcoords="offset points",
                    xytext=(4, 4 if rank[id(p)] % 2 == 0 else -10), fontsize=7)
    fp = sorted((p for p, on in zip(points, front) if on), key=lambda p: p.seconds)
    if len(fp) > 1:
        ax.plot([p.seconds for p in fp], [p.error for p in fp], color="tab:blue", lw=1, label="Pareto front")
    ax.scatter([], [], marker="*", color="tab:red", s=70, label="default")
    xs = [p.seconds for p in points if math.isfinite(p.seconds)] + [c[0] for cv in (curves or {}).values() for c in cv]
    ys = ([p.error for p in points if math.isfinite(p.error)] + [c[1] for cv in (curves or {}).values() for c in cv]
          + [e for p in points if p.error_interval is not None for e in p.error_interval if math.isfinite(e)])
    # A log axis over less than a factor of 3 has no labelled tick: linear reads better there.
    for axis, values, log in ((ax.xaxis, xs, logx), (ax.yaxis, ys, logy)):
        if log and values and min(values) > 0 and max(values) / min(values) >= 3:
            (ax.set_xscale if axis is ax.xaxis else ax.set_yscale)("log")
            axis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
            axis.set_minor_formatter(ticker.NullFormatter())
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path)


def save_figure(fig, path: Path) -> None:
    """Writes a matplotlib figure as a PNG atomically and closes it."""
    import matplotlib.pyplot as plt  # heavy: only the plots need it

    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write(path, lambda f: f.write(buf.getvalue()))


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
            cells.append(fmt_value(v))
        label = f"**{p.label}** (default)" if p.default else p.label
        rows.append("| " + " | ".join([label, *cells, "yes" if on else ""]) + " |")
    return "\n".join(rows)


def fmt_value(v) -> str:
    """A table cell: floats to about 4 significant digits (small ones in e-notation), a (low, high)
    pair of floats as ``[low, high]``, else ``str``."""
    if isinstance(v, tuple) and len(v) == 2 and all(isinstance(x, float) for x in v):
        return f"[{fmt_value(v[0])}, {fmt_value(v[1])}]"
    if isinstance(v, float):
        if v == 0:
            return "0"
        if abs(v) >= 100:
            return f"{v:.0f}"
        if abs(v) >= 0.01:
            return f"{v:.4g}"
        return f"{v:.3e}"
    return str(v)


def _finite(points: Sequence[Point]) -> list[Point]:
    return [p for p in points if math.isfinite(p.error) and math.isfinite(p.seconds)]


def cheapest_within(points: Sequence[Point], tolerance: float = 0.1) -> tuple[Point, Point]:
    """(the most accurate point, the fastest point whose error is within ``tolerance`` (relative)
    of it); points with a non-finite error or time are left out."""
    if not tolerance >= 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance!r}")
    pts = _finite(points)
    if not pts:
        raise ValueError("points holds no point with a finite error and time")
    best = min(pts, key=lambda p: (p.error, p.seconds))
    good = min((p for p in pts if p.error <= best.error * (1 + tolerance)), key=lambda p: (p.seconds, p.error))
    return best, good


def reading(points: Sequence[Point], unit: str = "s", error_name: str = "error",
            tolerance: float = 0.1, noise: float = 0.2) -> str:
    """A plain-words reading of one sweep, computed from its points (so it stays true when the
    study is rerun): the Pareto front from fast to accurate, the cheapest setting within
    ``tolerance`` (relative) of the best error, and where the default stands.

    Args:
        points: the measured settings (non-finite errors are left out of the reading).
        unit: the unit of ``seconds`` in the text; error_name: what ``error`` is, in words.
        tolerance: how much worse than the best error still counts as "as good" (0.1: 10 %).
        noise: relative time differences below this are called timing noise (0.2: 20 %).
    Returns:
        one markdown paragraph.
    """
    if not tolerance >= 0:
        raise ValueError(f"tolerance must be >= 0, got {tolerance!r}")
    if not 0 <= noise < 1:
        raise ValueError(f"noise must lie in [0, 1), got {noise!r}")
    pts = _finite(points)
    if not pts:
        return "No setting gave a finite result."
    front = sorted((p for p, on in zip(pts, pareto_front(pts)) if on), key=lambda p: (p.seconds, p.error))
    best, good = cheapest_within(pts, tolerance)
    fast = min(pts, key=lambda p: (p.seconds, p.error))
    text = [f"Pareto front (fast to accurate): "
            + ", ".join(f"{p.label} ({fmt_value(p.seconds)} {unit}, {fmt_value(p.error)})" for p in front) + "."]
    if good is best:
        text.append(f"The lowest {error_name} is {best.label}'s ({fmt_value(best.error)}, {fmt_value(best.seconds)} "
                    f"{unit}); no cheaper setting comes within {tolerance:.0%} of it.")
    else:
        text.append(f"{good.label} comes within {tolerance:.0%} of the lowest {error_name} ({best.label}: "
                    f"{fmt_value(best.error)}) in {fmt_value(good.seconds)} {unit} instead of "
                    f"{fmt_value(best.seconds)} {unit}.")
    if fast is not good:
        text.append(f"The fastest, {fast.label}, costs {fmt_value(fast.seconds)} {unit} for {error_name} "
                    f"{fmt_value(fast.error)} ({fmt_value(fast.error / best.error)}x the lowest).")
    default = next((p for p in pts if p.default), None)
    if default is not None:
        if any(default is q for q in front):
            text.append(f"The default ({default.label}) is on the front.")
        else:
            better = [q for q in pts if q.seconds <= default.seconds and q.error <= default.error
                      and (q.seconds < default.seconds or q.error < default.error)]
            q = min(better, key=lambda q: q.seconds)
            as_good = q.seconds >= default.seconds * (1 - noise) and q.error >= default.error / (1 + tolerance)
            text.append(f"The default ({default.label}) is not on the front: {q.label} is at least as accurate "
                        f"({fmt_value(q.error)} vs {fmt_value(default.error)}) in {fmt_value(q.seconds)} {unit} "
                        f"instead of {fmt_value(default.seconds)} {unit}"
                        + (" (within the timing noise and the error tolerance: the default is as good a choice)"
                           if as_good else "") + ".")
    return " ".join(text)


def tradeoff_section(points: Sequence[Point], columns: Sequence[tuple[str, str]], png: Path, *, title: str,
                     setting_name: str, xlabel: str, ylabel: str, unit: str = "s", error_name: str = "error",
                     logx: bool = True, logy: bool = True,
                     curves: Optional[Mapping[str, Sequence[tuple[float, float]]]] = None,
                     heading: str = "###", tolerance: float = 0.1, choice: Optional[str] = None,
                     figsize: tuple[float, float] = (6.0, 4.2)) -> str:
    """One study section: writes the plot to ``png`` and returns the markdown: a heading, the table
    (``markdown_table``), the plot (linked by file name: the report sits beside it) and
    ``reading``'s paragraph (with ``tolerance``), or ``choice`` instead where the part words its own
    (e.g. from intervals, which ``reading`` does not weigh)."""
    plot_tradeoff(points, png, title, xlabel, ylabel, logx=logx, logy=logy, curves=curves, figsize=figsize)
    choose = "**What to choose.** " + (choice if choice is not None else reading(points, unit, error_name, tolerance))
    return "\n".join([f"{heading} {title}", "", markdown_table(points, columns, setting_name), "",
                      f"![{title}]({png.name})", "", choose, ""])


def progress_log(enabled: bool, indent: str = "  ") -> Callable[[str], None]:
    """A function that prints a progress line to stderr (indented), or does nothing."""
    if not enabled:
        return lambda line: None

    return lambda line: print(f"{indent}{line}", file=sys.stderr, flush=True)


@dataclass(frozen=True)
class Timed:
    """What ``timed`` measured: the call's result, wall and CPU seconds (this process, all its
    threads) and the mean of the 1-minute load average before and after."""

    result: Any
    wall: float
    cpu: float
    load: float


def timed(fn: Callable[[], Any]) -> Timed:
    """Calls ``fn()`` once and measures it (see ``Timed``)."""
    load0 = _load1()
    t0, c0 = time.perf_counter(), time.process_time()
    result = fn()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return Timed(result, wall, cpu, (load0 + _load1()) / 2)


def _load1() -> float:
    try:
        return os.getloadavg()[0]
    except (OSError, AttributeError):
        return float("nan")


def load_average() -> str:
    """The 1, 5 and 15 minute load averages, e.g. ``"2.1 / 1.8 / 1.5"`` (``"n/a"`` where unknown)."""
    try:
        return " / ".join(f"{x:.1f}" for x in os.getloadavg())
    except (OSError, AttributeError):
        return "n/a"


def machine_info(extra: Optional[dict] = None) -> str:
    """A markdown list of the machine, library versions and the load average now."""
    lines = [
        f"- machine: {platform.machine()}, {os.cpu_count()} CPU cores, {platform.platform()}",
        f"- python {platform.python_version()}, torch {torch.__version__}, numpy {numpy.__version__}",
    ]
    try:
        import numba  # optional: the renderer runs without it

        lines.append(f"- numba {numba.__version__}")
    except ImportError:
        pass
    lines.append(f"- torch threads: {torch.get_num_threads()}; CUDA: "
                 f"{torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'none'}")
    lines.append(f"- load average (1 / 5 / 15 min) when written: {load_average()}")
    for k, v in (extra or {}).items():
        lines.append(f"- {k}: {v}")
    return "\n".join(lines)
