"""Scores a finished training run the way the demo reports it: its last stage's checkpoint, its
coarse stage's and every baseline (``svr.evaluation.baselines``) on the same images by the benchmark
protocol, written as the evaluation's files beside the demo's pictures of predictions and meshes."""
from __future__ import annotations

import json
from pathlib import Path

from hydra.utils import instantiate

import renderer
from svr.evaluation.baselines import BASELINES
from svr.evaluation.benchmark import add_baselines, evaluate
from svr.evaluation.tables import format_table, write_report
from svr.inference.checkpoints import load_network
from svr.inference.prediction import load_model
from svr.inference.showcase import showcase
from svr.training.run_folder import RunFolder
from svr.training.settings import TrainSettings


def score_run(settings: TrainSettings, run: RunFolder, out_dir: Path, split: str = "test", progress: bool = True,
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


__all__ = ["score_run"]
