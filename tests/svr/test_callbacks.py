"""Training plumbing: checkpoint files are readable like every other output; the logged pictures
are labelled."""
from __future__ import annotations

import stat

import torch

from svr.callbacks import AtomicCheckpointIO


def test_checkpoints_follow_the_umask(tmp_path, umask_022):
    path = tmp_path / "ckpts" / "last.ckpt"
    AtomicCheckpointIO().save_checkpoint({"step": 1}, path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o755
