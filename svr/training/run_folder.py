"""The layout of a training run's folder, written down once: ``config.yaml`` (the resolved config
the run started with) and, per stage, ``<stage>/checkpoints/{best,last,final}.ckpt`` (best
validation IoU; rewritten every few steps, what a killed run resumes from; the weights at the end
of the stage), Lightning's SLURM checkpoints ``<stage>/hpc_ckpt_<n>.ckpt`` and the logs
(``<stage>/tensorboard/``, ``<stage>/csv/metrics.csv``, ``<stage>/images/``). Everything that
reads or writes a run folder goes through ``RunFolder``."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

from svr.inference.checkpoints import load_checkpoint
from svr.models.checkpoint_layout import CHECKPOINT_KEY, STAGES

CONFIG_FILE = "config.yaml"
HYDRA_RECORD = ".hydra/hydra.yaml"  # hydra's record of how a new run was composed (configs/train.yaml's output_subdir)
CHECKPOINTS = "checkpoints"
BEST, LAST, FINAL = "best.ckpt", "last.ckpt", "final.ckpt"
SLURM_CHECKPOINT_PREFIX = "hpc_ckpt_"


@dataclass(frozen=True)
class RunFolder:
    """A training run's folder (``root``) and the paths inside it."""

    root: Path

    @property
    def config(self) -> Path:
        """The run's resolved config (written when the run starts)."""
        return self.root / CONFIG_FILE

    @property
    def hydra_record(self) -> Path:
        """hydra's record of the command that started the run (its config groups' options among it)."""
        return self.root / HYDRA_RECORD

    def holds_run(self) -> bool:
        """Whether a training run was started here (its ``config.yaml`` exists)."""
        return self.config.is_file()

    def holds_checkpoint(self) -> bool:
        """Whether any stage wrote a checkpoint here (a run that failed or stopped before its first
        holds none: nothing in the folder is worth keeping or resuming)."""
        return any(f.is_file() for folder in self.stage_dirs() for f in folder.rglob("*.ckpt"))

    def stage_dir(self, stage: str) -> Path:
        """Where one stage writes its checkpoints and logs."""
        return self.root / stage

    def stage_dirs(self) -> list[Path]:
        """The folders of every stage (made or not)."""
        return [self.stage_dir(stage) for stage in STAGES]

    def checkpoints(self, stage: str) -> Path:
        """The folder of a stage's checkpoints."""
        return self.stage_dir(stage) / CHECKPOINTS

    def best(self, stage: str) -> Path:
        return self.checkpoints(stage) / BEST

    def last(self, stage: str) -> Path:
        return self.checkpoints(stage) / LAST

    def final(self, stage: str) -> Path:
        return self.checkpoints(stage) / FINAL

    def finished(self, stage: str) -> bool:
        """Whether the stage ran to its end (its ``final.ckpt`` exists)."""
        return self.final(stage).is_file()

    def best_or_final(self, stage: str) -> Path:
        """A finished stage's best checkpoint (by validation IoU), else its final one."""
        for path in (self.best(stage), self.final(stage)):
            if path.is_file():
                return path
        raise FileNotFoundError(f"no {BEST} or {FINAL} in {self.checkpoints(stage)}: has the {stage} stage run?")

    def resume_point(self, schedule: Sequence[str]) -> tuple[bool, Optional[Path]]:
        """Where a run left off: (finished, checkpoint to resume from): finished when the last
        scheduled stage wrote ``final.ckpt``; otherwise its latest checkpoint (None: start afresh)."""
        if self.finished(schedule[-1]):
            return True, self.final(schedule[-1])
        return False, self.latest_checkpoint(schedule)

    def train_seconds(self, schedule: Sequence[str]) -> Optional[float]:
        """The whole run's training seconds: the sum of the ``train_seconds`` its stages' final
        checkpoints record (kept over resumes); None when a stage has not finished."""
        if not all(self.finished(stage) for stage in schedule):
            return None
        return sum(float(load_checkpoint(self.final(stage))[CHECKPOINT_KEY].get("train_seconds", 0.0))
                   for stage in schedule)

    def steps(self, schedule: Sequence[str], planned: dict[str, int]) -> dict[str, dict[str, Optional[int]]]:
        """Per scheduled stage, the steps ``planned`` and the steps its ``final.ckpt`` reached
        (None where the stage has not finished; fewer: the stage's time cap stopped it)."""
        return {str(stage): {"planned": planned[stage],
                             "reached": int(load_checkpoint(self.final(stage))["global_step"])
                             if self.finished(stage) else None} for stage in schedule}

    def latest_checkpoint(self, schedule: Sequence[str]) -> Optional[Path]:
        """What a stopped run resumes from: the newest of ``last.ckpt``, ``final.ckpt`` and
        Lightning's SLURM checkpoints of the latest scheduled stage that wrote one (None: no stage
        has)."""
        for stage in reversed(list(schedule)):
            found = [p for p in (self.final(stage), self.last(stage)) if p.is_file()]
            found += [f for f in self.stage_dir(stage).glob(f"{SLURM_CHECKPOINT_PREFIX}*.ckpt") if f.is_file()]
            if found:
                return max(found, key=lambda f: f.stat().st_mtime_ns)
        return None


def run_folder_of(ckpt_path: Union[str, Path]) -> Optional[RunFolder]:
    """The training run a checkpoint belongs to: ``RUN`` for ``RUN/<stage>/checkpoints/<name>.ckpt``
    (or ``RUN/<stage>/hpc_ckpt_<n>.ckpt``) when ``RUN`` holds a run; None otherwise."""
    p = Path(ckpt_path).expanduser().resolve()
    if p.parent.name == CHECKPOINTS and p.parent.parent.name in STAGES:
        run = RunFolder(p.parent.parent.parent)
    elif p.name.startswith(SLURM_CHECKPOINT_PREFIX) and p.parent.name in STAGES:
        run = RunFolder(p.parent.parent)
    else:
        return None
    return run if run.holds_run() else None


def run_named_by(ckpt_path: Union[str, Path]) -> Optional[RunFolder]:
    """The run a ``ckpt_path`` setting names: the folder itself when it holds a run, else the run
    its checkpoint belongs to (``run_folder_of``); None for neither."""
    path = Path(ckpt_path).expanduser()
    folder = RunFolder(path.resolve())
    return folder if folder.holds_run() else run_folder_of(path)


__all__ = ["RunFolder", "run_folder_of", "run_named_by", "CONFIG_FILE", "BEST", "LAST", "FINAL"]
