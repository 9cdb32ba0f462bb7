"""The CPU demo, ``python -m svr.demo`` (what ``make demo`` runs; configs/demo.yaml): trains
``experiment=demo`` from scratch on the procedural data into ``<out>/train`` (a stopped run resumes
with its saved config when the command runs again, a finished one is only evaluated again), then
scores it by the benchmark protocol with the coarse stage and every baseline as extra rows, and
writes into ``out``: the evaluation's files (``table.md``, ``table.csv``, ``iou.json``,
``per_object.csv``, ``per_image.csv``), ``timings.json`` (training seconds over resumes, this
command's wall and evaluation seconds, per stage the steps planned and reached),
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
from hydra.utils import instantiate
from omegaconf import OmegaConf

import renderer
from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.commands import hydra_entry
from sdfcommon.tooling.outputs import write_json, write_text
from sdfcommon.tooling.settings import settings_record
from svr.evaluation.baselines import BASELINES
from svr.evaluation.benchmark import add_baselines, evaluate
from svr.evaluation.tables import format_table, write_report
from svr.inference.checkpoints import CHECKPOINT_KEY, load_checkpoint, load_network
from svr.inference.prediction import load_model
from svr.inference.showcase import showcase
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
        protocol_workers: processes for the evaluation's mesh voxelisation (0: this one).
        quiet: no progress bars.
    """

    out: str
    eval_only: bool
    fresh: bool
    protocol_workers: int
    quiet: bool

    def __post_init__(self) -> None:
        if not self.out:
            raise ValueError("out must name the demo's folder")
        if self.eval_only and self.fresh:
            raise ValueError("eval_only=true and fresh=true contradict each other: choose one")
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


def evaluate_run(settings: TrainSettings, run: RunFolder, out_dir: Path, split: str = "test", progress: bool = True,
                 protocol_workers: int = 0) -> dict:
    """Scores a finished run with the benchmark protocol: its last stage's checkpoint, its coarse
    stage's and every baseline (``svr.evaluation.baselines``) on the same images; writes the
    evaluation's files, ``predictions.png`` and ``meshes/`` into ``out_dir``.

    Returns:
        ``{"table": markdown, "iou": the iou.json dict, "files": [paths]}``.
    """
    dm = instantiate(settings.data)
    dm.prepare_data()
    schedule = list(settings.stage.schedule)
    final_ckpt, coarse_ckpt = run.best_or_final(schedule[-1]), run.best_or_final(schedule[0])
    kwargs = dict(progress=progress, protocol_workers=protocol_workers)  # batches: the data's eval_batch_size
    model = load_model(final_ckpt, "cpu")
    result = evaluate(model, dm, split, **kwargs)
    extra = {}
    if coarse_ckpt != final_ckpt:
        extra["coarse stage alone"] = evaluate(load_model(coarse_ckpt, "cpu"), dm, split, **kwargs).table
    result = add_baselines(result, dm, BASELINES, model, progress=progress)
    label = f"ours ({schedule[-1]} stage, {result.output})"
    files = write_report(result, out_dir, extra_rows=extra, label=label)

    net, _ = load_network(final_ckpt)
    coarse_net, _ = load_network(coarse_ckpt)
    scene = (dm.shading.scene(effects=("shading",)) if dm.shading is not None else
             renderer.Scene(effects=("shading",), background=(1.0, 1.0, 1.0)))
    pictures = showcase(net, coarse_net, dm.dataset(split), dm.categories, scene, out_dir)
    summary = json.loads(Path(files["json"]).read_text())
    return {"table": format_table(result, extra, label), "iou": summary,
            "files": [str(p) for p in files.values()] + [str(p) for p in pictures]}


