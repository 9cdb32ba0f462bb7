"""The CPU demo, ``python -m svr.demo`` (what ``make demo`` runs; configs/demo.yaml): trains
``experiment=demo`` from scratch on the procedural data into ``<out>/train`` (a stopped run resumes
with its saved config when the command runs again, a finished one is only evaluated again), then
calibrates its last checkpoint on the validation split (``svr.evaluation.calibration_search``; once,
kept in the checkpoint) and scores it by the benchmark protocol with the coarse stage and every baseline
as extra rows, and writes into ``out``: the evaluation's files (``table.md``, ``table.csv``,
``iou.json``, ``per_object.csv``, ``per_image.csv``), ``timings.json`` (training seconds over
resumes, this command's wall and evaluation seconds, per stage the steps planned and reached),
``predictions.png`` and ``meshes/*.ply``."""
from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.commands import hydra_entry
from sdfcommon.tooling.outputs import write_json, write_text
from sdfcommon.tooling.settings import settings_record
from svr.scoring import score_run
from svr.training.resume import continued_settings
from svr.training.run_folder import RunFolder
from svr.training.settings import TrainSettings
from svr.training.stages import TrainingStopped, train


@dataclass(frozen=True)
class DemoSettings(TrainSettings):
    """configs/demo.yaml: the training settings of ``experiment=demo`` and the demo's own.

    Attributes:
        out: the demo's folder (from the working directory).
        eval_only: evaluate the finished run in ``<out>/train``, train nothing.
        fresh: delete ``<out>/train`` and train from scratch.
        protocol_workers: processes for the mesh voxelisation (0: this one): the calibration search's,
            and the evaluation's where they take at most half the cores or the network runs on a GPU.
        quiet: no progress bars.
        calibrate: calibrate the last checkpoint on the validation split and score both stages so
            (false: score the network's raw output).
        recalibrate: search the calibration again even where the checkpoint holds one.
        calibrate_carving: let the calibration carve by the input silhouette's cone (which reads the
            input camera); false: a level only, so that the scored predictions read only the image.
    """

    out: str
    eval_only: bool
    fresh: bool
    protocol_workers: int
    quiet: bool
    calibrate: bool
    recalibrate: bool
    calibrate_carving: bool

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.out:
            raise ValueError("out must name the demo's folder")
        if self.eval_only and self.fresh:
            raise ValueError("eval_only=true and fresh=true contradict each other: choose one")
        if self.recalibrate and not self.calibrate:
            raise ValueError("recalibrate=true needs calibrate=true")
        check_int(self.protocol_workers, "protocol_workers", 0)

    def training(self) -> TrainSettings:
        """The training part, with the progress bars off when ``quiet``."""
        settings = TrainSettings(**{f.name: getattr(self, f.name) for f in dataclasses.fields(TrainSettings)})
        if not self.quiet:
            return settings
        return dataclasses.replace(settings, data={**settings.data, "progress": False},
                                   trainer={**settings.trainer, "enable_progress_bar": False},
                                   callbacks={**settings.callbacks, "progress_bar": None})


DEMO_KEYS = tuple(f.name for f in dataclasses.fields(DemoSettings) if f.name not in
                  {g.name for g in dataclasses.fields(TrainSettings)})
QUIET_OVERRIDES = ("data.progress=false", "trainer.enable_progress_bar=false", "callbacks.progress_bar=null")


@dataclass(frozen=True)
class DemoResult:
    """What the demo made.

    Attributes:
        table: the markdown IoU table it printed.
        iou: ``iou.json`` as written (the evaluation, the calibration searches, the steps).
        files: every file written, as strings.
        timings: ``timings.json`` as written (seconds, whether the run resumed, the steps).
    """

    table: str
    iou: dict
    files: list[str]
    timings: dict


