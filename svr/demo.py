"""The CPU demo: train ``experiment=demo`` from scratch on the procedural data, then evaluate it.

    python -m svr.demo [out=outputs/demo] [eval_only=true | fresh=true] [quiet=true] [train overrides ...]

configs/demo.yaml: configs/train.yaml with ``experiment=demo`` and the demo's own settings; ``run``
does the work, ``main`` is the hydra wrapper with the entry points' shared error handling (a
mistake is one line, exit status 2). A run that was stopped (SIGTERM: it saves a checkpoint and
exits with status 143) resumes from its last checkpoint, with its saved config, when the command is
run again; a finished run is only evaluated again. ``out`` is taken from the working directory.

Writes into ``out`` (default ``outputs/demo``; hydra's ``.hydra/`` and ``demo.log`` too):

* ``train/``: the training run (config.yaml, per-stage checkpoints and logs; svr/train.py);
* the evaluation script's files (``svr.evaluate``: the benchmark IoU protocol, every view of every
  test object): ``table.md`` / ``table.csv`` in the paper's layout (categories as columns, mean
  last) with the full model, the coarse stage alone and every baseline of ``svr.evaluation.baselines`` (mean
  shape, category mean shape, retrieval, the oracle) as rows, and ours minus retrieval;
  ``iou.json`` (``{"split", "categories", "mean", ...}``, the coarse stage under ``"extra"``, the
  baselines under ``"baselines"``); ``per_object.csv`` and ``per_image.csv``;
* ``timings.json``: the whole run's training seconds (over resumes: each stage's checkpointed
  training time), this command's wall seconds, evaluation seconds, and per stage the steps planned
  and reached (fewer reached: the stage's time cap stopped it; also in ``iou.json``);
* ``predictions.png``: per category one test input beside renders of the predictions;
* ``meshes/*.ply``: marching-cubes meshes of the full model's predictions for those inputs.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any, Optional, Sequence

import torch
from omegaconf import DictConfig, OmegaConf

from sdfcommon.tooling.commands import hydra_entry


# ------------------------------------------------------------------------------------------------
# Pictures and meshes


@torch.no_grad()
def showcase(net, coarse_net, dataset, categories: Sequence[tuple[str, str]], scene, out_dir: Path,
             views: Sequence[int] = (0,)) -> list[Path]:
    """For the first test object of each category: a PNG row (input, the coarse stage's and the
    full model's predictions rendered from the input view, the full model's from 90 and 180 degrees
    further round) and the full model's marching-cubes mesh (.ply).

    Returns:
        the files written (the PNG first).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sdfcommon.numerics.meshing import sdf_to_mesh

    from svr.data.nmr import NUM_VIEWS
    from svr.inference.prediction import LoadedModel, predict_sdf
    from svr.view_renders import render_views

    net.eval()
    coarse_net.eval()
    mesh_dir = out_dir / "meshes"
    mesh_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    rows = []
    for c, (cid, name) in enumerate(categories):
        if dataset.counts[c] == 0:
            continue
        obj = int(dataset.offsets[c])
        for v in views:
            image = dataset.views(obj, [v])  # (1, 4, 64, 64)
            final = predict_sdf(LoadedModel(net), image).final  # what the evaluation scored
            coarse = predict_sdf(LoadedModel(coarse_net), image, refine=False).coarse
            hs = net.half_side
            shots = []
            for sdf, view in ((coarse, v), (final, v), (final, v + 6), (final, v + 12)):
                _, colours = render_views(sdf, hs, torch.tensor([[view % NUM_VIEWS]]), scene, 64)
                shots.append(colours[0, 0].permute(1, 2, 0).clamp(0, 1).numpy())
            rows.append((f"{name} #0 view {v}", image[0, :3].permute(1, 2, 0).numpy(), shots))
            mesh = sdf_to_mesh(final[0], -hs, hs)
            path = mesh_dir / f"{name}_test0_view{v}.ply"
            mesh.export(path)
            written.append(path)
    titles = ["input", "coarse stage", "full model", "full, +90°", "full, +180°"]
    fig, axes = plt.subplots(len(rows), 5, figsize=(5 * 1.6, len(rows) * 1.7), squeeze=False)
    for r, (label, inp, shots) in enumerate(rows):
        for k, img in enumerate([inp] + shots):
            ax = axes[r, k]
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(titles[k], fontsize=8)
        axes[r, 0].set_ylabel(label, fontsize=7)
    fig.tight_layout()
    png = out_dir / "predictions.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return [png] + written


# ------------------------------------------------------------------------------------------------
# The driver


def stage_checkpoint(run_dir: Path, stage: str) -> Path:
    """A finished stage's best checkpoint (by validation IoU), else its final one."""
    d = Path(run_dir) / stage / "checkpoints"
    for name in ("best.ckpt", "final.ckpt"):
        if (d / name).is_file():
            return d / name
    raise FileNotFoundError(f"no best.ckpt or final.ckpt in {d}: has the {stage} stage run?")


