"""What a single-view training checkpoint is made of, for its writer (``svr.models.module``) and its
readers (``svr.inference.checkpoints``, the training's run folders): the names of the three
training stages, in their order (paper section 6), and the key under which a checkpoint holds our
metadata beside Lightning's."""
from __future__ import annotations

STAGES = ("coarse", "refine", "joint")
CHECKPOINT_KEY = "sdfdiff"


def check_stage(stage: str) -> str:
    """``stage``, or a ValueError unless it is one of ``STAGES``."""
    if stage not in STAGES:
        raise ValueError(f"stage must be one of {STAGES}, got {stage!r}")
    return stage


__all__ = ["STAGES", "CHECKPOINT_KEY", "check_stage"]
