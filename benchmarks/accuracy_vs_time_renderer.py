"""The renderer part of the accuracy-versus-time study, run by
``python -m benchmarks.accuracy_vs_time --parts renderer`` (``--docs DIR`` to keep docs/ as it is),
which runs ``python -m benchmarks.accuracy_vs_time_renderer [--quick] [--no-cuda]``: on the CPU, and
on CUDA too where its fused kernel runs (a second section), the plots to
``<docs>/study_renderer[_cuda]_<sweep>.png`` and the section to ``<work>/sections/renderer.md`` for
the study's report. Each sweep changes one setting from the default (64^3 grid, 128^2 images, threshold 0.5 pixel
footprint, 256 steps, conservative intersection, all effects) and measures, on one scene (the
demo's torus and sphere, 4 views), the image error against a high-accuracy render of the analytic
shape, the march error and the depth error against a high-accuracy render of the same grid, the
false hits, and the time per frame, forward and forward + backward (medians of this process's CPU
time); ``Renderer.measure`` defines each.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Optional

import torch

import renderer
from benchmarks.common import (Point, cheapest_within, fmt_value, median_times_ms, progress_log, run_study_part,
                               study_folders, study_part_parser, tradeoff_section)
import mvr
from renderer import Cameras, DirectionalLight, SDFGrid, Scene, TraceSettings, render, torus_and_sphere

VIEWS = 4
REFERENCE_THRESHOLD_VOXELS = 1e-4  # the reference's hit threshold, in voxels of its grid
REFERENCE_STEPS = 4000
# The reference's search behind a hit (soft silhouettes) must go as deep as a normal render's:
# with its tiny threshold, the default ``inner_depth`` (in thresholds) would stop it at once.
REFERENCE_INNER_DEPTH_WORLD = 0.2
REFERENCE_INNER_STEPS = 64


@dataclass(frozen=True)
class Config:
    """One renderer setting (grid and image sides, march settings, intersection, effects)."""

    grid: int = 64
    image: int = 128
    threshold_scale: float = 0.5
    max_steps: int = 256
    intersection: str = "conservative"
    effects: tuple[str, ...] = ("silhouette", "depth", "normal", "shading")
    inner_depth: float = 8.0  # TraceSettings.inner_depth, in hit thresholds


DEFAULT = Config()
QUICK_DEFAULT = Config(grid=24, image=24)


@dataclass(frozen=True)
class Sweep:
    """One sweep: what it varies (in words), its configs, and how a config is labelled."""

    what: str
    configs: tuple[Config, ...]
    label: Callable[[Config], str]


def default_config(quick: bool) -> Config:
    """The default setting (toy sizes with ``quick``)."""
    return QUICK_DEFAULT if quick else DEFAULT


def sweeps(quick: bool) -> dict[str, Sweep]:
    """Name -> Sweep, each a one-setting change of the default (the intersection sweep: both
    modes at several thresholds, where the conservative point's error grows)."""
    d = default_config(quick)
    grids = [32, 64, 128, 256] if not quick else [16, 24]
    images = [64, 128, 256, 512] if not quick else [16, 24]
    thresholds = [0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0] if not quick else [0.1, 0.5]
    # A smaller threshold also shortens the search behind hits (inner_depth counts thresholds);
    # these rows keep that search as deep as the default's.
    deep = [s for s in thresholds if s < d.threshold_scale]
    same_depth = [replace(d, threshold_scale=s, inner_depth=d.inner_depth * d.threshold_scale / s) for s in deep]
    steps = [8, 16, 32, 64, 128, 256] if not quick else [8, 256]
    cross = [0.5, 2.0, 4.0] if not quick else [0.5, 4.0]
    effects = [("silhouette",), ("silhouette", "depth"), ("silhouette", "depth", "normal"),
               ("silhouette", "depth", "normal", "shading")]
    if quick:
        effects = effects[::3]

    def threshold_label(c: Config) -> str:
        return f"{c.threshold_scale:g}" + (f" (inner {c.inner_depth:g})" if c.inner_depth != d.inner_depth else "")

    def grid_label(c: Config) -> str:
        return f"{c.grid}^3" + (f" @{c.threshold_scale:g}" if c.threshold_scale != d.threshold_scale else "")

    return {
        "threshold": Sweep("hit threshold (pixel footprints)",
                           (*(replace(d, threshold_scale=s) for s in thresholds), *same_depth), threshold_label),
        "max_steps": Sweep("maximum march steps", tuple(replace(d, max_steps=s) for s in steps),
                           lambda c: f"{c.max_steps}"),
        "intersection": Sweep("intersection mode at several hit thresholds",
                              tuple(replace(d, intersection=m, threshold_scale=s)
                                    for s in cross for m in ("conservative", "exact")),
                              lambda c: f"{c.intersection} @{c.threshold_scale:g}"),
        # At the default threshold the march's error hides the grid's: the finest threshold shows it.
        "grid": Sweep("grid resolution at the default and the finest hit threshold",
                      (*(replace(d, grid=g) for g in grids), *(replace(same_depth[0], grid=g) for g in grids)),
                      grid_label),
        "image": Sweep("image resolution", tuple(replace(d, image=s) for s in images), lambda c: f"{c.image}^2"),
        "effects": Sweep("effects rendered", tuple(replace(d, effects=e) for e in effects),
                         lambda c: "+".join(e[:3] for e in c.effects)),
    }


class Renderer:
    """Measures configs on one scene; caches grids, cameras, references and measurements."""

    def __init__(self, device: str, backend: str, reference_grid: int, reps: int):
        if reference_grid < 4:
            raise ValueError(f"reference_grid must be >= 4, got {reference_grid!r}")
        if reps < 1:
            raise ValueError(f"reps must be >= 1, got {reps!r}")
        self.device, self.backend, self.reps = device, backend, reps
        self.reference_grid = reference_grid
        self._grids: dict[int, SDFGrid] = {}
        self._refs: dict[tuple[int, int], object] = {}
        self._measured: dict[Config, dict] = {}
        self.scene_kw = dict(lights=(DirectionalLight((1.0, 2.0, 1.5), 0.8),), ambient=0.15,
                             albedo=(0.9, 0.75, 0.55), background=(1.0, 1.0, 1.0))

    def grid(self, n: int) -> SDFGrid:
        """The scene sampled on an n^3 grid over [-0.8, 0.8]^3."""
        if n not in self._grids:
            self._grids[n] = SDFGrid.from_function(torus_and_sphere, n, -0.8, 0.8, device=self.device)
        return self._grids[n]

    def cameras(self, size: int) -> Cameras:
        """The 4 views at size^2."""
        eyes = torch.tensor([[0.0, 1.2, 2.6], [2.2, 1.2, 1.2], [-1.5, 2.2, -1.5], [1.0, -1.5, -2.0]])
        return Cameras.look_at(eyes, fov_deg=40, image_size=size, device=self.device)

    def reference(self, grid: int, size: int):
        """A high-accuracy render (RenderOutput) of the n^3 grid at size^2: the exact intersection, a
        1e-4 voxel threshold, many steps, and a search behind hits as deep as a normal render's."""
        key = (grid, size)
        if key not in self._refs:
            g = self.grid(grid)
            threshold = REFERENCE_THRESHOLD_VOXELS * float(g.voxel_size.min())
            settings = TraceSettings(threshold=threshold, max_steps=REFERENCE_STEPS, inner_steps=REFERENCE_INNER_STEPS,
                                     inner_depth=REFERENCE_INNER_DEPTH_WORLD / threshold)
            with torch.no_grad():
                self._refs[key] = render(g, self.cameras(size), Scene(intersection="exact", **self.scene_kw),
                                         settings, backend=self.backend)
        return self._refs[key]

    def measure(self, c: Config) -> dict:
        """Times and errors of one config, measured once per config.

        The image error is the mean absolute difference of the shaded image (of the soft
        silhouette in the effects sweep, the one output every row has) against a high-accuracy
        reference render of the same analytic shape at the same image size (a fine grid, the exact
        intersection, a hit threshold of 1e-4 voxel and many steps). The march error is the same
        against a high-accuracy render of the *same* grid: what the march and the intersection
        settings add on top of the grid's discretisation. The depth error is the median and 90th
        percentile of |depth - reference depth| over the pixels both renders hit (same-grid
        reference, world units): where the conservative hit point ``s + f(s) v`` falls short of the
        surface and the exact one does not. False hits are the fraction of hit pixels that the
        same-grid reference misses (rays that passed within the hit threshold of the surface),
        which no intersection mode can correct. Times per frame, forward and forward + backward
        into the grid values, are medians over repeats of this process's CPU time (with one thread
        it is the wall time on an idle core; the wall time is kept too).
        """
        if c in self._measured:
            return self._measured[c]
        grid = self.grid(c.grid)
        cams = self.cameras(c.image)
        scene = Scene(effects=c.effects, intersection=c.intersection, **self.scene_kw)
        settings = TraceSettings(threshold_scale=c.threshold_scale, max_steps=c.max_steps, inner_depth=c.inner_depth)
        values = grid.values.detach().clone().requires_grad_(True)
        g = SDFGrid(values, grid.bbox_min, grid.bbox_max)

        sync = torch.cuda.synchronize if torch.device(self.device).type == "cuda" else (lambda: None)

        def forward():
            with torch.no_grad():
                out = render(g, cams, scene, settings, backend=self.backend)
            sync()
            return out

        def forward_backward():
            out = render(g, cams, scene, settings, backend=self.backend)
            loss = sum(t.sum() for t in (out.image, out.silhouette, out.depth, out.normal) if t is not None)
            loss.backward()
            values.grad = None
            sync()
            return out

        ms = median_times_ms({"forward": forward, "forward_backward": forward_backward}, self.reps)
        # On a GPU the host's CPU time says nothing: the times are wall times there.
        clock = "_cpu" if torch.device(self.device).type == "cpu" else ""
        m = {  # per frame
            "forward_ms": ms["forward" + clock] / VIEWS, "forward_backward_ms": ms["forward_backward" + clock] / VIEWS,
            "forward_wall_ms": ms["forward"] / VIEWS, "forward_backward_wall_ms": ms["forward_backward"] / VIEWS,
        }
        out = forward()
        fine = self.reference(self.reference_grid, c.image)
        same = self.reference(c.grid, c.image)
        m["silhouette_error"] = _mean_abs(out.silhouette, fine.silhouette)
        m["image_error"] = _mean_abs(out.image, fine.image)
        m["march_error"] = _mean_abs(out.image, same.image) if out.image is not None else _mean_abs(
            out.silhouette, same.silhouette)
        m.update(_hit_errors(out, same))
        m["steps_mean"] = out.trace.steps.float().mean().item()
        self._measured[c] = m
        return m


def _mean_abs(a: Optional[torch.Tensor], b: torch.Tensor) -> float:
    return float("nan") if a is None else (a.detach() - b).abs().mean().item()


def _hit_errors(out, ref) -> dict:
    """Where a render's hits differ from a reference's: the median and 90th percentile of
    |depth - reference depth| over the pixels both hit (world units; nan without depth), and the
    fraction of the render's hits that the reference misses (rays that passed within the hit
    threshold of the surface without meeting it)."""
    both = out.hit & ref.hit
    hits = int(out.hit.sum())
    m = {"false_hits": float((out.hit & ~ref.hit).sum()) / hits if hits else float("nan"),
         "depth_median": float("nan"), "depth_p90": float("nan")}
    if out.depth is not None and bool(both.any()):
        err = (out.depth.detach() - ref.depth).abs()[both].double()
        q = torch.quantile(err, torch.tensor([0.5, 0.9], dtype=err.dtype))
        m["depth_median"], m["depth_p90"] = float(q[0]), float(q[1])
    return m


COLUMNS = (("forward (ms/frame)", "forward_ms"), ("fwd+bwd (ms/frame)", "forward_backward_ms"),
           ("fwd+bwd wall (ms/frame)", "forward_backward_wall_ms"), ("image error", "image_error"),
           ("silhouette error", "silhouette_error"), ("march error", "march_error"),
           ("depth error median", "depth_median"), ("depth error p90", "depth_p90"), ("false hits", "false_hits"),
           ("mean steps", "steps_mean"))


def sweep_points(r: Renderer, name: str, sweep: Sweep, default: Config,
                 log: Callable[[str], None] = progress_log(False)) -> list[Point]:
    """Measures a sweep's configs; a Point per config (seconds: CPU ms per frame, forward +
    backward; error: image error, or silhouette error in the effects sweep)."""
    points = []
    for c in sweep.configs:
        log(f"renderer/{name}: {sweep.label(c)}")
        m = {**r.measure(c), "config": c}
        err = m["silhouette_error"] if name == "effects" else m["image_error"]
        points.append(Point(sweep.label(c), m["forward_backward_ms"], err, default=(c == default), extra=m))
    return points


def threshold_note(points: list[Point], default: Config) -> str:
    """What the threshold sweep says about the finest threshold, with and without the search
    behind hits kept as deep as the default's."""
    configs = [p.extra["config"] for p in points]
    finest = min(c.threshold_scale for c in configs)
    pick = {(c.threshold_scale, c.inner_depth != default.inner_depth): p.extra for c, p in zip(configs, points)}
    d, plain, deep = pick.get((default.threshold_scale, False)), pick.get((finest, False)), pick.get((finest, True))
    if d is None or plain is None or deep is None:
        return ""
    inner = deep["config"].inner_depth
    text = (f"At {finest:g} pixel footprints the image error is {fmt_value(plain['image_error'])} against "
            f"{fmt_value(d['image_error'])} at the default {default.threshold_scale:g}, and forward + backward takes "
            f"{fmt_value(plain['forward_backward_ms'])} ms against {fmt_value(d['forward_backward_ms'])} ms (the "
            f"fused march takes {fmt_value(plain['steps_mean'])} samples per ray on average against "
            f"{fmt_value(d['steps_mean'])}). `TraceSettings.inner_depth`, how deep the search behind a hit goes "
            f"for the soft silhouette, counts thresholds: the silhouette error is "
            f"{fmt_value(plain['silhouette_error'])} with it left at {default.inner_depth:g} and "
            f"{fmt_value(deep['silhouette_error'])} with it raised to {inner:g} (the rows marked *inner*), against "
            f"{fmt_value(d['silhouette_error'])} at the default threshold.")
    if plain["silhouette_error"] > 1.5 * deep["silhouette_error"]:
        text += (" Left alone, the soft silhouettes of hit pixels no longer saturate: a smaller threshold wants "
                 "`inner_depth` raised in proportion.")
    return text + "\n"


def intersection_note(points: list[Point]) -> str:
    """The exact-versus-conservative discussion, with the intersection sweep's numbers (each
    point's ``extra["config"]`` says its mode and threshold)."""
    by = {(p.extra["config"].intersection, p.extra["config"].threshold_scale): p.extra for p in points}
    rows = ["| threshold | depth error median (cons. / exact) | depth error p90 | march error (image) | false hits "
            "| forward ms/frame | fwd+bwd ms/frame |", "|---|---|---|---|---|---|---|"]
    for thr in dict.fromkeys(k[1] for k in by):
        c, e = by.get(("conservative", thr)), by.get(("exact", thr))
        if c is None or e is None:
            continue

        def pair(key: str, ratio: bool = False) -> str:
            text = f"{fmt_value(c[key])} / {fmt_value(e[key])}"
            return text + (f" ({e[key] / c[key]:.1f}x)" if ratio else "")

        cells = [pair("depth_median"), pair("depth_p90"), pair("march_error"), pair("false_hits"),
                 pair("forward_ms", True), pair("forward_backward_ms", True)]
        rows.append(f"| {thr:g} | " + " | ".join(cells) + " |")
    return "\n".join([
        "#### Exact against conservative intersection",
        "",
        "The paper's hit point ``p = s + f(s) v`` stops short of the surface by up to the hit threshold times "
        "``1/cos - 1`` (cos between the ray and the normal), so its error grows with the threshold and at grazing "
        "hits; the exact mode (renderer/exact.py) finds the root of the trilinear SDF along the ray by bracketing "
        "and bisection and differentiates it implicitly. Against a high-accuracy render of the same grid "
        "(conservative / exact):",
        "",
        *rows,
        "",
        "Where it is more accurate: the depth (and the hit point the normals and shading are evaluated at) of "
        "true hits, most at large thresholds and grazing angles (the 90th percentile). Where it is not: the "
        "*false hits*, rays that passed within the threshold of the surface without crossing it, near "
        "silhouettes, are the same in both modes (the exact mode falls back to the conservative point where it "
        "finds no sign change) and in this scene they dominate the image error, so the image improves far less "
        "than the depth. "
        "What it costs: the bracketing and 30 bisection steps are plain PyTorch over all hit pixels (the march "
        "itself is the fused kernel), hence the forward-time ratio above. A smaller threshold (the threshold "
        "sweep, with `inner_depth` raised to match) shrinks both errors at once.",
        "",
    ])


def run(out_dir: Path, quick: bool = False, device: str = "cpu", backend: str = "auto", reps: int = 5,
        progress: bool = True, prefix: Optional[str] = None) -> str:
    """Runs every renderer sweep; writes one plot per sweep into ``out_dir`` as
    ``<prefix>_<sweep>.png`` (prefix: ``study_renderer``, ``study_renderer_cuda`` on a GPU);
    returns the report's markdown section (plots linked by file name)."""
    on_gpu = torch.device(device).type == "cuda"
    prefix = prefix or ("study_renderer_cuda" if on_gpu else "study_renderer")
    clock = "wall" if on_gpu else "CPU"
    r = Renderer(device, backend, reference_grid=256 if not quick else 32, reps=reps if not quick else 1)
    default = default_config(quick)
    log = progress_log(progress)
    parts = [
        f"## Renderer{' (CUDA)' if on_gpu else ''}\n",
        f"Scene: the demo's torus and sphere (analytic SDF sampled on the grid over [-0.8, 0.8]^3), "
        f"{VIEWS} views of 40 degrees, device `{device}`, backend `{backend}`, one directional light. Each sweep "
        f"changes one setting of the default ({default.grid}^3 grid, {default.image}^2 images, threshold "
        f"{default.threshold_scale:g} pixel footprint, {default.max_steps} steps, {default.intersection} "
        f"intersection, all effects). *Image error*: mean absolute difference of the shaded image against a "
        f"{r.reference_grid}^3 grid rendered with the exact intersection, a 1e-4 voxel threshold and "
        f"{REFERENCE_STEPS} steps, at the same image size; *march error*: the same against such a render of the "
        f"same grid (what the march adds to the grid's discretisation; of the silhouette where no image is "
        f"rendered); *depth error*: median and 90th "
        f"percentile of |depth difference| (world units; the scene is 1.6 across, a voxel of the default grid "
        f"{1.6 / (default.grid - 1):.3g}) on pixels hit by both, against the same-grid reference; *false hits*: "
        f"the fraction of hit pixels that the same-grid reference misses. Times: {clock} milliseconds per frame "
        f"(a batch "
        f"of {VIEWS} views / {VIEWS}), medians of {r.reps} runs after a warm-up; forward without autograd, "
        f"forward + backward into the grid values; the plots use forward + backward.\n",
    ]
    glance = ["### At a glance", "",
              f"How far each setting moves the error and the time (forward + backward, {clock} ms per frame) over "
              "its sweep, and the cheapest setting within 10 % of the sweep's lowest error:", "",
              "| sweep | error: lowest .. highest | time: fastest .. slowest | cheapest within 10 % (error, ms) |",
              "|---|---|---|---|"]
    parts.append("")  # the glance table goes here once every sweep has run
    at = len(parts) - 1
    for name, sweep in sweeps(quick).items():
        points = sweep_points(r, name, sweep, default, log)
        errs, times = [p.error for p in points], [p.seconds for p in points]
        _, good = cheapest_within(points)
        glance.append(f"| {sweep.what} | {fmt_value(min(errs))} .. {fmt_value(max(errs))} | {fmt_value(min(times))} .. "
                      f"{fmt_value(max(times))} | {good.label} ({fmt_value(good.error)}, {fmt_value(good.seconds)}) |")
        ylabel = "mean abs silhouette error" if name == "effects" else "mean abs image error"
        parts.append(tradeoff_section(
            points, COLUMNS, out_dir / f"{prefix}_{name}.png", title=f"{sweep.what[0].upper()}{sweep.what[1:]}",
            setting_name=sweep.what, xlabel=f"forward + backward, {clock} ms per frame", ylabel=ylabel, unit="ms",
            error_name=ylabel.replace("mean abs ", "")))
        if name == "intersection":
            parts.append(intersection_note(points))
        if name == "threshold":
            parts.append(threshold_note(points, default))
    parts[at] = "\n".join([*glance, "", "(The effects sweep's error is the silhouette's, which every effect "
                           "shares: it shows what each pass costs.)", ""])
    return "\n".join(parts)


def devices(cuda: bool = True) -> tuple[str, ...]:
    """The part's devices: the CPU, and CUDA where ``cuda`` and its fused kernel runs."""
    if not cuda:
        return ("cpu",)

    return ("cpu", "cuda") if renderer.backend_available("cuda")[0] else ("cpu",)


def main(argv: Optional[list[str]] = None) -> None:
    ap = study_part_parser(__doc__)
    ap.add_argument("--no-cuda", action="store_true",
                    help="on the CPU only (default: also on CUDA where its kernel runs)")
    args = ap.parse_args(argv)
    docs, work = study_folders(args.quick, args.docs, args.work)
    mvr.configure_runtime(threads=args.threads)
    run_study_part("renderer", lambda: "\n".join(run(docs, quick=args.quick, device=d, progress=not args.no_progress)
                                                 for d in devices(not args.no_cuda)), work, args.quick)


if __name__ == "__main__":
    main()