def evaluate_run(cfg, run_dir: Path, out_dir: Path, split: str = "test", progress: bool = True,
                 protocol_workers: int = 0) -> dict:
    """Scores a finished demo run with the benchmark protocol (``svr.evaluate``): its last stage's
    checkpoint, its coarse stage's checkpoint and every baseline (``svr.evaluation.baselines``), on the same images.

    Writes into ``out_dir`` the evaluation script's files (``table.md``, ``table.csv``,
    ``iou.json`` with the coarse stage under ``"extra"`` and the baselines under ``"baselines"``,
    ``per_object.csv``, ``per_image.csv``),
    ``predictions.png`` and ``meshes/``.

    Returns:
        ``{"table": markdown, "iou": the iou.json dict, "files": [paths]}``.
    """
    from hydra.utils import instantiate

    from svr.evaluation.baselines import BASELINES
    from svr.inference.checkpoints import load_network
    from svr.evaluation.benchmark import add_baselines, evaluate
    from svr.inference.prediction import load_model
    from svr.evaluation.tables import format_table, write_report

    dm = instantiate(cfg.data)
    dm.prepare_data()
    schedule = list(cfg.stage.schedule)
    final_ckpt, coarse_ckpt = stage_checkpoint(run_dir, schedule[-1]), stage_checkpoint(run_dir, schedule[0])
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
    scene = dm.shading.scene(effects=("shading",)) if dm.shading is not None else None
    if scene is None:
        import renderer

        scene = renderer.Scene(effects=("shading",), background=(1.0, 1.0, 1.0))
    pictures = showcase(net, coarse_net, dm.dataset(split), dm.categories, scene, out_dir)
    summary = json.loads(Path(files["json"]).read_text())
    return {"table": format_table(result, extra, label), "iou": summary,
            "files": [str(p) for p in files.values()] + [str(p) for p in pictures]}


def stage_steps(cfg, run_dir: Path) -> dict[str, dict[str, Optional[int]]]:
    """Per scheduled stage, the steps its config planned and the steps its ``final.ckpt`` reached
    (None where the stage has not finished). A stage that reached fewer was stopped by its time cap
    (``stage.<name>.max_time``): that run trained less than the demo's schedule."""
    from svr.inference.checkpoints import load_checkpoint

    out: dict[str, dict[str, Optional[int]]] = {}
    for stage in cfg.stage.schedule:
        final = Path(run_dir) / stage / "checkpoints" / "final.ckpt"
        reached = int(load_checkpoint(final)["global_step"]) if final.is_file() else None
        out[str(stage)] = {"planned": int(cfg.stage[stage].max_steps), "reached": reached}
    return out


def resume_point(run_dir: Path, schedule: Sequence[str]) -> tuple[bool, Optional[Path]]:
    """Where a demo run left off: (finished, checkpoint to resume from).

    Finished when the last scheduled stage wrote ``final.ckpt``; otherwise the latest checkpoint
    of the latest stage that wrote one (``svr.training.resume.latest_checkpoint``; None: start afresh).
    """
    from svr.training.resume import latest_checkpoint

    if (Path(run_dir) / schedule[-1] / "checkpoints" / "final.ckpt").is_file():
        return True, Path(run_dir) / schedule[-1] / "checkpoints" / "final.ckpt"
    return False, latest_checkpoint(run_dir, schedule)


def run_train_seconds(run_dir: Path, schedule: Sequence[str]) -> Optional[float]:
    """The whole run's training seconds: the sum over its stages of the ``train_seconds`` their
    final checkpoints record (kept over resumes, so a run stopped and resumed counts every part).
    None when a stage has not finished."""
    from svr.inference.checkpoints import CHECKPOINT_KEY, load_checkpoint

    total = 0.0
    for stage in schedule:
        final = Path(run_dir) / stage / "checkpoints" / "final.ckpt"
        if not final.is_file():
            return None
        total += float(load_checkpoint(final)[CHECKPOINT_KEY].get("train_seconds", 0.0))
    return total


DEMO_KEYS = ("out", "eval_only", "fresh", "protocol_workers", "quiet")  # configs/demo.yaml's own settings
QUIET = {"data.progress": False, "trainer.enable_progress_bar": False, "callbacks.progress_bar": None}


def split_config(cfg: DictConfig) -> tuple[dict[str, Any], DictConfig]:
    """configs/demo.yaml composed -> (the demo's own settings, checked; the training config)."""
    from sdfcommon.tooling.commands import config_bool, config_int, config_value

    opts = {"out": config_value(cfg, "out"), "eval_only": config_bool(cfg, "eval_only"),
            "fresh": config_bool(cfg, "fresh"), "protocol_workers": config_int(cfg, "protocol_workers", minimum=0),
            "quiet": config_bool(cfg, "quiet")}
    if opts["out"] in (None, ""):
        raise ValueError("out must name the demo's folder")
    if opts["eval_only"] and opts["fresh"]:
        raise ValueError("eval_only=true and fresh=true contradict each other: choose one")
    train_cfg = OmegaConf.masked_copy(cfg, [k for k in cfg.keys() if k not in DEMO_KEYS])
    if opts["quiet"]:
        for key, value in QUIET.items():
            OmegaConf.update(train_cfg, key, value, merge=False)
    return opts, train_cfg


