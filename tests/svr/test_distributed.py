"""Several processes: rank-aware samplers, gathering, a 2-process CPU DDP training run (gloo, Lightning's
own strategy) and distributed evaluation, and the memory-mapped data shared between processes.

The DDP run is ``python train.py trainer=ddp_cpu`` in a subprocess, exactly as a user starts it: Lightning
starts the second process itself. ``RankProbe`` (a callback added on the command line) records in each
process what it trained on, its weights and its validation results.
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import pytorch_lightning as pl
import torch

from svr.data.datamodules import ProceduralDataModule
from svr.data.samplers import EvalShardSampler, ObjectViewSampler, RankShardedSampler
from svr.distributed import RankInfo, gather_unique, gather_uneven, launch_rank_is_zero, shard_indices

REPO = Path(__file__).resolve().parents[2]
CONFIGS = str(REPO / "configs")

# The session's tiny procedural set (tests/svr/conftest.py: chair, mug, lamp; 2/1/1 objects; seed 3).
# Three val objects x 3 views = 9 images: uneven over 2 ranks (5 + 4, padded to 5 + 5).
VAL_VIEWS = [0, 12, 18]
EVAL_VIEWS = [0, 5, 10]
SAMPLES_PER_EPOCH = 4   # 2 per rank = 1 batch of 2: the 2 steps span 2 epochs
STEPS = 2
LAUNCH_VARS = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "LOCAL_WORLD_SIZE", "NODE_RANK", "GROUP_RANK", "GROUP_WORLD_SIZE",
               "MASTER_ADDR", "MASTER_PORT", "PL_GLOBAL_SEED")


class RankProbe(pl.Callback):
    """Records, per process, into ``<folder>/rank<global rank>.pt``: the world size, every training
    batch's (epoch, category, object, views), the network's state at the start and the end, the
    skipped steps, and each validation's ``val/iou`` with the (category, object, view) items this rank
    scored. ``poison_rank``: that rank's first batch becomes NaN (its step is not finite)."""

    def __init__(self, folder: str, poison_rank: int = -1) -> None:
        self.folder = Path(folder)
        self.poison_rank = poison_rank
        self.batches: list[dict[str, Any]] = []
        self.validations: list[dict[str, Any]] = []
        self.start: dict[str, torch.Tensor] = {}

    def on_train_start(self, trainer, pl_module) -> None:
        self.start = {k: v.detach().clone() for k, v in pl_module.net.state_dict().items()}

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self.batches.append({"epoch": trainer.current_epoch, "category": batch.category.tolist(),
                             "object": batch.object_index.tolist(), "views": batch.view_ids.tolist()})
        if trainer.global_rank == self.poison_rank and trainer.global_step == 0:
            batch.images.fill_(float("nan"))

    def on_validation_end(self, trainer, pl_module) -> None:
        keys = torch.cat(pl_module._val_key).tolist() if pl_module._val_key else []
        self.validations.append({"iou": float(trainer.callback_metrics["val/iou"]), "keys": keys,
                                 "images": int(trainer.callback_metrics["val/images"])})

    def on_train_end(self, trainer, pl_module) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        torch.save({"rank": trainer.global_rank, "world_size": trainer.world_size,
                    "strategy": type(trainer.strategy).__name__, "batches": self.batches,
                    "validations": self.validations, "start": self.start, "skipped": pl_module.skipped_steps,
                    "end": {k: v.detach().clone() for k, v in pl_module.net.state_dict().items()}},
                   self.folder / f"rank{trainer.global_rank}.pt")


def clean_env() -> dict[str, str]:
    """This environment without launcher variables (a test run inside a DDP or SLURM job stays alone)."""
    return {k: v for k, v in os.environ.items() if k not in LAUNCH_VARS and not k.startswith("SLURM_")}


