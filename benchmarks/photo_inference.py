"""Single-view reconstruction of photos whose camera nobody gives, run as ``python -m
benchmarks.photo_inference --ckpt RUN/joint/checkpoints/best.ckpt [--preset demo] [--views 4]``
(issue 43, point 5). Each test object is seen from ``--views`` random NMR views, or with
``--random-views`` from random cameras (any azimuth, elevation 10 to 50 degrees: rendered from its
exact shape as the dataset's views were); each render becomes a photo: scaled by 0.8 to 1.2 (from
twice its size), placed up to 10% of the image off centre on a 240^2 white canvas, saved as a JPEG
with no alpha. ``svr.infer``'s own steps then read it (plain background removed), estimate its
camera with the checkpoint's head and its framing bank's votes, frame it (by that bank, built here
where the checkpoint has none or one without the renders' views) and reconstruct it
(``svr.inference.reconstruction``). Beside it on the same images, by the benchmark's voxel IoU in
the canonical frame, with 95% bootstrap intervals over objects: the same photos given their true
camera and framing (the framing the render had); given their true view with the framing estimated
(by the bank, as ``svr.infer`` does, and by the camera head, as it did before); the original
renders given their true camera (the benchmark's own protocol); and silhouette retrieval in any
view (camera-free) from the framed photo. Also the azimuth error of the estimate and the photos per
second of the pipeline (read, background, camera, framing, network; not the meshes and previews the
command also writes). Writes ``--out`` (markdown) and a JSON beside it.
"""
from __future__ import annotations

import argparse
import dataclasses
import io
import json
import time
from pathlib import Path
from typing import Optional

import numpy as np
import torch
from PIL import Image

from benchmarks.common import atomic_write_text, bootstrap_means, machine_info, procedural_data
from svr.data.procedural.generator import EXTRA_ELEVATION_DEG, render_dataset_object
from svr.evaluation.baselines import retrieve_any_view
from svr.inference.framing import TRAINING_FRAMING, frame_image, measure_framing
from svr.inference.framing_bank import build_framing_bank
from svr.inference.images import read_rgba, rgba_to_input
from svr.inference.prediction import load_model, predict_sdf
from svr.inference.input_camera import estimate_cameras
from svr.inference.reconstruction import input_and_camera
from svr.nmr.metrics import iou_table, voxel_iou, voxels_protocol
from svr.nmr.views import view_rows

ROOT = Path(__file__).resolve().parents[1]
CANVAS = 240  # room for the largest object (2 x 1.2 x 64 pixels) moved by 10%