def demo_config(run_dir: Path, cfg: DictConfig, overrides: Sequence[str], fresh: bool) -> DictConfig:
    """The training config: ``cfg`` (experiment=demo with the overrides); for a run already in
    ``run_dir`` (unless ``fresh``), that run's ``config.yaml`` with the changes a resume may make
    (``svr.training.resume.resume_config``: other changed settings are refused, naming them)."""
    from svr.training.resume import resume_config

    saved = Path(run_dir) / "config.yaml"
    if fresh or not saved.is_file():
        return cfg
    merged, changes = resume_config(OmegaConf.load(saved), cfg, list(overrides))
    for change in changes:
        print(f"warning: resuming {run_dir} with a changed setting: {change}")
    return merged


def run(cfg: DictConfig, overrides: Optional[Sequence[str]] = None) -> dict:
    """The demo (see the module docstring) from a composed configs/demo.yaml.

    Args:
        cfg: configs/demo.yaml with the command line's overrides.
        overrides: those overrides (default: hydra's, inside a hydra run); a resumed run may change
            only what ``svr.training.resume.RESUMABLE_KEYS`` allows of the ones that name training settings.
    Returns:
        {"table", "iou", "files"} and the timings.
    """
    if overrides is None:
        from hydra.core.hydra_config import HydraConfig

        overrides = list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []
    opts, train_cfg = split_config(cfg)
    requested = [o for o in overrides if o.lstrip("+~").split("=", 1)[0] not in DEMO_KEYS]
    if opts["quiet"]:
        requested += [f"{k}={'null' if v is None else str(v).lower()}" for k, v in QUIET.items()]
    out_dir = Path(opts["out"]).expanduser().resolve()  # from the working directory, as every command
    run_dir = out_dir / "train"
    cfg = demo_config(run_dir, train_cfg, requested, opts["fresh"])
    schedule = list(cfg.stage.schedule)
    start = time.time()
    train_wall = None
    finished, resume = (False, None) if opts["fresh"] else resume_point(run_dir, schedule)
    if opts["eval_only"]:
        if not finished:
            raise ValueError(f"eval_only=true needs a finished run in {run_dir} "
                             f"(no {schedule[-1]}/checkpoints/final.ckpt)")
    elif finished:
        print(f"{run_dir} holds a finished run: evaluating it (fresh=true trains again)")
    else:
        from svr.training.stages import TrainingStopped, train

        if opts["fresh"] and run_dir.exists():
            import shutil

            shutil.rmtree(run_dir)
        if resume is not None:
            print(f"resuming the unfinished run in {run_dir} from {resume}")
            cfg.ckpt_path = str(resume)
        print(f"training experiment=demo into {run_dir} (stages: {', '.join(schedule)})", flush=True)
        try:
            train(cfg, run_dir)
        except TrainingStopped:
            print(f"the demo stopped; run the same command again to resume it from {run_dir}", file=sys.stderr)
            raise
        train_wall = time.time() - start
    t_eval = time.time()
    result = evaluate_run(cfg, run_dir, out_dir, progress=not opts["quiet"], protocol_workers=opts["protocol_workers"])
    steps = stage_steps(cfg, run_dir)
    train_seconds = run_train_seconds(run_dir, schedule)
    timings = {"train_seconds": train_seconds, "train_wall_seconds_this_command": train_wall,
               "eval_seconds": time.time() - t_eval, "total_seconds_this_command": time.time() - start,
               "resumed": resume is not None, "steps": steps}
    from sdfcommon.tooling.outputs import write_json

    result["files"].append(str(write_json(out_dir / "timings.json", timings)))
    iou_json = out_dir / "iou.json"
    write_json(iou_json, {**json.loads(iou_json.read_text()), "steps": steps})
    result["iou"]["steps"] = steps
    print()
    print(result["table"])
    if train_seconds is not None:
        print(f"training {train_seconds / 60:.1f} min (the whole run{', over resumes' if resume else ''}), "
              f"evaluation {timings['eval_seconds'] / 60:.1f} min")
    print("steps (planned / reached): " + ", ".join(f"{k} {v['planned']} / {v['reached']}" for k, v in steps.items()))
    short = [k for k, v in steps.items() if v["reached"] is not None and v["reached"] < v["planned"]]
    if short:
        print(f"warning: the time cap stopped {', '.join(short)} early: this run trained less than the demo's "
              f"schedule, so its table differs from the README's")
    print(f"outputs in {out_dir}:")
    for f in result["files"]:
        print(f"  {f}")
    return {**result, **timings}


main = hydra_entry("svr.demo", "demo", run)


if __name__ == "__main__":
    main()
