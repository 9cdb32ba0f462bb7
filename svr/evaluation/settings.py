"""The typed settings of the evaluation command (configs/eval.yaml), built from the composed config
by ``sdfcommon.tooling.settings.build_settings``: an unknown key, a value of the wrong type or one
out of range fails with a message naming the key before the command makes its folder. Every
default is written once, in the YAML; the data module stays a ``_target_`` component that the
command instantiates."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Union

from sdfcommon.tooling.checks import check_float, check_int
from sdfcommon.tooling.settings import Component, PathSettings
from svr.evaluation.baselines import check_baselines
from svr.nmr.format import SPLITS, check_view_ids

DISTRIBUTED_MODES = ("auto", True, False)


@dataclass(frozen=True)
class EvalSettings:
    """The evaluation command's settings (configs/eval.yaml; its comments say more).

    Attributes:
        ckpt_path: the checkpoint to evaluate.
        split: "train", "val" or "test" (the benchmark's).
        output_dir: where the report goes; None: hydra's run folder (``<paths.output_dir>/eval/<time>``).
        compare_coarse: also score the coarse SDF.
        calibrated: apply the checkpoint's calibration when it holds one (``svr.inference.calibration``).
        baselines: names from ``svr.evaluation.baselines.BASELINES`` scored on the same images.
        batch_size: images per forward pass (configs/eval.yaml: the data's ``eval_batch_size``).
        num_workers: DataLoader workers. protocol_workers: voxelisation processes (0: this one).
        device: "auto", "cpu", "cuda" or "cuda:N".
        views, max_objects_per_category: thin the evaluation (None: the whole protocol).
        progress: progress bars. seed: the data module's draws (``data.seed``).
        distributed: "auto" (join the process group torchrun or srun describe), True or False.
        distributed_timeout_s: how long a process may wait for the others.
        data: the data module (a ``_target_`` component). paths: as ``PathSettings``.
    """

    ckpt_path: str
    split: str
    output_dir: Optional[str]
    compare_coarse: bool
    calibrated: bool
    baselines: list[str]
    batch_size: int
    num_workers: int
    device: str
    protocol_workers: int
    views: Optional[list[int]]
    max_objects_per_category: Optional[int]
    progress: bool
    seed: int
    distributed: Union[bool, str]
    distributed_timeout_s: float
    data: Component
    paths: PathSettings

    def __post_init__(self) -> None:
        if self.split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {self.split!r}")
        if self.views is not None:
            check_view_ids(self.views, "views", allow_empty=False)
        check_int(self.batch_size, "batch_size", 1)
        check_int(self.num_workers, "num_workers", 0)
        check_int(self.protocol_workers, "protocol_workers", 0)
        if self.max_objects_per_category is not None:
            check_int(self.max_objects_per_category, "max_objects_per_category", 1)
        if not any(type(self.distributed) is type(m) and self.distributed == m for m in DISTRIBUTED_MODES):
            raise ValueError(f"distributed must be one of auto, true, false, got {self.distributed!r}")
        check_float(self.distributed_timeout_s, "distributed_timeout_s", 1)
        check_baselines(self.baselines)


__all__ = ["EvalSettings", "DISTRIBUTED_MODES"]
