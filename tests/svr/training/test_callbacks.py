"""Training plumbing: checkpoint files are readable like every other output; the logged pictures
are labelled."""
from __future__ import annotations

import stat

import torch

from svr.training.callbacks import AtomicCheckpointIO


def test_checkpoints_follow_the_umask(tmp_path, umask_022):
    path = tmp_path / "ckpts" / "last.ckpt"
    AtomicCheckpointIO().save_checkpoint({"step": 1}, path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o755


def test_image_logger_writes_a_labelled_legible_picture(tmp_path):
    from types import SimpleNamespace

    import numpy as np
    from PIL import Image

    from svr.training.callbacks import ImageLogger

    b, v, h = 3, 2, 16
    g = torch.Generator().manual_seed(0)
    visuals = {"input": torch.rand(b, 4, 32, 32, generator=g), "target": torch.rand(b, v, 4, h, h, generator=g),
               "silhouette": torch.rand(b, v, h, h, generator=g), "colour": torch.rand(b, v, 3, h, h, generator=g)}
    trainer = SimpleNamespace(global_step=4, is_global_zero=True, loggers=[], default_root_dir=str(tmp_path))
    module = SimpleNamespace(capture_visuals=False, visuals=None)
    logger = ImageLogger(every_n_steps=2, max_samples=2)
    logger.on_train_batch_start(trainer, module, None, 0)
    assert module.capture_visuals
    module.visuals = visuals
    logger.on_train_batch_end(trainer, module, None, None, 0)
    picture = np.asarray(Image.open(tmp_path / "images" / "step_0000004.png"))
    columns, rows = 1 + 4 * v, 2
    # 16-pixel renders scaled by 8 to 128-pixel tiles, plus a label strip above and one at the left
    assert picture.shape[0] > rows * 128 + 10 and picture.shape[1] > columns * 128 + 40
    assert (picture[:10].max(axis=-1) < 128).any()  # column labels in the top strip
    assert (picture[:, :40].max(axis=-1) < 128).any()  # row labels in the left strip
    assert (picture[:4, :].min() == 255) and (picture[:, :4].min() == 255)  # white margin around the labels
