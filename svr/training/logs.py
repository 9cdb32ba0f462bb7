"""What a stage's loggers write and print: the CSV metrics of earlier runs of a stage kept when it
starts again (Lightning's CSV logger would delete them), and the messages every stage would print
that say nothing about the run, silenced."""
from __future__ import annotations

import csv
import logging
import warnings
from pathlib import Path
from typing import Optional, Sequence

from pytorch_lightning.loggers import CSVLogger, Logger

from sdfcommon.tooling.outputs import write_csv
from svr.distributed import launch_rank_is_zero


class _DropAdvertisements(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("\U0001f4a1 Tip:")  # "try installing <a cloud logger>"


def quiet_known_noise() -> None:
    """Silences the messages every stage would print that say nothing about this run: Lightning's
    advertisement for a cloud logger, a deprecation inside Lightning's own code (LeafSpec), and
    the warning about modules in eval mode (the stages freeze parts of the network on purpose:
    their batch-norm statistics must not move, ``SVRLightningModule.apply_stage``)."""
    rank_zero = logging.getLogger("pytorch_lightning.utilities.rank_zero")
    if not any(isinstance(f, _DropAdvertisements) for f in rank_zero.filters):
        rank_zero.addFilter(_DropAdvertisements())
    warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)` is deprecated")
    warnings.filterwarnings("ignore", message=r"Found \d+ module\(s\) in eval mode at the start of training")


def continue_metrics(log_dir: Path, resume_step: Optional[int]) -> Optional[Path]:
    """Keeps the metrics of earlier runs of a stage in its ``metrics.csv``, which Lightning's CSV
    logger would delete when it starts.

    Resuming (``resume_step``: the checkpoint's step), the rows up to that step are kept in
    ``metrics.csv`` and the logger appends to them (rows after it were logged by steps the resumed
    run trains again). Otherwise an earlier file is moved aside to ``metrics.<k>.csv``.

    Returns:
        the file holding the earlier rows (``metrics.csv`` or the moved one), or None.
    """
    old = log_dir / "metrics.csv"
    if not old.is_file():
        return None
    if resume_step is not None:  # rewritten in place, atomically
        with open(old, newline="") as f:
            reader = csv.DictReader(f)
            columns = list(reader.fieldnames or [])
            rows = [r for r in reader if _step_of(r) is not None and _step_of(r) <= resume_step]
        return write_csv(old, rows, columns)
    k = 1
    while (log_dir / f"metrics.{k}.csv").exists():
        k += 1
    return old.rename(log_dir / f"metrics.{k}.csv")


def _step_of(row: dict) -> Optional[int]:
    try:
        return int(float(row.get("step") or ""))
    except ValueError:
        return None


def _adopt_metrics_file(logger: CSVLogger) -> None:
    """Points a fresh CSV logger at a resumed stage's log folder: it appends to the ``metrics.csv``
    kept by ``continue_metrics`` (its writer would delete the file, and warn about the folder,
    when it starts)."""
    log_dir = Path(logger.log_dir)
    if not log_dir.is_dir():
        return
    path = log_dir / "metrics.csv"
    columns = None
    if path.is_file():
        with open(path, newline="") as f:
            columns = next(csv.reader(f), [])
    kept = log_dir.rename(log_dir.with_name(f".{log_dir.name}.kept"))
    writer = logger.experiment  # creates log_dir anew, empty
    for item in kept.iterdir():
        item.rename(log_dir / item.name)
    kept.rmdir()
    if columns is not None:
        writer.metrics_keys = list(columns)


def keep_earlier_metrics(loggers: Sequence[Logger], resume_step: Optional[int]) -> None:
    """Before a stage's trainer starts (launch rank only): each CSV logger keeps the rows of earlier
    runs of the stage (``continue_metrics``) and, resuming from step ``resume_step``, appends to them."""
    if not launch_rank_is_zero():
        return
    for lg in loggers:
        if isinstance(lg, CSVLogger):
            continue_metrics(Path(lg.log_dir), resume_step)
            if resume_step is not None:
                _adopt_metrics_file(lg)


__all__ = ["quiet_known_noise", "continue_metrics", "keep_earlier_metrics"]
