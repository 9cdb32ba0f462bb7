"""The evaluation command, ``python -m svr.evaluate ckpt_path=X.ckpt`` / ``sdfdiff-evaluate``
(configs/eval.yaml, whose comments show the command lines): a checkpoint's benchmark 3D IoU per
category in the paper's layout (``svr.evaluation.protocol``), printed and written into
``output_dir``, else hydra's run folder ``<paths.output_dir>/eval/<time>`` (``table.md``,
``table.csv``, ``iou.json``, ``per_object.csv``, ``per_image.csv``: ``svr.evaluation.tables``). ``run``
loads the model, prepares the split's data (rank 0 first) and evaluates; started several times by
torchrun or srun, the processes share the images, gather the per-image results and only rank 0
prints and writes (the ``rank_zero_only`` resolver, registered here, gives hydra's ``.hydra/`` record
to rank 0 alone). A mistake in the settings or files is one line ``sdfdiff-evaluate: error: ...``
with exit status 2 (``sdfcommon.tooling.commands``)."""
from __future__ import annotations

import contextlib
import dataclasses
import sys
import warnings
from typing import Any, Iterator, Optional

import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import OmegaConf

from sdfcommon.tooling.commands import hydra_entry
from sdfcommon.tooling.outputs import ensure_output_dir
from svr.distributed import RankInfo, barrier, launch_rank_is_zero, local_rank, process_group_from_environment
from svr.evaluation.protocol import add_baselines, evaluate
from svr.evaluation.settings import EvalSettings
from svr.evaluation.tables import EvaluationResult, format_iou, format_table, write_report
from svr.inference.prediction import load_model


def rank_zero_only(value: Any) -> Optional[Any]:
    """``${rank_zero_only:x}``: ``x`` in the launch's rank 0, None in the other processes (as
    Lightning does for its DDP processes: one process writes hydra's ``.hydra/`` record)."""
    return value if launch_rank_is_zero() else None


OmegaConf.register_new_resolver("rank_zero_only", rank_zero_only, replace=True)


def _device_of_rank(device: str, ranks: RankInfo) -> str:
    """With several processes, "auto"/"cuda" become this process's GPU (its local rank)."""
    if ranks.world_size > 1 and device in ("auto", "cuda") and torch.cuda.is_available():
        return f"cuda:{local_rank() % torch.cuda.device_count()}"
    return device


@contextlib.contextmanager
def _warnings_in_one_line() -> Iterator[None]:
    """Inside: each warning is one line ``<prog>: warning: <message>`` on stderr, as a mistake is one
    line ``<prog>: error: ...``, not Python's file:line and source line."""
    prog = HydraConfig.get().help.app_name if HydraConfig.initialized() else "svr.evaluate"

    def show(message, category, filename, lineno, file=None, line=None) -> None:
        print(f"{prog}: warning: {' '.join(str(message).split())}", file=sys.stderr, flush=True)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def run(settings: EvalSettings) -> EvaluationResult:
    """Evaluates, prints and writes (see the module docstring); returns the result. Warnings (a
    checkpoint trained on other categories than the data's, ...) are one line each.

    ``distributed`` ("auto", the default): join the process group that torchrun or srun describe
    when they started several processes; each evaluates its share, rank 0 prints and writes.
    """
    with _warnings_in_one_line():
        if settings.distributed is False:
            return _evaluate_checkpoint(settings, RankInfo())
        with process_group_from_environment(timeout_s=settings.distributed_timeout_s) as ranks:
            return _evaluate_checkpoint(settings, ranks)


def _evaluate_checkpoint(settings: EvalSettings, ranks: RankInfo) -> EvaluationResult:
    # The output folder is output_dir, else hydra's run folder (eval.yaml makes them one); checked
    # before the long run.
    out = settings.output_dir or HydraConfig.get().runtime.output_dir
    folder = ensure_output_dir(out, "output_dir") if ranks.is_zero else None
    datamodule = instantiate(settings.data)
    model = load_model(settings.ckpt_path, _device_of_rank(settings.device, ranks))
    if not settings.calibrated:
        model = dataclasses.replace(model, calibration=None)
    say = print if ranks.is_zero else (lambda *args, **kwargs: None)
    say(f"evaluating {model.checkpoint} ({model.stage} stage, {model.output_name} output) on {model.device}"
        + (f" and {ranks.world_size - 1} more processes" if ranks.world_size > 1 else "")
        + (f"; calibration: {model.calibration.describe()}" if model.calibration is not None else ""))
    say(f"data: {datamodule.describe()}; split: {settings.split}")
    if ranks.is_zero:
        datamodule.prepare_split(settings.split, progress=settings.progress)
    barrier()  # the other processes read the split once rank 0 has made it
    result = evaluate(model, datamodule, settings.split, batch_size=settings.batch_size,
                      distributed=ranks.world_size > 1, views=settings.views,
                      max_objects_per_category=settings.max_objects_per_category,
                      num_workers=settings.num_workers, compare_coarse=settings.compare_coarse,
                      protocol_workers=settings.protocol_workers, progress=settings.progress and ranks.is_zero)
    if not ranks.is_zero:
        return result
    result = add_baselines(result, datamodule, settings.baselines, model, progress=settings.progress)
    print()
    print(format_table(result))
    files = write_report(result, folder)
    print(f"split '{result.split}': mean IoU {format_iou(result.mean)} over {len(result.present)} categories, "
          f"{len(result.iou)} images, {result.seconds:.1f} s")
    print("wrote " + ", ".join(str(p) for p in files.values()))
    return result


main = hydra_entry("eval", run)


if __name__ == "__main__":
    main()


__all__ = ["run", "main", "rank_zero_only"]
