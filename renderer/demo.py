"""A small render demo, run as ``python -m renderer.demo [--out FOLDER]``: an SDF grid (64^3 by
default) of a torus and a sphere seen by three cameras, written as one PNG (``render_demo.png``,
a row per view: shading, normals, depth, soft silhouette) into the output folder, docs/ by default.
"""
from __future__ import annotations

import argparse
import os
import secrets
from pathlib import Path

import numpy as np
import torch

from . import Cameras, DirectionalLight, Scene, SDFGrid, render, torus_and_sphere


def save_png(path: Path, image: np.ndarray) -> None:
    """Writes an (H, W) or (H, W, C) float image in [0, 1] atomically."""
    from PIL import Image  # optional (not a renderer dependency): only the demo writes PNGs

    arr = (np.clip(image, 0.0, 1.0) * 255).round().astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    # PIL creates the temporary file plainly, so the umask sets its mode (mkstemp would give 0600).
    tmp = path.parent / f".{path.name}.{secrets.token_hex(8)}.tmp"
    try:
        Image.fromarray(arr).save(tmp, format="PNG")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="example:\n  python -m renderer.demo --out docs")
    ap.add_argument("--out", default="docs", help="output folder (default: docs)")
    ap.add_argument("--resolution", type=int, default=64, help="SDF grid resolution")
    ap.add_argument("--image-size", type=int, default=192, help="image side in pixels")
    args = ap.parse_args(argv)
    if args.resolution < 2:
        ap.error("--resolution must be >= 2")
    if args.image_size < 1:
        ap.error("--image-size must be >= 1")
    grid = SDFGrid.from_function(torus_and_sphere, args.resolution)
    eyes = torch.tensor([[0.0, 1.2, 2.6], [2.2, 1.2, 1.2], [-1.5, 2.2, -1.5]])
    cams = Cameras.look_at(eyes, fov_deg=40, image_size=args.image_size)
    scene = Scene(lights=(DirectionalLight((1.0, 2.0, 1.5), 0.8),), ambient=0.15,
                  albedo=(0.9, 0.75, 0.55), background=(1.0, 1.0, 1.0))
    out = render(grid, cams, scene)
    rows = []
    for k in range(cams.batch_size):
        depth = out.depth[k].detach()
        dn = torch.where(out.hit[k], 1.0 - (depth - depth[out.hit[k]].min()) / 2.0, torch.zeros_like(depth))
        normal = (out.normal[k].detach() * 0.5 + 0.5) * out.hit[k, ..., None]
        sil = out.silhouette[k].detach()
        tiles = [out.image[k].detach().numpy(), normal.numpy(), np.repeat(dn.clamp(0, 1)[..., None].numpy(), 3, -1),
                 np.repeat(sil[..., None].numpy(), 3, -1)]
        rows.append(np.concatenate(tiles, axis=1))
    path = Path(args.out) / "render_demo.png"
    save_png(path, np.concatenate(rows, axis=0))
    print(f"wrote {path} (columns: shading, normals, depth, silhouette; {cams.batch_size} views)")


if __name__ == "__main__":
    main()