def data_overrides(cache: Path, settings) -> list[str]:
    return [f"data.cache_dir={cache}", f"data.categories=[{','.join(settings.categories)}]",
            f"data.train={settings.train}", f"data.val={settings.val}", f"data.test={settings.test}",
            f"data.data_seed={settings.seed}", f"data.supersample={settings.supersample}", "data.progress=false"]


def datamodule(cache: Path, settings, **kwargs) -> ProceduralDataModule:
    return ProceduralDataModule(cache_dir=cache, categories=list(settings.categories), train=settings.train,
                                val=settings.val, test=settings.test, data_seed=settings.seed,
                                supersample=settings.supersample, progress=False, **kwargs)


# ------------------------------------------------------------------------------------------------
# sharding and gathering (one process)


@pytest.mark.parametrize("world", [1, 2, 3, 4])
def test_shards_cover_every_item_once_or_pad_to_equal_sizes(world):
    for n in range(0, 14):
        plain = [shard_indices(n, r, world) for r in range(world)]
        assert np.concatenate(plain).tolist() == list(range(n))  # each once, in order
        assert max(map(len, plain)) - min(map(len, plain)) <= 1
        padded = [shard_indices(n, r, world, pad=True) for r in range(world)]
        assert len({len(p) for p in padded}) == 1 and len(padded[0]) == -(-n // world)
        flat = np.concatenate(padded).tolist()
        assert flat[:n] == list(range(n)) and set(flat) == set(range(n))  # the extra items are repeats
    with pytest.raises(ValueError, match="rank"):
        shard_indices(5, 2, 2)
    with pytest.raises(ValueError, match="world_size"):
        shard_indices(5, 0, 0)
    with pytest.raises(ValueError, match="num_items"):
        shard_indices(-1, 0, 1)


def test_training_sampler_ranks_take_disjoint_parts_of_one_stream():
    counts, n, world = [3, 0, 5], 40, 3
    whole = ObjectViewSampler(counts, 2, n, seed=7, rank=0, world_size=1)
    ranks = [ObjectViewSampler(counts, 2, n, seed=7, rank=r, world_size=world) for r in range(world)]
    for epoch in (0, 1):
        for s in (whole, *ranks):
            s.set_epoch(epoch)
        stream = list(whole)
        parts = [list(s) for s in ranks]
        assert [len(p) for p in parts] == [n // world] * world == [len(s) for s in ranks]
        for r, part in enumerate(parts):
            assert part == stream[r:world * (n // world):world]
        assert len({p[0] for p in parts}) == world  # different data from the first batch on
    whole.set_epoch(0)
    assert list(whole) == list(ObjectViewSampler(counts, 2, n, seed=7))  # one process: as before
    with pytest.raises(ValueError, match="samples_per_epoch"):
        len(ObjectViewSampler(counts, 2, 2, rank=0, world_size=3))
    with pytest.raises(ValueError, match="rank"):
        ObjectViewSampler(counts, rank=3, world_size=3)
    with pytest.raises(ValueError, match="rank"):
        ObjectViewSampler(counts, rank=1)


def test_samplers_are_left_alone_by_lightning():
    """Lightning replaces or wraps (and pads) any sampler that is not a DistributedSampler."""
    from torch.utils.data.distributed import DistributedSampler

    for s in (ObjectViewSampler([2], 2, 4), EvalShardSampler(5)):
        assert isinstance(s, RankShardedSampler) and isinstance(s, DistributedSampler)
        assert (s.rank, s.num_replicas) == (0, 1)  # no process group: one process
    assert list(EvalShardSampler(9, pad=True, rank=1, world_size=2)) == [5, 6, 7, 8, 0]
    assert list(EvalShardSampler(9, pad=False, rank=1, world_size=2)) == [4, 5, 6, 7, 8]
    with pytest.raises(ValueError, match="num_items"):
        EvalShardSampler(-1)


def test_gather_unique_keeps_the_first_of_repeated_items():
    keys = torch.tensor([[0, 0, 1], [1, 0, 2], [0, 0, 1], [0, 1, 0]])
    iou = torch.tensor([0.5, 0.25, 0.5, 0.75], dtype=torch.float64)
    k, v = gather_unique(keys, iou)
    assert k.tolist() == [[0, 0, 1], [1, 0, 2], [0, 1, 0]] and v.tolist() == [0.5, 0.25, 0.75]
    assert gather_uneven(iou) is iou  # no process group
    with pytest.raises(ValueError, match="keys"):
        gather_unique(torch.zeros(3, dtype=torch.long), iou)
    with pytest.raises(ValueError, match="values"):
        gather_unique(keys, iou[:2])


def test_rank_zero_before_a_process_group(monkeypatch):
    for var in LAUNCH_VARS + ("SLURM_PROCID",):
        monkeypatch.delenv(var, raising=False)
    assert launch_rank_is_zero()
    monkeypatch.setenv("SLURM_PROCID", "0")
    monkeypatch.setenv("LOCAL_RANK", "1")  # a process Lightning started inside an interactive SLURM shell
    assert not launch_rank_is_zero()
    monkeypatch.setenv("LOCAL_RANK", "0")
    monkeypatch.setenv("NODE_RANK", "1")
    assert not launch_rank_is_zero()
    monkeypatch.setenv("RANK", "0")  # torchrun
    assert launch_rank_is_zero()
    with pytest.raises(ValueError, match="rank and world_size"):
        RankInfo.resolve(rank=0)


def test_process_group_from_the_launchers_environment(monkeypatch):
    from svr.distributed import environment_ranks

    for var in LAUNCH_VARS:
        monkeypatch.delenv(var, raising=False)
    for var in [v for v in os.environ if v.startswith("SLURM_")]:
        monkeypatch.delenv(var)
    assert environment_ranks() is None  # a single process
    monkeypatch.setenv("SLURM_PROCID", "0")
    monkeypatch.setenv("SLURM_NTASKS", "8")  # a batch script's own shell: not an srun step
    assert environment_ranks() is None
    monkeypatch.setenv("SLURM_STEP_NUM_TASKS", "8")
    monkeypatch.setenv("SLURM_PROCID", "5")
    monkeypatch.setenv("SLURM_STEP_NODELIST", "gpu[12-13]")
    monkeypatch.setenv("SLURM_JOB_ID", "123456")
    assert environment_ranks() == (5, 8, "gpu12", 18456)
    for var, value in (("RANK", "3"), ("WORLD_SIZE", "4"), ("MASTER_ADDR", "node0"), ("MASTER_PORT", "29501")):
        monkeypatch.setenv(var, value)  # torchrun's variables win
    assert environment_ranks() == (3, 4, "node0", 29501)


def test_ddp_configs_compose(monkeypatch):
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate
    from pytorch_lightning.strategies import DDPStrategy

    for var in ("SLURM_NTASKS_PER_NODE", "SLURM_NNODES", "LOCAL_WORLD_SIZE", "GROUP_WORLD_SIZE"):
        monkeypatch.delenv(var, raising=False)
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        gpu = compose("train", overrides=["trainer=ddp"])
        cpu = compose("train", overrides=["trainer=ddp_cpu"])
    assert gpu.trainer.strategy == "ddp" and gpu.trainer.accelerator == "gpu"
    assert (gpu.trainer.devices, gpu.trainer.num_nodes) == (-1, 1)
    monkeypatch.setenv("SLURM_NTASKS_PER_NODE", "4")  # Lightning insists on devices == --ntasks-per-node
    monkeypatch.setenv("SLURM_NNODES", "2")
    assert (gpu.trainer.devices, gpu.trainer.num_nodes) == (4, 2)
    trainer = instantiate(cpu.trainer, max_steps=1, logger=False)
    assert isinstance(trainer.strategy, DDPStrategy) and trainer.world_size == 2
    assert (cpu.trainer.devices, cpu.trainer.num_nodes) == (2, 1)  # not from the environment


def test_slurm_launcher_config_composes():
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher", reason="pip install -e .[slurm]")
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose("train", overrides=["hydra/launcher=slurm", "trainer=ddp"], return_hydra_config=True)
    launcher = cfg.hydra.launcher
    assert launcher._target_.endswith("SlurmLauncher")
    assert launcher.tasks_per_node == launcher.gpus_per_node  # one task per GPU


# ------------------------------------------------------------------------------------------------
# a 2-process CPU DDP run


@pytest.fixture(scope="module")
def ddp_run(tmp_path_factory, tiny_procedural) -> dict[str, Any]:
    """``python train.py trainer=ddp_cpu``: 2 processes (gloo), 2 coarse steps over 2 epochs, one
    validation at the end; rank 1's first batch is NaN. About 45 s on 2 cores, so its tests are
    `slow`; the samplers' sharding and the gathers stay in the default suite."""
    cache, _, settings = tiny_procedural
    root = tmp_path_factory.mktemp("ddp")
    run, probe = root / "run", root / "probe"
    cmd = [sys.executable, str(REPO / "train.py"), "trainer=ddp_cpu", "stage=coarse", f"stage.coarse.max_steps={STEPS}",
           "stage.coarse.optimizer.lr=0.01", "model=tiny", "loss.render_size=16", "loss.trace.max_steps=64",
           *data_overrides(cache, settings),
           f"data.samples_per_epoch={SAMPLES_PER_EPOCH}", "data.batch_size=2", "data.eval_batch_size=2",
           f"data.val_views=[{','.join(map(str, VAL_VIEWS))}]", f"trainer.val_check_interval={STEPS}",
           "trainer.log_every_n_steps=1", "trainer.enable_progress_bar=false", "trainer.enable_model_summary=false",
           "callbacks.progress_bar=null", "callbacks.lr_monitor=null", "callbacks.image_logger.every_n_steps=1",
           "logger=csv", f"+callbacks.probe._target_={__name__}.RankProbe", f"+callbacks.probe.folder={probe}",
           "+callbacks.probe.poison_rank=1",
           f"hydra.run.dir={run}"]
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=REPO, env=clean_env(), capture_output=True, text=True, timeout=300)
    seconds = time.perf_counter() - start
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    ranks = [torch.load(probe / f"rank{r}.pt", weights_only=False) for r in range(2)]
    return {"run": run, "ranks": ranks, "seconds": seconds, "cache": cache, "settings": settings,
            "output": proc.stdout + proc.stderr}


@pytest.mark.slow
def test_ddp_run_finishes_with_one_set_of_outputs(ddp_run):
    run = ddp_run["run"]
    for r, probe in enumerate(ddp_run["ranks"]):
        assert (probe["rank"], probe["world_size"], probe["strategy"]) == (r, 2, "DDPStrategy")
    ckpts = run / "coarse" / "checkpoints"
    assert (ckpts / "final.ckpt").is_file() and (ckpts / "best.ckpt").is_file()
    assert (run / "config.yaml").is_file() and (run / "coarse" / "csv" / "metrics.csv").is_file()
    assert list((run / "coarse" / "images").glob("step_*.png"))
    # Lightning's launcher reruns train.py in the same folder: one hydra folder, no per-rank outputs
    # (each process has its own log file).
    assert sorted(p.name for p in run.iterdir() if p.suffix != ".log") == [".hydra", "coarse", "config.yaml"]
    assert sorted(p.name for p in ckpts.iterdir()) == ["best.ckpt", "final.ckpt", "last.ckpt"]


@pytest.mark.slow
def test_ddp_ranks_see_different_parts_of_one_stream(ddp_run):
    """Each rank trains on its own slice of the single-process stream (seeded by seed + epoch): every
    key once across ranks, none twice. Were Lightning to wrap the samplers, the slices would differ."""
    settings = ddp_run["settings"]
    offsets = np.concatenate([[0], np.cumsum([settings.train] * len(settings.categories))])
    whole = ObjectViewSampler([settings.train] * len(settings.categories), 2, SAMPLES_PER_EPOCH, seed=0,
                              rank=0, world_size=1)
    seen = []
    for r, probe in enumerate(ddp_run["ranks"]):
        keys = [(b["epoch"], int(offsets[c]) + o, tuple(v))
                for b in probe["batches"] for c, o, v in zip(b["category"], b["object"], b["views"])]
        assert len(keys) == STEPS * 2  # 2 steps x batch 2 on every rank
        expected = []
        for epoch in sorted({k[0] for k in keys}):
            whole.set_epoch(epoch)
            expected += [(epoch, obj, views) for obj, views in list(whole)[r::2]]
        assert keys == expected
        seen.append(keys)
    assert {k[0] for k in seen[0]} == {0, 1}  # the run crossed an epoch boundary
    assert all(a != b for a, b in zip(seen[0], seen[1]))  # different data at every step


@pytest.mark.slow
def test_ddp_gradients_are_synchronised(ddp_run):
    """The weights are equal on both ranks after the steps, also after a step that was not finite on
    rank 1 only: both ranks skipped it."""
    r0, r1 = ddp_run["ranks"]
    assert r0["skipped"] == r1["skipped"] == 1
    assert "the step is not finite on another process" in ddp_run["output"]
    assert r0["end"].keys() == r1["end"].keys()
    for k in r0["end"]:
        assert torch.equal(r0["end"][k], r1["end"][k]), f"{k} differs between the ranks"
    moved = [k for k in r0["end"] if r0["end"][k].is_floating_point() and not torch.equal(r0["start"][k], r0["end"][k])]
    assert any(k.startswith("encoder.") for k in moved) and any(k.startswith("decoder.") for k in moved)


@pytest.mark.slow
def test_ddp_validation_counts_each_image_once_and_matches_one_process(ddp_run):
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    from svr.inference.checkpoints import load_checkpoint, load_network_weights
    from sdfcommon.tooling.settings import build_settings
    from svr.training.stages import build_module

    r0, r1 = ddp_run["ranks"]
    assert len(r0["validations"]) == len(r1["validations"]) == 1
    v0, v1 = r0["validations"][0], r1["validations"][0]
    # 9 images, uneven over 2 ranks: padded to 5 + 5, the repeat dropped when gathering.
    assert len(v0["keys"]) == len(v1["keys"]) == 5
    images = {tuple(k) for k in v0["keys"] + v1["keys"]}
    assert len(images) == 3 * len(VAL_VIEWS) and {k[2] for k in images} == set(VAL_VIEWS)
    assert v0["images"] == v1["images"] == 3 * len(VAL_VIEWS)  # the means are over 9 images, not 10
    assert v0["iou"] == v1["iou"]

    cache, settings = ddp_run["cache"], ddp_run["settings"]
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        cfg = compose("train", overrides=["model=tiny", "loss.render_size=16", "trainer=cpu",
                                          *data_overrides(cache, settings), "data.eval_batch_size=4",
                                          f"data.val_views=[{','.join(map(str, VAL_VIEWS))}]"])
    dm = instantiate(cfg.data)
    net = instantiate(cfg.model)
    best = ddp_run["run"] / "coarse" / "checkpoints" / "best.ckpt"
    load_network_weights(net, load_checkpoint(best), best)
    module = build_module(build_settings(cfg), net, "coarse", dm)
    trainer = pl.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                         enable_model_summary=False, enable_checkpointing=False)
    single = trainer.validate(module, datamodule=dm, verbose=False)[0]
    assert single["val/images"] == 3 * len(VAL_VIEWS)
    assert v0["iou"] == pytest.approx(single["val/iou"], abs=1e-6)


@pytest.mark.slow
def test_distributed_evaluation_matches_one_process(ddp_run, tmp_path):
    """torchrun, 2 processes, 9 images (5 + 4): the same files as a single-process evaluation."""
    from svr.evaluation.baselines import BASELINES
    from svr.evaluation.protocol import add_baselines, evaluate
    from svr.inference.prediction import load_model
    from svr.evaluation.tables import write_report

    cache, settings = ddp_run["cache"], ddp_run["settings"]
    ckpt = ddp_run["run"] / "coarse" / "checkpoints" / "final.ckpt"
    out = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", "-m", "svr.evaluate",
           f"ckpt_path={ckpt}", f"output_dir={out}", f"views=[{','.join(map(str, EVAL_VIEWS))}]", "device=cpu",
           "progress=false", "batch_size=2", f"hydra.run.dir={tmp_path / 'hydra'}", *data_overrides(cache, settings)]
    env = clean_env()
    env["OMP_NUM_THREADS"] = "1"
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    assert "and 1 more processes" in proc.stdout
    assert proc.stdout.count("wrote ") == 1  # rank 0 alone prints and writes

    model, dm = load_model(ckpt, "cpu"), datamodule(cache, settings)
    result = evaluate(model, dm, "test", views=EVAL_VIEWS, batch_size=4, progress=False)
    assert len(result.iou) == 3 * len(EVAL_VIEWS)
    result = add_baselines(result, dm, BASELINES, model, progress=False)  # as the command line does by default
    write_report(result, tmp_path / "single")
    for name in ("table.md", "table.csv", "per_image.csv", "per_object.csv"):
        assert (out / name).read_text() == (tmp_path / "single" / name).read_text(), name
    ddp_json, single_json = (json.loads((d / "iou.json").read_text()) for d in (out, tmp_path / "single"))
    ddp_json.pop("seconds"), single_json.pop("seconds")
    assert ddp_json == single_json


@pytest.mark.slow
def test_evaluate_distributed_needs_a_process_group(ddp_run):
    from svr.evaluation.protocol import evaluate
    from svr.inference.prediction import load_model

    ckpt = ddp_run["run"] / "coarse" / "checkpoints" / "final.ckpt"
    with pytest.raises(ValueError, match="distributed"):
        evaluate(load_model(ckpt, "cpu"), datamodule(ddp_run["cache"], ddp_run["settings"]), "test", views=[0],
                 progress=False, distributed=True)


# ------------------------------------------------------------------------------------------------
# memory: the memory-mapped arrays are shared by the processes of a node

CHILD = r"""
import sys
from svr.data.datasets import NMRDataset

def wait(tag):
    print(tag, flush=True)
    assert sys.stdin.readline().strip() == "go"

wait("imported")
ds = NMRDataset(sys.argv[1], "train", categories=sys.argv[2].split(","), require_prepared=True)
for i in range(len(ds)):           # every byte of both arrays, through the dataset's own reads
    ds.images_uint8(i)
    ds.voxels(i)
wait("touched")
"""


def _memory(pid: int, folder: Path) -> dict[str, int]:
    """Bytes: the process's private (USS) memory (smaps_rollup), and Rss, Pss and private memory of
    its mappings of files under ``folder`` (smaps)."""
    out = {"private": 0, "data_rss": 0, "data_pss": 0, "data_private": 0}
    for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in ("Private_Clean", "Private_Dirty"):
            out["private"] += int(value.split()[0]) * 1024
    in_folder = False
    for line in Path(f"/proc/{pid}/smaps").read_text().splitlines():
        if re.match(r"^[0-9a-f]+-[0-9a-f]+ ", line):
            fields = line.split(maxsplit=5)
            in_folder = len(fields) == 6 and fields[5].startswith(str(folder))
        elif in_folder:
            name, _, value = line.partition(":")
            if name in ("Rss", "Pss"):
                out[f"data_{name.lower()}"] += int(value.split()[0]) * 1024
            elif name in ("Private_Clean", "Private_Dirty"):
                out["data_private"] += int(value.split()[0]) * 1024
    return out


@pytest.mark.skipif(not Path("/proc/self/smaps_rollup").exists(), reason="needs Linux /proc/<pid>/smaps_rollup")
def test_memory_mapped_data_is_shared_by_processes(tmp_path):
    """Three processes open the same prepared (memory-mapped) dataset and read all of it. First one
    alone, then the other two: the memory the data costs, summed over the processes, stays the size
    of the data plus a small overhead per process, instead of growing by the data size with every
    process. The cost is counted as the Pss of the data's mappings (a page shared by k processes
    counts 1/k in each) plus the growth of other private memory; a process's whole Pss is not used, as
    its shared libraries' share moves whenever other processes on the machine map or drop them."""
    from svr.nmr.format import prepare_nmr

    root = tmp_path / "nmr"
    root.mkdir()
    rng = np.random.default_rng(0)
    categories = ("02691156", "02828884")
    for cid in categories:  # 12 objects each: 10.2 MB of images and voxels in all
        np.savez(root / f"{cid}_train_images.npz", rng.integers(0, 256, (12, 24, 4, 64, 64), dtype=np.uint8))
        np.savez(root / f"{cid}_train_voxels.npz", rng.random((12, 32, 32, 32)) < 0.3)
    prepared = prepare_nmr(root, categories=list(categories), splits=("train",), progress=False)
    data_bytes = sum(p.stat().st_size for p in prepared)

    env = clean_env()
    env["OMP_NUM_THREADS"] = "1"
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, str(root), ",".join(categories)], cwd=REPO, env=env,
                              text=True, stdin=subprocess.PIPE, stdout=subprocess.PIPE) for _ in range(3)]
    try:
        def step(group, tag):
            for p in group:
                p.stdin.write("go\n")
                p.stdin.flush()
            for p in group:
                assert p.stdout.readline().strip() == tag

        for p in procs:
            assert p.stdout.readline().strip() == "imported"
        before = [_memory(p.pid, root) for p in procs]
        step(procs[:1], "touched")                      # one process reads everything
        one = [_memory(p.pid, root) for p in procs]
        step(procs[1:], "touched")                      # two more read everything
        three = [_memory(p.pid, root) for p in procs]
        step(procs, "")                                  # let them exit
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()

    def other_private(m):  # private memory outside the data's mappings (a page mapped by one
        return m["private"] - m["data_private"]  # process alone counts as private too)

    def cost(after):
        return sum(a["data_pss"] - b["data_pss"] + other_private(a) - other_private(b) for a, b in zip(after, before))

    cost_one, cost_three = cost(one), cost(three)
    private_growth = [other_private(a) - other_private(b) for a, b in zip(three, before)]
    report = (f"data {data_bytes / 2**20:.2f} MiB; summed cost: 1 process {cost_one / 2**20:.2f} MiB, "
              f"3 processes {cost_three / 2**20:.2f} MiB; private growth per process "
              f"{[round(g / 2**20, 2) for g in private_growth]} MiB")
    print(report)
    for m in three:  # every process maps all of the data, as shared pages
        assert m["data_rss"] >= 0.98 * data_bytes, report
        assert m["data_private"] == 0, report
    assert abs(sum(m["data_pss"] for m in three) - data_bytes) <= 0.02 * data_bytes, report
    overhead = 2 * 2**20  # per process: Python objects, allocator slack
    assert 0.9 * data_bytes <= cost_one <= data_bytes + overhead, report
    assert cost_three - cost_one <= 2 * overhead, report  # a private copy each would add 2 x 10 MiB
    assert all(g <= overhead for g in private_growth), report
