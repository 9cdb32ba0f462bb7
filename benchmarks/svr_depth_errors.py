"""Where a single-view network's output is wrong in depth, run as ``python -m benchmarks.svr_depth_errors
CKPT [--preset demo|bench] [--split test] [--every 2] [--calibrated] [--out FILE.md]``: every
``--every``-th object of a procedural split is predicted from view ``index mod 24`` and its direct
occupancy (the SDF below 0 at the NMR voxel centres) compared with the object's voxels. False
positives are split into those hidden behind the input silhouette (inside the input view's cone:
the image cannot show they are wrong), and of them those outside the visual hull of the object's
24 views (what its own images could carve), and those visible outside the cone; false negatives
into inside and outside the cone; beside them the silhouette area (prediction / truth) and IoU from
the input view and the two side views (``svr.nmr.side_views``), at 64^2. Counts are per true solid
voxel, pooled over a category's objects, then averaged over the categories; the raw output unless
``--calibrated``. Reads only what the split holds: images, cameras, voxels."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np
import torch

from benchmarks.common import DATA_PRESETS, atomic_write_text, machine_info, procedural_data
from svr.inference.prediction import load_model, predict_sdf
from svr.nmr.cones import silhouette_cone_sdf
from svr.nmr.format import NUM_VIEWS
from svr.nmr.side_views import render_silhouettes, side_views
from svr.nmr.voxels import sdf_at_voxel_centres

COUNTS = ("truth", "fp_hidden", "fp_hidden_outside_hull", "fp_visible", "fn_inside", "fn_outside",
          "input_pred", "input_true", "input_inter", "input_union", "side_pred", "side_true", "side_inter", "side_union")
COLUMNS = (("fp_hidden", "false positives hidden behind the input silhouette"),
           ("fp_hidden_outside_hull", "of which outside the 24-view visual hull"),
           ("fp_visible", "false positives visible in the input view"),
           ("fn_inside", "false negatives inside the input cone"),
           ("fn_outside", "false negatives outside it"),
           ("input_area", "input view: area / truth"),
           ("input_iou", "input view: IoU"),
           ("side_area", "side views: area / truth"),
           ("side_iou", "side views: IoU"))


def object_counts(occupied: torch.Tensor, truth: torch.Tensor, input_cone: torch.Tensor, hull: torch.Tensor,
                  silhouettes: torch.Tensor, alpha: torch.Tensor) -> dict[str, int]:
    """The counts of one prediction.

    Args:
        occupied, truth: (R, R, R) bool, the prediction's and the object's solid voxels.
        input_cone: (R, R, R) bool, the voxel centres inside the input view's silhouette cone.
        hull: (R, R, R) bool, those inside the visual hull of all the object's views.
        silhouettes: (3, S, S) bool, the prediction seen from the input view and the two side views.
        alpha: (3, S, S) bool, the stored silhouettes of the same views.
    Returns:
        {name: count} for every name of ``COUNTS``.
    """
    for name, t in (("truth", truth), ("input_cone", input_cone), ("hull", hull)):
        if t.shape != occupied.shape:
            raise ValueError(f"{name} has shape {tuple(t.shape)}, occupied {tuple(occupied.shape)}")
    if silhouettes.shape != alpha.shape or silhouettes.shape[0] != 3:
        raise ValueError(f"silhouettes {tuple(silhouettes.shape)} and alpha {tuple(alpha.shape)} must both be (3, S, S)")
    fp, fn = occupied & ~truth, truth & ~occupied
    s, a = silhouettes.bool(), alpha.bool()
    return {
        "truth": int(truth.sum()), "fp_hidden": int((fp & input_cone).sum()),
        "fp_hidden_outside_hull": int((fp & input_cone & ~hull).sum()), "fp_visible": int((fp & ~input_cone).sum()),
        "fn_inside": int((fn & input_cone).sum()), "fn_outside": int((fn & ~input_cone).sum()),
        "input_pred": int(s[0].sum()), "input_true": int(a[0].sum()), "input_inter": int((s[0] & a[0]).sum()),
        "input_union": int((s[0] | a[0]).sum()), "side_pred": int(s[1:].sum()), "side_true": int(a[1:].sum()),
        "side_inter": int((s[1:] & a[1:]).sum()), "side_union": int((s[1:] | a[1:]).sum()),
    }


def rates(counts: dict[str, int]) -> dict[str, float]:
    """Pooled counts -> the figures of ``COLUMNS`` (voxel counts per true solid voxel)."""
    truth = max(counts["truth"], 1)
    out = {k: counts[k] / truth for k in ("fp_hidden", "fp_hidden_outside_hull", "fp_visible", "fn_inside", "fn_outside")}
    for view in ("input", "side"):
        out[f"{view}_area"] = counts[f"{view}_pred"] / max(counts[f"{view}_true"], 1)
        out[f"{view}_iou"] = counts[f"{view}_inter"] / max(counts[f"{view}_union"], 1)
    return out


def depth_errors(predict: Callable[[torch.Tensor, int], torch.Tensor], objects, half_side: float, resolution: int,
                 every: int = 2, progress: bool = True) -> dict:
    """Every figure of the module docstring.

    Args:
        predict: (1, 4, 64, 64) RGBA in [0, 1] and its NMR view -> (1, N, N, N) SDF over
            ``[-half_side, half_side]^3`` (``model_predictor``).
        objects: a split's per-object dataset (``NMRDataset``: ``images_uint8``, ``voxels``,
            ``category_of``, ``categories``).
        resolution: N. every: score every this many objects.
    Returns:
        {"categories": {name: {column: value}}, "mean": {column: value}, "objects": count}.
    """
    if every < 1:
        raise ValueError(f"every must be a positive integer, got {every}")
    names = [name for _, name in objects.categories]
    pooled = {name: dict.fromkeys(COUNTS, 0) for name in names}
    scored = range(0, len(objects), every)
    n = int(resolution)
    for k, obj in enumerate(scored):
        view = obj % NUM_VIEWS
        images = torch.from_numpy(np.asarray(objects.images_uint8(obj, list(range(NUM_VIEWS))))).float() / 255.0
        sdf = predict(images[view:view + 1], view).float().cpu()
        truth = torch.as_tensor(objects.voxels(obj)).bool()
        r = int(truth.shape[-1])
        occ, _ = sdf_at_voxel_centres(sdf, -half_side, half_side, r)
        cones = silhouette_cone_sdf(images[:, 3], torch.arange(NUM_VIEWS, dtype=torch.float64), n, half_side)
        cones, _ = sdf_at_voxel_centres(cones.reshape(NUM_VIEWS, n, n, n), -half_side, half_side, r)
        shown = torch.cat([torch.tensor([view]), side_views(torch.tensor([view]))[0]])
        counts = object_counts(occ[0] < 0, truth, cones[view] < 0, cones.amax(0) < 0,
                               render_silhouettes(sdf, half_side, shown[None])[0], images[shown, 3] >= 0.5)
        cat = pooled[names[objects.category_of(obj)]]
        for key, value in counts.items():
            cat[key] += value
        if progress and (k + 1) % 10 == 0:
            print(f"  {k + 1}/{len(scored)} objects", file=sys.stderr, flush=True)
    per_cat = {name: rates(c) for name, c in pooled.items() if c["truth"] > 0}
    mean = {key: float(np.mean([v[key] for v in per_cat.values()])) for key, _ in COLUMNS}
    return {"objects": len(scored), "categories": per_cat, "mean": mean}


def model_predictor(model, calibrated: bool = False) -> Callable[[torch.Tensor, int], torch.Tensor]:
    """``depth_errors``'s ``predict`` for a loaded checkpoint (``load_model``): its final SDF, raw
    unless ``calibrated``."""
    def predict(image: torch.Tensor, view: int) -> torch.Tensor:
        return predict_sdf(model, image, views=torch.tensor([float(view)]), calibrated=calibrated).final
    return predict


def markdown(result: dict, command: str) -> str:
    head = "| category | " + " | ".join(label for _, label in COLUMNS) + " |"
    rows = [head, "|---|" + "---:|" * len(COLUMNS)]
    for name, r in [*result["categories"].items(), ("**mean**", result["mean"])]:
        rows.append(f"| {name} | " + " | ".join(f"{r[key]:.3f}" for key, _ in COLUMNS) + " |")
    return "\n".join([
        "# Where the single-view output is wrong in depth", "",
        f"Command: `{command}`.", "", machine_info(), "",
        f"Checkpoint `{result['checkpoint']}`, {'calibrated' if result['calibrated'] else 'raw'} output; "
        f"{result['split']} split of the {result['preset']} preset, {result['objects']} objects (every "
        f"{result['every']}), each from view (object index mod 24). Voxel counts are per true solid voxel "
        "(the SDF below 0 at the NMR voxel centres against the object's voxels); silhouettes at 64^2.", "",
        *rows, ""])


def main(argv: Optional[Sequence[str]] = None) -> int:
    doc = (__doc__ or "").strip().split(": every")[0]
    parser = argparse.ArgumentParser(prog="python -m benchmarks.svr_depth_errors", description=doc)
    parser.add_argument("ckpt", type=Path, help="a single-view checkpoint")
    parser.add_argument("--preset", choices=sorted(DATA_PRESETS), default="demo", help="procedural data preset")
    parser.add_argument("--split", choices=("train", "val", "test"), default="test")
    parser.add_argument("--every", type=int, default=2, help="score every N-th object")
    parser.add_argument("--calibrated", action="store_true", help="apply the checkpoint's calibration")
    parser.add_argument("--out", type=Path, default=None, help="write the table here (.md) and the figures beside it (.json)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    if not args.ckpt.is_file():
        parser.error(f"ckpt: no such file: {args.ckpt}")
    if args.every < 1:
        parser.error(f"--every must be a positive integer, got {args.every}")
    if args.out is not None and args.out.suffix != ".md":
        parser.error(f"--out must name a .md file, got {args.out}")
    model = load_model(args.ckpt, "cpu")
    objects = procedural_data(args.preset).dataset(args.split)
    result = {"checkpoint": str(args.ckpt), "preset": args.preset, "split": args.split, "every": args.every,
              "calibrated": args.calibrated,
              **depth_errors(model_predictor(model, args.calibrated), objects, model.half_side, model.grid_resolution,
                             args.every, progress=not args.quiet)}
    command = "python -m benchmarks.svr_depth_errors " + " ".join(sys.argv[1:] if argv is None else argv)
    text = markdown(result, command)
    print(text)
    if args.out is not None:
        atomic_write_text(args.out, text)
        atomic_write_text(args.out.with_suffix(".json"), json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