def stage_steps(settings: TrainSettings, run: RunFolder) -> dict[str, dict[str, Optional[int]]]:
    """Per scheduled stage, the steps planned and the steps its ``final.ckpt`` reached (None where
    the stage has not finished; fewer: the stage's time cap stopped it)."""
    out: dict[str, dict[str, Optional[int]]] = {}
    for stage in settings.stage.schedule:
        reached = int(load_checkpoint(run.final(stage))["global_step"]) if run.finished(stage) else None
        out[str(stage)] = {"planned": settings.stage.of(stage).max_steps, "reached": reached}
    return out


def resume_point(run_dir: Path, schedule: Sequence[str]) -> tuple[bool, Optional[Path]]:
    """Where a demo run left off: (finished, checkpoint to resume from): finished when the last
    scheduled stage wrote ``final.ckpt``; otherwise its latest checkpoint (None: start afresh)."""
    run = RunFolder(Path(run_dir))
    if run.finished(schedule[-1]):
        return True, run.final(schedule[-1])
    return False, run.latest_checkpoint(schedule)


def run_train_seconds(run_dir: Path, schedule: Sequence[str]) -> Optional[float]:
    """The whole run's training seconds: the sum of the ``train_seconds`` its stages' final
    checkpoints record (kept over resumes); None when a stage has not finished."""
    run = RunFolder(Path(run_dir))
    if not all(run.finished(stage) for stage in schedule):
        return None
    return sum(float(load_checkpoint(run.final(stage))[CHECKPOINT_KEY].get("train_seconds", 0.0))
               for stage in schedule)


def run(settings: DemoSettings, overrides: Optional[Sequence[str]] = None) -> dict:
    """The demo (see the module docstring).

    Args:
        settings: configs/demo.yaml's settings.
        overrides: the command line's overrides (default: hydra's); a resumed run may change only
            what ``svr.training.resume.RESUMABLE_KEYS`` allows of those naming training settings.
    Returns:
        {"table", "iou", "files"} and the timings.
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
    finished, resume = (False, None) if settings.fresh else resume_point(folder.root, schedule)
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
        print(f"training experiment=demo into {folder.root} (stages: {', '.join(schedule)})", flush=True)
        try:
            train(train_settings, folder.root)
        except TrainingStopped:
            print(f"the demo stopped; run the same command again to resume it from {folder.root}", file=sys.stderr)
            raise
        train_wall = time.time() - start
    t_eval = time.time()
    result = evaluate_run(train_settings, folder, out_dir, progress=not settings.quiet,
                          protocol_workers=settings.protocol_workers)
    steps = stage_steps(train_settings, folder)
    train_seconds = run_train_seconds(folder.root, schedule)
    timings = {"train_seconds": train_seconds, "train_wall_seconds_this_command": train_wall,
               "eval_seconds": time.time() - t_eval, "total_seconds_this_command": time.time() - start,
               "resumed": resume is not None, "steps": steps}
    result["files"].append(str(write_json(out_dir / "timings.json", timings)))
    iou_json = out_dir / "iou.json"
    write_json(iou_json, {**json.loads(iou_json.read_text()), "steps": steps})
    result["iou"]["steps"] = steps
    _print_summary(result, timings, out_dir)
    return {**result, **timings}


def _print_summary(result: dict, timings: dict, out_dir: Path) -> None:
    print()
    print(result["table"])
    if timings["train_seconds"] is not None:
        print(f"training {timings['train_seconds'] / 60:.1f} min (the whole run"
              f"{', over resumes' if timings['resumed'] else ''}), evaluation {timings['eval_seconds'] / 60:.1f} min")
    steps = timings["steps"]
    print("steps (planned / reached): " + ", ".join(f"{k} {v['planned']} / {v['reached']}" for k, v in steps.items()))
    short = [k for k, v in steps.items() if v["reached"] is not None and v["reached"] < v["planned"]]
    if short:
        print(f"warning: the time cap stopped {', '.join(short)} early: this run trained less than the demo's "
              f"schedule, so its table differs from docs/demo.md's")
    print(f"outputs in {out_dir}:")
    for f in result["files"]:
        print(f"  {f}")


main = hydra_entry("demo", run)


if __name__ == "__main__":
    main()