def run(settings: DemoSettings, overrides: Optional[Sequence[str]] = None) -> DemoResult:
    """The demo (see the module docstring).

    Args:
        settings: configs/demo.yaml's settings.
        overrides: the command line's overrides (default: hydra's); a resumed run may change only
            what ``svr.training.resume.RESUMABLE_KEYS`` allows of those naming training settings.
    Returns:
        the table, iou.json, the files and the timings.
    """
    if overrides is None:
        overrides = list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []
    requested = [o for o in overrides if o.lstrip("+~").split("=", 1)[0] not in DEMO_KEYS]
    requested += list(QUIET_OVERRIDES) if settings.quiet else []
    out_dir = Path(settings.out).expanduser().resolve()  # from the working directory, as every command
    folder = RunFolder(out_dir / "train")
    train_settings, record = settings.training(), None
    if not settings.fresh and folder.holds_run():
        train_settings, record = continued_settings(train_settings, folder, requested)
    schedule = list(train_settings.stage.schedule)
    start = time.time()
    train_wall = None
    finished, resume = (False, None) if settings.fresh else folder.resume_point(schedule)
    if settings.eval_only:
        if not finished:
            raise ValueError(f"eval_only=true needs a finished run in {folder.root} "
                             f"(no {schedule[-1]}/checkpoints/final.ckpt)")
    elif finished:
        print(f"{folder.root} holds a finished run: evaluating it (fresh=true trains again)")
    else:
        if settings.fresh and folder.root.exists():
            shutil.rmtree(folder.root)
        if resume is not None:
            print(f"resuming the unfinished run in {folder.root} from {resume}")
            train_settings = train_settings.with_ckpt_path(str(resume))
        folder.root.mkdir(parents=True, exist_ok=True)
        write_text(folder.config, OmegaConf.to_yaml(record if record is not None else settings_record(train_settings)))
        print(f"training {_experiment()} into {folder.root} (stages: {', '.join(schedule)})", flush=True)
        try:
            train(train_settings, folder.root)
        except TrainingStopped:
            print(f"the demo stopped; run the same command again to resume it from {folder.root}", file=sys.stderr)
            raise
        train_wall = time.time() - start
    t_eval = time.time()
    scores = score_run(train_settings, folder, out_dir, progress=not settings.quiet,
                       protocol_workers=settings.protocol_workers, calibrate=settings.calibrate,
                       recalibrate=settings.recalibrate, carving=settings.calibrate_carving)
    steps = folder.steps(schedule, {s: train_settings.stage.of(s).max_steps for s in schedule})
    report = scores.write(out_dir, fields={"steps": steps})
    timings = {"train_seconds": folder.train_seconds(schedule), "train_wall_seconds_this_command": train_wall,
               "eval_seconds": time.time() - t_eval, "total_seconds_this_command": time.time() - start,
               "resumed": resume is not None, "steps": steps}
    files = [*report.values(), *scores.pictures, write_json(out_dir / "timings.json", timings)]
    result = DemoResult(scores.table, json.loads(report["json"].read_text()), [str(f) for f in files], timings)
    _print_summary(result, out_dir)
    print(f"your own photo next: python -m svr.infer ckpt_path={folder.best_or_final(schedule[-1])} "
          f"images=PHOTO.jpg (docs/svr_inference.md)")
    return result


def _experiment() -> str:
    """``experiment=<name>`` as hydra composed it (the demo's own, unless the command line chose another)."""
    choices = HydraConfig.get().runtime.choices if HydraConfig.initialized() else {}
    return f"experiment={choices.get('experiment') or 'demo'}"


def _print_summary(result: DemoResult, out_dir: Path) -> None:
    timings = result.timings
    print()
    print(result.table)
    if timings["train_seconds"] is not None:
        print(f"training {timings['train_seconds'] / 60:.1f} min (the whole run"
              f"{', over resumes' if timings['resumed'] else ''}), evaluation {timings['eval_seconds'] / 60:.1f} min")
    steps = timings["steps"]
    print("steps (planned / reached): " + ", ".join(f"{k} {v['planned']} / {v['reached']}" for k, v in steps.items()))
    short = [k for k, v in steps.items() if v["reached"] is not None and v["reached"] < v["planned"]]
    if short:
        print(f"warning: the time cap stopped {', '.join(short)} early: this run trained less than its "
              f"schedule, so its table differs from the documented one (docs/demo.md, README)")
    print(f"outputs in {out_dir}:")
    for f in result.files:
        print(f"  {f}")


main = hydra_entry("demo", run)


if __name__ == "__main__":
    main()
