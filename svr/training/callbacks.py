"""Training plumbing for Lightning: atomic checkpoint files and image logging."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import numpy as np
import pytorch_lightning as pl
import torch
from pytorch_lightning.plugins.io import TorchCheckpointIO

from sdfcommon.tooling.outputs import write_png, write_torch
from sdfcommon.tooling.pictures import labelled_grid


class AtomicCheckpointIO(TorchCheckpointIO):
    """Writes each checkpoint atomically (``sdfcommon.tooling.outputs.atomic_write``: a temporary file in the
    target's folder, flushed to disk, then renamed over the target; its mode follows the umask).

    Lightning's own writer goes through fsspec, whose local transaction stages the bytes in the
    system temp folder and moves them; when that folder is on another file system (a tmpfs /tmp)
    the move degrades to a copy, and a process killed during the copy leaves a truncated
    checkpoint under the real name. Here the file at ``path`` is always either the previous
    complete checkpoint or the new complete one.
    """

    def save_checkpoint(self, checkpoint: dict[str, Any], path, storage_options: Optional[Any] = None) -> None:
        if storage_options is not None:
            raise TypeError(f"storage_options is not supported by {type(self).__name__}, got {storage_options!r}")
        write_torch(path, checkpoint)


def visual_grid(visuals: dict[str, torch.Tensor], max_samples: int = 4, min_tile: int = 128) -> np.ndarray:
    """One labelled picture of a training batch: per sample a row with the input view, then per
    supervised view the target silhouette, the rendered silhouette and (when rendered) the target and
    rendered colours, all at the render size (the input is area-resized to it), each tile scaled up
    to at least ``min_tile`` pixels (``sdfcommon.tooling.pictures.labelled_grid``).

    Args:
        visuals: ``input`` (B, 4, H, W), ``target`` (B, V, 4, h, w), ``silhouette`` (B, V, h, w),
            optional ``colour`` (B, V, 3, h, w); CPU tensors in [0, 1].
    Returns:
        (H', W', 3) float32 array in [0, 1]: rows labelled by sample, columns by what they show.
    """
    target = visuals["target"]
    b, v, _, h, w = target.shape
    n = min(b, max_samples)
    inp = visuals["input"][:n]
    if inp.shape[-1] != w:
        inp = torch.nn.functional.adaptive_avg_pool2d(inp, (h, w))
    columns = ["input"]
    for k in range(v):
        columns += [f"view {k} target mask", f"view {k} render mask"]
        if "colour" in visuals:
            columns += [f"view {k} target colour", f"view {k} render colour"]
    rows = []
    for i in range(n):
        # The input's RGB as given: the datasets already composite it over white
        # (svr.nmr.format.images_to_float), so its alpha is not needed here.
        tiles = [inp[i, :3].permute(1, 2, 0)]
        for k in range(v):
            tiles.append(target[i, k, 3, :, :, None].expand(h, w, 3))
            tiles.append(visuals["silhouette"][i, k, :, :, None].expand(h, w, 3))
            if "colour" in visuals:
                tiles.append(target[i, k, :3].permute(1, 2, 0))
                tiles.append(visuals["colour"][i, k].clamp(0, 1).permute(1, 2, 0))
        rows.append(torch.stack(tiles))
    tiles = torch.stack(rows).detach().float().clamp(0, 1).numpy()
    return labelled_grid(tiles, [f"sample {i}" for i in range(n)], columns, min_tile=min_tile)


class ImageLogger(pl.Callback):
    """Every ``every_n_steps`` training steps, logs a labelled picture of the batch (``visual_grid``:
    inputs, target silhouettes, renders of the prediction; colours too when shading is rendered) to
    TensorBoard and writes it as a PNG under ``<folder>/step_XXXXXXX.png`` (the CSV logger has no
    images).

    Args:
        every_n_steps: period in optimiser steps (0 disables).
        max_samples: rows per picture.
        folder: where PNGs go; None: ``<trainer.default_root_dir>/images``.
    """

    def __init__(self, every_n_steps: int = 200, max_samples: int = 4, folder: Optional[str] = None) -> None:
        super().__init__()
        if isinstance(every_n_steps, bool) or not isinstance(every_n_steps, int) or every_n_steps < 0:
            raise ValueError(f"every_n_steps must be a non-negative int, got {every_n_steps!r}")
        if isinstance(max_samples, bool) or not isinstance(max_samples, int) or max_samples < 1:
            raise ValueError(f"max_samples must be a positive int, got {max_samples!r}")
        self.every_n_steps = every_n_steps
        self.max_samples = max_samples
        self.folder = folder

    def on_train_batch_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule, batch: Any,
                             batch_idx: int) -> None:
        pl_module.capture_visuals = bool(self.every_n_steps) and trainer.global_step % self.every_n_steps == 0
        self._step = trainer.global_step

    def on_train_batch_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:
        visuals = getattr(pl_module, "visuals", None)
        pl_module.capture_visuals = False
        if visuals is None:
            return
        pl_module.visuals = None
        if not trainer.is_global_zero:
            return
        picture = visual_grid(visuals, self.max_samples)
        step = getattr(self, "_step", trainer.global_step)
        for logger in trainer.loggers:
            experiment = getattr(logger, "experiment", None)
            if hasattr(experiment, "add_image"):
                experiment.add_image("train/renders", picture, step, dataformats="HWC")
        folder = Path(self.folder) if self.folder else Path(trainer.default_root_dir) / "images"
        folder.mkdir(parents=True, exist_ok=True)
        write_png(folder / f"step_{step:07d}.png", picture)
