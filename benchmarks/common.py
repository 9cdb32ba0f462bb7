"""What several benchmarks share, the one module of benchmarks/ that the others import (each
benchmark is a leaf: it imports the library packages and this module, never another benchmark;
tests/benchmarks/test_leaves.py checks it): Pareto fronts, plots, tables and a reading of the
results; machine info and timing; peak memory of this process; bootstrap intervals; the procedural
presets' data and their lookup ceiling; the sections of the accuracy-versus-time study."""
from __future__ import annotations

import argparse
import datetime
import io
import json
import math
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np
import torch
from hydra.utils import instantiate

from sdfcommon.tooling.commands import compose
from sdfcommon.tooling.outputs import atomic_write, write_text

ROOT = Path(__file__).resolve().parents[1]


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


@dataclass(frozen=True)
class Setting:
    """One run of a study: its label and its hydra overrides (of configs/mvr.yaml, say), and whether
    it is the default setting."""

    label: str
    overrides: tuple[str, ...] = ()
    default: bool = False


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


def median_times_ms(fns: dict, repeats: int) -> dict[str, float]:
    """Median wall time and CPU time (ms) of each function: ``name`` and ``name_cpu``.

    One warm-up each (compiles or loads the kernels, fills the allocator), then the functions take
    turns so that a change of the machine's load hits all of them alike. CPU time is this
    process's user + system time over all its threads (torch's and numba's).
    """
    for fn in fns.values():
        fn()
    wall: dict[str, list[float]] = {name: [] for name in fns}
    cpu: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            start, start_cpu = time.perf_counter(), time.process_time()
            fn()
            wall[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
    out = {name: 1e3 * statistics.median(t) for name, t in wall.items()}
    out.update({f"{name}_cpu": 1e3 * statistics.median(t) for name, t in cpu.items()})
    return out


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
        f"- python {platform.python_version()}, torch {torch.__version__}, numpy {np.__version__}",
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


# ---------------------------------------------------------------------------- peak memory (Linux)
def _status_kib(field: str) -> Optional[int]:
    """A field of /proc/self/status in KiB (``VmRSS``, ``VmHWM``), or None where it is not there."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def reset_peak_rss() -> Optional[int]:
    """Resets this process's peak resident set (VmHWM) to its resident set now, through
    /proc/self/clear_refs; returns that resident set (KiB), or None where this is not available
    (then ``peak_rss_kib`` measures nothing)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return None
    return _status_kib("VmRSS")


def peak_rss_kib() -> Optional[int]:
    """This process's peak resident set (KiB) since ``reset_peak_rss`` (VmHWM), or None where unknown."""
    return _status_kib("VmHWM")


# ---------------------------------------------------------------------------- bootstrap intervals
def bootstrap_means(values: np.ndarray, category: np.ndarray, samples: int = 2000,
                    seed: int = 0) -> tuple[dict[int, tuple[float, float]], tuple[float, float]]:
    """95% percentile bootstrap intervals over objects: per category of its mean, and of the
    benchmark's mean over categories (objects resampled within each category, so every draw keeps
    the categories' sizes).

    Args:
        values: (N,) per-object scores. category: (N,) int category of each object.
    Returns:
        ({category: (lo, hi)}, (lo, hi) of the mean over categories).
    """
    values = np.asarray(values, dtype=np.float64)
    category = np.asarray(category)
    if values.shape != category.shape or values.ndim != 1 or not len(values):
        raise ValueError(f"values and category must be equal non-empty 1-D arrays, got {values.shape} "
                         f"and {category.shape}")
    rng = np.random.default_rng(seed)
    per_cat, draws = {}, []
    for c in np.unique(category):
        v = values[category == c]
        means = v[rng.integers(len(v), size=(samples, len(v)))].mean(1)
        per_cat[int(c)] = (float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5)))
        draws.append(means)
    overall = np.mean(draws, axis=0)
    return per_cat, (float(np.percentile(overall, 2.5)), float(np.percentile(overall, 97.5)))


def bootstrap_interval(values: np.ndarray, samples: int = 2000, seed: int = 0) -> tuple[float, float]:
    """The 95% percentile bootstrap interval of the mean of ``values`` (N,): ``bootstrap_means``
    with one category."""
    values = np.asarray(values, dtype=np.float64)
    return bootstrap_means(values, np.zeros(values.shape, dtype=np.int64), samples, seed)[1]


# ---------------------------------------------------------------------------- procedural presets
DATA_PRESETS = {"demo": "procedural", "bench": "procedural_bench"}  # configs/data/<name>.yaml of each preset


def procedural_data(preset: str, overrides: Sequence[str] = ()):
    """The data module of a procedural preset (``data=DATA_PRESETS[preset]`` composed through
    configs/eval.yaml with ``overrides``), its data generated first where the cache lacks it."""
    dm = instantiate(compose("eval", [f"data={DATA_PRESETS[preset]}", *overrides]).data)
    dm.prepare_data()
    return dm


def all_voxels(dataset) -> np.ndarray:
    """Every object's voxels of a split: (N, R, R, R) bool."""
    return np.stack([dataset.voxels(g).numpy() for g in range(len(dataset))])