def make_photo(render: np.ndarray, rng: np.random.Generator) -> tuple[bytes, float]:
    """A (4, 64, 64) uint8 render as a JPEG photo: scaled by 0.8-1.2 (from a 2x upsampling),
    composited over white on a CANVAS^2 image up to 10% of it off centre. Returns the bytes and
    the scale."""
    scale = float(rng.uniform(0.8, 1.2))
    side = int(round(128 * scale))
    rgba = Image.fromarray(np.ascontiguousarray(render.transpose(1, 2, 0)), "RGBA").resize((side, side),
                                                                                           Image.Resampling.BILINEAR)
    canvas = Image.new("RGB", (CANVAS, CANVAS), (255, 255, 255))
    dx, dy = (rng.uniform(-0.1, 0.1, size=2) * CANVAS).round().astype(int)
    canvas.paste(rgba, ((CANVAS - side) // 2 + int(dx), (CANVAS - side) // 2 + int(dy)), rgba)
    buffer = io.BytesIO()
    canvas.save(buffer, format="JPEG", quality=90)
    return buffer.getvalue(), scale


def sample_test_views(root: Path, test, obj: int, views: int, random_views: bool,
               rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One test object's renders and their cameras as (view, elevation) rows: ``views`` distinct
    NMR views from the dataset, or with ``random_views`` renders from cameras at any azimuth and an
    elevation of 10 to 50 degrees (the view coordinate ``-azimuth / 15`` taken modulo 24)."""
    if not random_views:
        chosen = rng.choice(24, size=views, replace=False)
        rows = np.stack([chosen.astype(np.float64), np.full(views, 30.0)], axis=1)
        return test.images_uint8(obj, chosen.tolist()), rows
    cams = np.stack([rng.uniform(0.0, 360.0, views), rng.uniform(*EXTRA_ELEVATION_DEG, views)], axis=1)
    c, o = test.locate(obj)
    renders = render_dataset_object(root, test.categories[c][0], "test", o, cams)
    return renders, view_rows(cams).numpy()


def run(ckpt: str, preset: str, views: int, seed: int, work: Path, random_views: bool = False) -> dict:
    dm = procedural_data(preset)
    test, train = dm.dataset("test"), dm.dataset("train")
    model = load_model(ckpt, "cpu")
    if getattr(model.net, "camera", None) is None:
        raise SystemExit(f"--ckpt {ckpt}: the checkpoint has no camera head (model.camera)")
    bank_source = "the checkpoint's"
    if model.framing_bank is None or model.framing_bank.views is None:
        # An older checkpoint: the bank svr.demo would store today, not written into it.
        why = "none" if model.framing_bank is None else "one without the renders' views"
        model = dataclasses.replace(model, framing_bank=build_framing_bank(train))
        bank_source = f"built here from the training split (the checkpoint holds {why})"
    hs = model.half_side
    rng = np.random.default_rng(seed)
    work.mkdir(parents=True, exist_ok=True)
    rows = {"photo_estimated": [], "photo_true": [], "render_true": [], "view_only": [], "framing_only": [],
            "head_framing_only": []}
    category, objects, view_error, right, query_alpha, seconds = [], [], [], [], [], 0.0
    elevation_error = []
    for obj in range(len(test)):
        c, _ = test.locate(obj)
        renders, cams = sample_test_views(dm.root, test, obj, views, random_views, rng)
        gt = test.voxels(obj)[None]
        for k, (row, render) in enumerate(zip(cams, renders)):
            v, true_cam = float(row[0]), torch.tensor(row[None], dtype=torch.float32)
            data, _ = make_photo(render, rng)
            path = work / f"photo_{obj}_{k}.jpg"
            path.write_bytes(data)
            started = time.perf_counter()
            rgba = read_rgba(path)
            image, camera = input_and_camera(model, rgba, str(path), None, True)
            estimated_cam = torch.tensor([camera.row], dtype=torch.float32)
            pred = predict_sdf(model, image[None], views=estimated_cam).final
            seconds += time.perf_counter() - started
            true_framing = measure_framing(render[3][None])
            framed, _ = frame_image(rgba, str(path), model.image_size, true_framing)
            true_image = rgba_to_input(framed, str(path), model.image_size)
            median, _ = frame_image(rgba, str(path), model.image_size, TRAINING_FRAMING)
            head = estimate_cameras(model.net, rgba_to_input(median, str(path), model.image_size)[None])[0]
            head_framed, _ = frame_image(rgba, str(path), model.image_size, head.framing)
            grids = {"photo_estimated": pred,
                     "photo_true": predict_sdf(model, true_image[None], views=true_cam).final,
                     "view_only": predict_sdf(model, true_image[None], views=estimated_cam).final,
                     "framing_only": predict_sdf(model, image[None], views=true_cam).final,
                     "head_framing_only": predict_sdf(model, rgba_to_input(head_framed, str(path),
                                                                           model.image_size)[None], views=true_cam).final,
                     "render_true": predict_sdf(model, torch.from_numpy(render[None]).float() / 255.0,
                                                views=true_cam).final}
            for name, grid in grids.items():
                rows[name].append(float(voxel_iou(voxels_protocol(grid.detach().float(), -hs, hs), gt)[0]))
            err = abs(((camera.view - v) * 15 + 180) % 360 - 180)
            view_error.append(err)
            elevation_error.append(abs(camera.elevation_deg - float(row[1])))
            right.append(err < 7.5)  # the nearest NMR view
            category.append(c)
            objects.append(obj)
            query_alpha.append((image[3].numpy() * 255).round().astype(np.uint8))
    category = np.asarray(category)
    objects = np.asarray(objects)
    found = retrieve_any_view(train, np.stack(query_alpha))
    train_vox = {g: train.voxels(int(g))[None] for g in np.unique(found)}
    rows["retrieval_any_view"] = [float(voxel_iou(train_vox[g], test.voxels(int(o))[None])[0])
                                  for g, o in zip(found, objects)]
    result = {"ckpt": str(ckpt), "preset": preset, "views_per_object": views, "seed": seed, "photos": len(category),
              "azimuth_error_median_deg": float(np.median(view_error)),
              "azimuth_error_mean_deg": float(np.mean(view_error)),
              "elevation_error_median_deg": float(np.median(elevation_error)),
              "elevation_estimated": model.net.camera.elevation_out is not None, "views_right": float(np.mean(right)),
              "flipped_180": float(np.mean(np.asarray(view_error) > 172.5)), "random_views": random_views,
              "photos_per_second": len(category) / seconds, "framing_bank": bank_source,
              "framing_bank_renders": len(model.framing_bank), "rows": {}}
    for name, values in rows.items():
        values = np.asarray(values)
        per_object = np.array([values[objects == o].mean() for o in np.unique(objects)])
        cats = np.array([category[objects == o][0] for o in np.unique(objects)])
        _, (lo, hi) = bootstrap_means(per_object, cats)
        result["rows"][name] = {"mean": iou_table(values, category, dm.categories).mean, "lo": lo, "hi": hi}
    return result


LABELS = {"render_true": "the original render, true camera (the benchmark's protocol)",
          "photo_true": "the photo, true camera and framing",
          "view_only": "the photo, camera estimated, true framing",
          "framing_only": "the photo, framing estimated (framing bank), true view",
          "head_framing_only": "the photo, the camera head's framing, true view",
          "photo_estimated": "the photo, camera and framing estimated (svr.infer's path)",
          "retrieval_any_view": "silhouette retrieval in any view, from the framed photo"}


def report(result: dict) -> str:
    r = result["rows"]
    random = result.get("random_views", False)
    seen = "random cameras (azimuth any, elevation 10-50 degrees)" if random else "random NMR views"
    lines = [f"# Photos in, no camera given ({result['preset']} preset{', random views' if random else ''})", "",
             f"`python -m benchmarks.photo_inference --ckpt {result['ckpt']} --preset {result['preset']} "
             f"--views {result['views_per_object']} --seed {result['seed']}{' --random-views' if random else ''}`: "
             f"{result['photos']} photos (each test object from {result['views_per_object']} {seen}; scale 0.8-1.2, "
             f"up to 10% off centre, JPEG on white, no alpha).", "",
             "| row | mean IoU | 95% interval |", "|---|---|---|"]
    for name in ("render_true", "photo_true", "view_only", "framing_only", "head_framing_only", "photo_estimated",
                 "retrieval_any_view"):
        if name not in r:  # reports written before the framing bank
            continue
        lines.append(f"| {LABELS[name]} | {r[name]['mean']:.4f} | [{r[name]['lo']:.3f}, {r[name]['hi']:.3f}] |")
    gap = r["photo_true"]["mean"] - r["photo_estimated"]["mean"]
    lines += ["", f"- Estimated camera: azimuth error median {result['azimuth_error_median_deg']:.0f} degrees, mean "
              f"{result['azimuth_error_mean_deg']:.1f}; nearest NMR view right {result['views_right']:.1%}; "
              f"turned by 180 degrees {result['flipped_180']:.1%}; elevation error median "
              f"{result.get('elevation_error_median_deg', 0.0):.1f} degrees"
              f"{'' if result.get('elevation_estimated') else ' (the head estimates no elevation: 30 is taken)'}.",
              f"- The estimate costs {gap:+.4f} IoU against the true camera on the same photos (issue 43 "
              f"target: at most 0.03); against retrieval it gains "
              f"{r['photo_estimated']['mean'] - r['retrieval_any_view']['mean']:+.4f}.",
              f"- Framing bank: {result.get('framing_bank', 'none')}, "
              f"{result.get('framing_bank_renders', 0)} renders (svr.inference.framing_bank).",
              f"- {result['photos_per_second']:.1f} photos/s (read, background removal, camera, framing, network, "
              f"calibration; one photo at a time; target at least 5).", "", machine_info()]
    return "\n".join(lines) + "\n"


def main(argv: Optional[list[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ckpt", required=True, help="a checkpoint with a camera head (model=pixel)")
    parser.add_argument("--preset", default="demo", choices=("demo", "bench"))
    parser.add_argument("--views", type=int, default=4, help="random NMR views per test object")
    parser.add_argument("--random-views", action="store_true",
                        help="render each test object from random cameras (azimuth any, elevation 10-50) instead")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--work", type=Path, default=Path("outputs/photo_inference"), help="where the JPEGs go")
    parser.add_argument("--out", type=Path, default=None, help="markdown report (default docs/photo_inference_<preset>.md)")
    args = parser.parse_args(argv)
    if args.views < 1 or args.views > 24:
        parser.error(f"--views must be 1..24, got {args.views}")
    torch.set_grad_enabled(False)
    result = run(args.ckpt, args.preset, args.views, args.seed, args.work, args.random_views)
    out = args.out or ROOT / "docs" / f"photo_inference_{args.preset}{'_random' if args.random_views else ''}.md"
    atomic_write_text(out, report(result))
    atomic_write_text(out.with_suffix(".json"), json.dumps(result, indent=2) + "\n")
    print(report(result))


if __name__ == "__main__":
    main()


__all__ = ["main", "make_photo", "run"]
