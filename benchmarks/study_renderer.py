"""The renderer part of the accuracy-versus-time study.

Each sweep changes one setting from the default (64^3 grid, 128^2 images, threshold 0.5 pixel
footprint, 256 steps, conservative intersection, all effects) and measures, on the same scene:

* error: mean absolute difference of the shaded image (and of the silhouette) against a
  high-accuracy reference render of the same analytic shape at the same image size (a fine grid,
  exact intersection, a threshold of 1e-4 voxel, many steps);
* time per frame: forward, and forward + backward (median of several runs).

Run through benchmarks/study.py (the report) or alone: ``python benchmarks/study_renderer.py --quick``.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.report import Point, markdown_table, plot_tradeoff  # noqa: E402
from renderer import Cameras, DirectionalLight, SDFGrid, Scene, TraceSettings, render  # noqa: E402
from renderer.demo import torus_and_sphere  # noqa: E402


@dataclass(frozen=True)
class Config:
    grid: int = 64
    image: int = 128
    threshold_scale: float = 0.5
    max_steps: int = 256
    intersection: str = "conservative"
    effects: tuple[str, ...] = ("silhouette", "depth", "normal", "shading")


DEFAULT = Config()


def sweeps(quick: bool) -> dict[str, tuple[str, list[Config]]]:
    """Name -> (the setting varied, the configs), each a one-setting change of the default."""
    d = DEFAULT if not quick else Config(grid=24, image=24)
    grids = [32, 64, 128, 256] if not quick else [16, 24]
    images = [64, 128, 256, 512] if not quick else [16, 24]
    effects = [("silhouette",), ("silhouette", "depth"), ("silhouette", "depth", "normal"),
               ("silhouette", "depth", "normal", "shading")]
    return {
        "threshold": ("hit threshold (pixel footprints)",
                      [replace(d, threshold_scale=s) for s in ([0.05, 0.1, 0.25, 0.5, 1.0, 2.0] if not quick else [0.1, 0.5])]),
        "max_steps": ("maximum march steps",
                      [replace(d, max_steps=s) for s in ([8, 16, 32, 64, 128, 256] if not quick else [8, 256])]),
        "intersection": ("intersection mode", [replace(d, intersection=m) for m in ("conservative", "exact")]),
        "grid": ("grid resolution", [replace(d, grid=g) for g in grids]),
        "image": ("image resolution", [replace(d, image=s) for s in images]),
        "effects": ("effects rendered", [replace(d, effects=e) for e in (effects if not quick else effects[::3])]),
    }


def _label(name: str, c: Config) -> str:
    return {
        "threshold": f"{c.threshold_scale:g}",
        "max_steps": f"{c.max_steps}",
        "intersection": c.intersection,
        "grid": f"{c.grid}^3",
        "image": f"{c.image}^2",
        "effects": "+".join(e[:3] for e in c.effects),
    }[name]


class Renderer:
    """Caches grids, cameras and reference renders across configs."""

    def __init__(self, device: str, backend: str, reference_grid: int, reps: int):
        self.device, self.backend, self.reps = device, backend, reps
        self.reference_grid = reference_grid
        self._grids: dict[int, SDFGrid] = {}
        self._refs: dict[int, torch.Tensor] = {}
        self.scene_kw = dict(lights=(DirectionalLight((1.0, 2.0, 1.5), 0.8),), ambient=0.15,
                             albedo=(0.9, 0.75, 0.55), background=(1.0, 1.0, 1.0))

    def grid(self, n: int) -> SDFGrid:
        if n not in self._grids:
            self._grids[n] = SDFGrid.from_function(torus_and_sphere, n, -0.8, 0.8, device=self.device)
        return self._grids[n]

    def cameras(self, size: int) -> Cameras:
        eyes = torch.tensor([[0.0, 1.2, 2.6], [2.2, 1.2, 1.2], [-1.5, 2.2, -1.5], [1.0, -1.5, -2.0]])
        return Cameras.look_at(eyes, fov_deg=40, image_size=size, device=self.device)

    def reference(self, size: int) -> tuple[torch.Tensor, torch.Tensor]:
        if size not in self._refs:
            g = self.grid(self.reference_grid)
            h = float(g.voxel_size.min())
            with torch.no_grad():
                out = render(g, self.cameras(size), Scene(intersection="exact", **self.scene_kw),
                             TraceSettings(threshold=1e-4 * h, max_steps=4000), backend=self.backend)
            self._refs[size] = (out.image, out.silhouette)
        return self._refs[size]

    def measure(self, c: Config) -> dict:
        grid = self.grid(c.grid)
        cams = self.cameras(c.image)
        scene = Scene(effects=c.effects, intersection=c.intersection, **self.scene_kw)
        settings = TraceSettings(threshold_scale=c.threshold_scale, max_steps=c.max_steps)
        values = grid.values.detach().clone().requires_grad_(True)
        g = SDFGrid(values, grid.bbox_min, grid.bbox_max)

        def forward():
            return render(g, cams, scene, settings, backend=self.backend)

        def forward_backward():
            out = forward()
            loss = sum(t.sum() for t in (out.image, out.silhouette, out.depth, out.normal) if t is not None)
            loss.backward()
            return out

        out = forward_backward()
        fwd = _median_time(forward, self.reps)
        fwdbwd = _median_time(forward_backward, self.reps)
        ref_img, ref_sil = self.reference(c.image)
        sil_err = (out.silhouette.detach() - ref_sil).abs().mean().item()
        img_err = (out.image.detach() - ref_img).abs().mean().item() if out.image is not None else float("nan")
        return {"forward_s": fwd, "forward_backward_s": fwdbwd, "image_error": img_err, "silhouette_error": sil_err,
                "steps_mean": out.trace.steps.float().mean().item()}


def _median_time(fn, reps: int) -> float:
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def run(out_dir: Path, quick: bool = False, device: str = "cpu", backend: str = "auto", reps: int = 5,
        progress: bool = True) -> str:
    """Runs every renderer sweep; writes one plot per sweep into out_dir; returns the markdown."""
    r = Renderer(device, backend, reference_grid=256 if not quick else 32, reps=reps if not quick else 1)
    parts = [
        "## Renderer\n",
        f"Scene: the demo's torus and sphere (analytic SDF sampled on the grid over [-0.8, 0.8]^3), "
        f"4 views, device `{device}`, backend `{backend}`. Error: mean absolute difference against a "
        f"{r.reference_grid}^3 grid rendered with the exact intersection, a 1e-4 voxel threshold and 4000 "
        f"steps, at the same image size. Times are medians of {r.reps} runs per frame batch of 4 views.\n",
    ]
    for name, (what, configs) in sweeps(quick).items():
        points = []
        for c in configs:
            if progress:
                print(f"  renderer/{name}: {_label(name, c)}", file=sys.stderr, flush=True)
            m = r.measure(c)
            # The effects sweep compares costs on the one output every row has: the silhouette.
            err = m["silhouette_error"] if name == "effects" else m["image_error"]
            points.append(Point(_label(name, c), m["forward_backward_s"], err,
                                default=(c == (DEFAULT if not quick else Config(grid=24, image=24))), extra=m))
        png = out_dir / f"accuracy_vs_time_renderer_{name}.png"
        plot_tradeoff(points, png, f"Renderer: {what}", "forward + backward time per batch (s)",
                      "mean abs silhouette error" if name == "effects" else "mean abs image error")
        cols = [("forward (s)", "forward_s"), ("forward+backward (s)", "forward_backward_s"),
                ("image error", "image_error"), ("silhouette error", "silhouette_error"),
                ("mean steps", "steps_mean")]
        parts.append(f"### {what}\n\n{markdown_table(points, cols, what)}\n\n![{name}]({png.name})\n")
    return "\n".join(parts)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="docs", help="folder for the plots and the markdown")
    ap.add_argument("--quick", action="store_true", help="toy sizes (seconds), for checking the code path")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--backend", default="auto")
    args = ap.parse_args(argv)
    print(run(Path(args.out), args.quick, args.device, args.backend))


if __name__ == "__main__":
    main()
