"""Pictures of a model's predictions beside its inputs (the demo's ``predictions.png``) and their
marching-cubes meshes."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import torch

from sdfcommon.numerics.meshing import sdf_to_mesh
from svr.inference.prediction import LoadedModel, predict_sdf
from svr.nmr.format import NUM_VIEWS
from svr.nmr.views import render_views


@torch.no_grad()
def showcase(model: LoadedModel, coarse_model: LoadedModel, dataset, categories: Sequence[tuple[str, str]], scene,
             out_dir: Path, views: Sequence[int] = (0,)) -> list[Path]:
    """For the first test object of each category: a PNG row (input, the coarse stage's and the
    full model's predictions rendered from the input view, the full model's from 90 and 180 degrees
    further round) and the full model's marching-cubes mesh (.ply). The models' predictions are the
    evaluation's (``predict_sdf``, with their calibrations); ``coarse_model``'s coarse SDF is shown.

    Returns:
        the files written (the PNG first).
    """
    import matplotlib  # heavy: only the demo's picture needs it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # heavy, as above

    mesh_dir = out_dir / "meshes"
    mesh_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    rows = []
    for c, (cid, name) in enumerate(categories):
        if dataset.counts[c] == 0:
            continue
        obj = int(dataset.offsets[c])
        for v in views:
            image = dataset.views(obj, [v])  # (1, 4, 64, 64)
            final = predict_sdf(model, image, views=v).final  # what the evaluation scored
            coarse = predict_sdf(coarse_model, image, refine=False, views=v).coarse
            hs = model.half_side
            shots = []
            for sdf, view in ((coarse, v), (final, v), (final, v + 6), (final, v + 12)):
                _, colours = render_views(sdf, hs, torch.tensor([[view % NUM_VIEWS]]), scene, 64)
                shots.append(colours[0, 0].permute(1, 2, 0).clamp(0, 1).cpu().numpy())
            rows.append((f"{name} #0 view {v}", image[0, :3].permute(1, 2, 0).cpu().numpy(), shots))
            mesh = sdf_to_mesh(final[0], -hs, hs)
            path = mesh_dir / f"{name}_test0_view{v}.ply"
            mesh.export(path)
            written.append(path)
    titles = ["input", "coarse stage", "full model", "full, +90°", "full, +180°"]
    fig, axes = plt.subplots(len(rows), 5, figsize=(5 * 1.6, len(rows) * 1.7), squeeze=False)
    for r, (label, inp, shots) in enumerate(rows):
        for k, img in enumerate([inp] + shots):
            ax = axes[r, k]
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(titles[k], fontsize=8)
        axes[r, 0].set_ylabel(label, fontsize=7)
    fig.tight_layout()
    png = out_dir / "predictions.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return [png] + written


__all__ = ["showcase"]
