"""How training stops on a signal, in one place: ``StopRequest`` is the one SIGTERM handler of a
training run. Outside a stage's ``fit`` (data generation, between stages) it raises
``TrainingStopped`` at once; inside it, the signal is only noted and ``SaveOnStop`` writes a
resumable ``last.ckpt`` at the end of the running training step, then lets Lightning stop (through
Lightning's own handler, which it calls once), so a resumed run continues exactly there."""
from __future__ import annotations

import contextlib
import signal
import sys
import threading
from pathlib import Path
from typing import Any, Callable, Iterator, Optional

import pytorch_lightning as pl
from pytorch_lightning.utilities.exceptions import SIGTERMException

from sdfcommon.tooling.command_line import invoked_as
from svr.distributed import launch_rank_is_zero


class TrainingStopped(SystemExit):
    """Training stopped by a signal (SIGTERM: ``kill``, a scheduler's time limit, a container stop)
    after saving a resumable checkpoint. Its exit status is 128 + the signal number (143 for
    SIGTERM), as a shell reports a process killed by that signal, so ``train && evaluate`` chains
    and job schedulers see a failure."""

    def __init__(self, message: str, signum: int = int(signal.SIGTERM), checkpoint: Optional[Path] = None):
        super().__init__(128 + int(signum))
        self.message = message
        self.checkpoint = checkpoint


class StopRequest:
    """The SIGTERM handler of one training run and what it has seen.

    Attributes:
        run_dir: the run folder (named in the message that says how to resume).
        in_fit: a stage's ``fit`` is running (the signal is noted, ``SaveOnStop`` acts on it).
        pending: a signal arrived during ``fit`` and has not been acted on.
    """

    def __init__(self, run_dir: Path):
        self.run_dir = Path(run_dir)
        self.in_fit = False
        self.pending = False

    def handle(self, signum: int, frame: Any) -> None:
        if self.in_fit:
            self.pending = True
            return
        message = (f"training stopped by signal {signum} outside a training step; resume from the latest "
                   f"checkpoint with: {invoked_as('python train.py')} ckpt_path={self.run_dir}")
        if launch_rank_is_zero():
            print(message, file=sys.stderr, flush=True)
        raise TrainingStopped(message, signum)

    def install(self) -> Optional[Callable]:
        """Makes ``handle`` the process's SIGTERM handler (main thread only, where handlers can be
        set); returns the handler it replaced (None elsewhere)."""
        if threading.current_thread() is not threading.main_thread():
            return None
        previous = signal.getsignal(signal.SIGTERM)
        signal.signal(signal.SIGTERM, self.handle)
        return previous

    @contextlib.contextmanager
    def installed(self) -> Iterator["StopRequest"]:
        """``handle`` is the SIGTERM handler inside the block; the previous one after it."""
        previous = self.install()
        try:
            yield self
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)

    @contextlib.contextmanager
    def fitting(self) -> Iterator[None]:
        """Marks a stage's ``fit`` (signals are noted, not raised)."""
        self.in_fit = True
        try:
            yield
        finally:
            self.in_fit = False


class SaveOnStop(pl.Callback):
    """Saves a resumable checkpoint (``path``, the stage's ``last.ckpt``) after a SIGTERM, then lets
    Lightning stop.

    The checkpoint is written at the end of the training step that is running (or the next one,
    when the signal came during validation or before the first step), at ``on_train_batch_end``,
    where Lightning's periodic checkpoints are written too: the state its resume logic restores
    exactly. Only then is Lightning told (its own handler), so it stops after that step. Had
    Lightning heard the signal itself, it would stop in the middle of a validation (before the
    step's learning-rate update: a resumed run would then be one scheduler step behind) or after an
    epoch's last step (a checkpoint that resumes one epoch too far). A signal after the stage's
    last step stays ``pending`` in the ``StopRequest`` for the schedule. The training data loader
    records its place in the epoch (``ResumableLoader``).
    """

    def __init__(self, path: Path, stop: StopRequest):
        self.path = Path(path)
        self.stop = stop
        self.saved_step: Optional[int] = None
        self._lightning_handler: Any = None

    def on_train_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        # Lightning installed its handler when fit began: the run's handler hears the signal first.
        self._lightning_handler = self.stop.install()

    def _save(self, trainer: pl.Trainer) -> None:
        if self.saved_step is None:
            trainer.save_checkpoint(self.path, weights_only=False)
            self.saved_step = int(trainer.global_step)

    def on_train_batch_end(self, trainer: pl.Trainer, *args: Any) -> None:
        if self.stop.pending or trainer.received_sigterm:
            self._save(trainer)
            if callable(self._lightning_handler) and not trainer.received_sigterm:
                self._lightning_handler(signal.SIGTERM, None)  # Lightning stops after this step

    def on_exception(self, trainer: pl.Trainer, pl_module: pl.LightningModule, exception: BaseException) -> None:
        if isinstance(exception, SIGTERMException):  # Lightning heard it first (e.g. broadcast by DDP)
            self._save(trainer)


__all__ = ["TrainingStopped", "StopRequest", "SaveOnStop"]