def iou_matrix(a: np.ndarray, b: np.ndarray, chunk: int = 512) -> np.ndarray:
    """Voxel IoU of every pair: (Q, ...) bool and (N, ...) bool -> (Q, N) float64 (1 where both are
    empty)."""
    fa = torch.from_numpy(np.ascontiguousarray(a, dtype=bool).reshape(len(a), -1)).float()
    fb = torch.from_numpy(np.ascontiguousarray(b, dtype=bool).reshape(len(b), -1)).float()
    if fa.shape[1] != fb.shape[1]:
        raise ValueError(f"a and b must hold grids of one size, got {fa.shape[1]} and {fb.shape[1]} cells")
    nb = fb.sum(1)
    out = np.empty((len(fa), len(fb)))
    for s in range(0, len(fa), chunk):
        q = fa[s:s + chunk]
        inter = q @ fb.T
        union = q.sum(1, keepdim=True) + nb[None, :] - inter
        out[s:s + chunk] = torch.where(union > 0, inter / union.clamp(min=1), torch.ones_like(inter)).double().numpy()
    return out


def lookup_ceiling(test: np.ndarray, train: np.ndarray) -> np.ndarray:
    """Per test object, the highest voxel IoU of any training object: (Q,) float64 (the best any
    lookup of training shapes can score)."""
    return iou_matrix(test, train).max(1)


# ---------------------------------------------------------------------------- the accuracy-versus-time study
# benchmarks/accuracy_vs_time.py runs each part, ``python -m benchmarks.accuracy_vs_time_<part>``, in
# a process of its own; a part keeps its section under ``<work>/sections`` and the report is
# assembled from there.
SECTIONS = "sections"


@dataclass(frozen=True)
class StudySection:
    """One part's section of the study's report and how its run went: the markdown (kept as
    ``<work>/sections/<part>.md``) and the rest (``<part>.json``): when it finished, its wall and
    CPU seconds, the load average (``load_average``) before and after, and whether it was a
    ``--quick`` run."""

    markdown: str
    finished: str
    wall_s: float
    cpu_s: float
    load_before: str
    load_after: str
    quick: bool

    def write(self, work: Path, part: str) -> None:
        """Keeps the section under ``work/sections`` (atomically)."""
        record = asdict(self)
        atomic_write_text(work / SECTIONS / f"{part}.md", record.pop("markdown"))
        atomic_write_text(work / SECTIONS / f"{part}.json", json.dumps(record, indent=2) + "\n")

    @classmethod
    def read(cls, work: Path, part: str) -> Optional[StudySection]:
        """The section kept under ``work/sections``, or None where the part has not run."""
        md, meta = work / SECTIONS / f"{part}.md", work / SECTIONS / f"{part}.json"
        if not (md.is_file() and meta.is_file()):
            return None
        m = json.loads(meta.read_text())
        return cls(md.read_text(), m["finished"], m["wall_s"], m["cpu_s"], m["load_before"], m["load_after"],
                   bool(m.get("quick")))


def run_study_part(part: str, make: Callable[[], str], work: Path, quick: bool) -> StudySection:
    """Runs one part (``make`` returns its markdown section), timed (``timed``), and keeps its
    section under ``work``."""
    load_before = load_average()
    t = timed(make)
    section = StudySection(t.result, datetime.datetime.now().isoformat(timespec="seconds"), t.wall, t.cpu,
                           load_before, load_average(), quick)
    section.write(work, part)
    return section


def study_folders(quick: bool, docs: Optional[Path] = None, work: Optional[Path] = None) -> tuple[Path, Path]:
    """The study's (docs, work) folders: those given, else docs/ and outputs/study/work, or with
    ``quick`` outputs/study_quick and outputs/study_quick/work (a toy run never replaces the report)."""
    return (docs or ROOT / ("outputs/study_quick" if quick else "docs"),
            work or ROOT / ("outputs/study_quick/work" if quick else "outputs/study/work"))


def study_part_parser(description: str) -> argparse.ArgumentParser:
    """The command line that every part of the study shares (the aggregator passes it on)."""
    ap = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="toy sizes: checks the code paths")
    ap.add_argument("--docs", type=Path, default=None,
                    help="where the plots go (default: docs; with --quick: outputs/study_quick)")
    ap.add_argument("--work", type=Path, default=None,
                    help="run folders and the kept section (default: outputs/study[_quick]/work)")
    ap.add_argument("--threads", type=int, default=1, help="torch and numba threads (default 1)")
    ap.add_argument("--no-progress", action="store_true", help="no progress lines")
    return ap


def parse_steps(text: Optional[str]) -> Optional[tuple[int, int]]:
    """``"150,50"`` -> (150, 50): (coarse, refine) training steps; None stays None."""
    if text is None:
        return None
    try:
        coarse, refine = (int(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"steps must be two integers 'coarse,refine', got {text!r}") from None
    if coarse < 1 or refine < 1:
        raise ValueError(f"steps must be positive, got {text!r}")
    return coarse, refine
