"""Training end to end on a tiny procedural set: the three-stage schedule, checkpoints, resume, a
stage alone from another stage's weights, frozen weights, overfitting one batch, non-finite steps,
atomic checkpoint files, and the hydra configs."""
from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

from sdfcommon.tooling.outputs import write_text
from sdfcommon.tooling.settings import build_settings, settings_record
from svr.inference.checkpoints import load_checkpoint
from svr.models.module import SVRLightningModule
from svr.training import stages
from svr.training.callbacks import AtomicCheckpointIO
from svr.training.run_folder import RunFolder
from svr.training.stages import build_module, build_trainer
from svr.training.stopping import StopRequest

REPO = Path(__file__).resolve().parents[3]
CONFIGS = str(REPO / "configs")


@pytest.fixture(scope="module")
def data_overrides(tmp_path_factory) -> list[str]:
    """A tiny procedural dataset (2 categories, 2/1/1 objects), generated once for this module."""
    cache = tmp_path_factory.mktemp("svr_cache")
    return [f"data.cache_dir={cache}", "data.categories=[chair,mug]", "data.train=2", "data.val=1", "data.test=1",
            "data.batch_size=2", "data.eval_batch_size=8", "data.val_views=[0,12]", "data.progress=false",
            "data.supersample=1"]


# Bit-for-bit comparisons pin the CPU: on a GPU the fused backward's atomic adds sum in no fixed
# order, so two runs (or a run and its resumed copy) differ in the last bits there.
BITWISE = "trainer.accelerator=cpu"


def tiny_overrides(data: list[str], steps: int = 2, *extra: str) -> list[str]:
    return [*data, "model=tiny", "loss.render_size=16", "loss.trace.max_steps=64",
            *(f"stage.{s}.max_steps={steps}" for s in ("coarse", "refine", "joint")),
            "trainer.val_check_interval=2", "trainer.log_every_n_steps=1", "trainer.enable_progress_bar=false",
            "trainer.enable_model_summary=false", "callbacks.progress_bar=null",
            "callbacks.last_checkpoint.every_n_train_steps=1", "callbacks.image_logger.every_n_steps=2", *extra]


def compose_train(overrides: list[str], hydra: bool = False):
    with initialize_config_dir(config_dir=CONFIGS, version_base="1.3"):
        return compose("train", overrides=overrides, return_hydra_config=hydra)


def train(cfg, run_dir: Path) -> stages.TrainResult:
    """What the training command does with a composed config in its run folder: the settings, the
    run's config.yaml (the command writes it), then the schedule."""
    settings = build_settings(cfg)
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    write_text(RunFolder(Path(run_dir)).config, OmegaConf.to_yaml(settings_record(settings)))
    return stages.train(settings, run_dir)


def state(path: Path, prefix: str) -> dict[str, torch.Tensor]:
    sd = load_checkpoint(path)["state_dict"]
    return {k: v for k, v in sd.items() if k.startswith(prefix)}


def assert_same(a: dict, b: dict, what: str) -> None:
    assert a.keys() == b.keys() and a, what
    for k in a:
        assert torch.equal(a[k], b[k]), f"{what}: {k} changed"


def metrics_columns(stage_dir: Path) -> set[str]:
    with open(stage_dir / "csv" / "metrics.csv") as f:
        return set(next(csv.reader(f)))


# ------------------------------------------------------------------------------------------------
# the schedule end to end


def test_schedule_checkpoints_resume_and_frozen_weights(tmp_path, data_overrides):
    # 1. The coarse stage alone, 2 steps.
    first = train(compose_train(tiny_overrides(data_overrides, 2, "stage=coarse")), tmp_path / "a")
    assert [s.stage for s in first.stages] == ["coarse"]
    last = tmp_path / "a" / "coarse" / "checkpoints" / "last.ckpt"
    assert load_checkpoint(last)["global_step"] == 2

    # 2. Resume that coarse run to 4 steps and go on with the rest of the schedule.
    cfg = compose_train(tiny_overrides(data_overrides, 2, f"ckpt_path={last}", "stage.coarse.max_steps=4"))
    run = tmp_path / "b"
    result = train(cfg, run)
    assert [s.stage for s in result.stages] == ["coarse", "refine", "joint"]
    assert (run / "config.yaml").is_file()
    for s in result.stages:
        ckpts = run / s.stage / "checkpoints"
        for name in ("best.ckpt", "last.ckpt", "final.ckpt"):
            assert (ckpts / name).is_file(), f"{s.stage}/{name} missing"
        assert s.best == ckpts / "best.ckpt" and s.best_val_iou is not None
        assert {"train/total", "train/silhouette", "train/eikonal", "train/laplacian", "train/skipped_steps",
                "val/iou", "val/iou_coarse", "val/train_seconds"} <= metrics_columns(run / s.stage)
        assert list((run / s.stage / "tensorboard").glob("events.out.tfevents*"))
        assert list((run / s.stage / "images").glob("step_*.png"))
        assert not list(ckpts.glob("*.tmp"))
    assert load_checkpoint(run / "coarse" / "checkpoints" / "final.ckpt")["global_step"] == 4  # resumed 2 -> 4
    # The stage's training time carries over the resume (the first part's seconds are included).
    first_part = load_checkpoint(last)["sdfdiff"]["train_seconds"]
    assert 0 < first_part < load_checkpoint(run / "coarse" / "checkpoints" / "final.ckpt")["sdfdiff"]["train_seconds"]

    # The coarse stage never trains the refiner (its head is still the zero initialisation).
    coarse_final = state(run / "coarse" / "checkpoints" / "final.ckpt", "net.refiner.head")
    assert all(torch.count_nonzero(v) == 0 for v in coarse_final.values())
    # The refine stage starts from coarse/best.ckpt and leaves encoder + decoder (weights and
    # batch-norm statistics) exactly as they were; the refiner moves.
    handoff = run / "coarse" / "checkpoints" / "best.ckpt"
    refine_final = run / "refine" / "checkpoints" / "final.ckpt"
    for part in ("net.encoder.", "net.decoder."):
        assert_same(state(handoff, part), state(refine_final, part), f"refine stage: {part}")
    assert not all(torch.equal(a, b) for a, b in zip(state(handoff, "net.refiner.").values(),
                                                     state(refine_final, "net.refiner.").values()))
    # The joint stage trains everything.
    joint_final = run / "joint" / "checkpoints" / "final.ckpt"
    refine_best = run / "refine" / "checkpoints" / "best.ckpt"
    for part in ("net.encoder.", "net.refiner."):
        a, b = state(refine_best, part), state(joint_final, part)
        assert any(not torch.equal(a[k], b[k]) for k in a), f"joint stage did not train {part}"


def test_one_stage_from_another_stages_weights(tmp_path, data_overrides):
    coarse = train(compose_train(tiny_overrides(data_overrides, 2, "stage=coarse")), tmp_path / "c")
    ckpt = coarse.checkpoint("coarse", "final")
    result = train(compose_train(tiny_overrides(data_overrides, 2, "stage=refine", f"ckpt_path={ckpt}")),
                   tmp_path / "r")
    assert [s.stage for s in result.stages] == ["refine"]
    assert not (tmp_path / "r" / "coarse").exists()
    final = result.checkpoint("refine", "final")
    assert load_checkpoint(final)["global_step"] == 2  # a fresh stage, not a resumed one
    assert_same(state(ckpt, "net.encoder."), state(final, "net.encoder."), "encoder from the coarse checkpoint")


def test_same_seed_same_weights(tmp_path, data_overrides):
    """Seeded and reproducible: the same seed gives the same weights bit for bit, another seed not."""
    def final(seed: int, name: str) -> dict:
        result = train(compose_train(tiny_overrides(data_overrides, 3, "stage=coarse", f"seed={seed}", BITWISE)), tmp_path / name)
        return state(result.checkpoint("coarse", "final"), "net.")

    a, b, c = final(0, "a"), final(0, "b"), final(1, "c")
    assert_same(a, b, "same seed")
    assert any(not torch.equal(a[k], c[k]) for k in a)


# A tiny model=pixel with a camera head, two stages, and a clip small enough to act on every step.
PIXEL_WITH_HEAD = ["model=pixel", "model.encoder.channels=[8,16,32,32]", "model.encoder.latent_dim=64",
                   "model.decoder.channels=[16,8,8]", "model.decoder.grid_resolution=32", "model.refiner.channels=[4,8]",
                   "model.local.image_channels=[4,8,16]", "model.local.volume_channels=8", "model.local.hidden=16",
                   "model.local.mirror_axis=null", "model.camera.channels=[8,16]", "stage.schedule=[coarse,refine]",
                   "trainer.gradient_clip_val=0.01", BITWISE]


def _pixel_run(run: Path, data_overrides: list[str], *extra: str) -> dict[str, dict]:
    """The run's weights: its coarse stage's best and final checkpoints and its refine stage's final."""
    result = train(compose_train(tiny_overrides(data_overrides, 3, *PIXEL_WITH_HEAD, *extra)), run)
    return {"coarse_best": state(result.checkpoint("coarse", "best"), "net."),
            "coarse": state(result.checkpoint("coarse", "final"), "net."),
            "refine": state(result.checkpoint("refine", "final"), "net.")}


@pytest.fixture(scope="module")
def head_run(tmp_path_factory, data_overrides) -> tuple[Path, dict[str, dict]]:
    """A run whose camera head learns in every stage (the default), shared by the tests below."""
    run = tmp_path_factory.mktemp("head")
    return run, _pixel_run(run, data_overrides)


def test_a_camera_head_trains_in_every_stage_and_leaves_the_rest_as_without_it(tmp_path, data_overrides, head_run):
    """model=pixel's camera head learns from every view of each batch, in each stage (the refine
    stage freezes the rest), and is clipped on its own: the other weights end bit for bit as a run
    without a head gives (on the CPU)."""
    run, with_head = head_run
    plain = _pixel_run(tmp_path / "plain", data_overrides, "model.camera=null")
    for stage in ("coarse", "refine"):
        assert_same({k: v for k, v in with_head[stage].items() if not k.startswith("net.camera.")}, plain[stage], stage)
    head = {k: v for k, v in with_head["coarse"].items() if k.startswith("net.camera.") and v.is_floating_point()}
    # It trained in refine too, from where the refine stage started (the coarse stage's best).
    assert head and any(not torch.equal(with_head["coarse_best"][k], with_head["refine"][k]) for k in head)
    # Its own parameter group, at model.camera.lr_scale times the stage's rate (4 in model=pixel).
    saved = load_checkpoint(run / "coarse" / "checkpoints" / "final.ckpt")
    groups = saved["optimizer_states"][0]["param_groups"]
    assert len(groups) == 2 and groups[1]["lr"] == pytest.approx(4.0 * groups[0]["lr"])
    assert len(groups[1]["params"]) == len([k for k in head if not k.endswith(("running_mean", "running_var"))])
    assert {"train/camera", "train/camera_views_right"} <= metrics_columns(run / "coarse")


def test_a_shape_prior_is_filled_from_the_training_split_and_travels_with_the_checkpoint(tmp_path, data_overrides,
                                                                                        monkeypatch):
    """model=pixel_prior: the training command sizes the prior from the training split, fills it
    from its images, keeps each training input's own object out of its retrieval (and nothing out
    in validation, whose objects are not training objects), and the checkpoint rebuilds the same
    prior."""
    from svr.inference.checkpoints import load_network
    from svr.models import ShapePrior
    calls = []
    forward = ShapePrior.forward

    def recording(self, alpha, views, exclude=None):
        calls.append(None if exclude is None else exclude.tolist())
        return forward(self, alpha, views, exclude)

    monkeypatch.setattr(ShapePrior, "forward", recording)
    pixel = [o for o in PIXEL_WITH_HEAD if o != "model=pixel"]
    cfg = compose_train(tiny_overrides(data_overrides, 2, "model=pixel_prior", *pixel, "model.prior.neighbours=2",
                                       "stage.schedule=[coarse]"))
    result = train(cfg, tmp_path / "run")
    training = [c for c in calls if c is not None]
    assert len(training) >= 2 and all(0 <= g < 4 for c in training for g in c)  # 2 steps, global training indices
    assert None in calls  # validation retrieves from every training object
    net, meta = load_network(result.checkpoint("coarse", "final"))
    prior = net.prior
    assert meta["model_config"]["prior"]["objects"] == 4 and meta["model_config"]["prior"]["categories"] == 2
    assert prior.first.tolist() == [0, 2] and prior.silhouettes.float().mean() > 1  # the objects' silhouettes
    assert prior.hulls.float().amax(1).min() > 200  # each object's hull holds points deep inside it
    # Built again from the training split, the prior is the one the checkpoint holds.
    dm = instantiate(cfg.data)
    again = stages.instantiate(meta["model_config"])
    stages.fill_shape_prior(again, dm)
    assert torch.equal(again.prior.silhouettes, prior.silhouettes) and torch.equal(again.prior.hulls, prior.hulls)
    # An object's own view retrieves it, unless excluded (as training does).
    train_set = dm.dataset("train")
    alpha = torch.from_numpy(train_set.images_uint8(3, [5])[:, 3]).float() / 255
    assert prior.nearest(alpha, torch.tensor([5]))[0, 0] == 3
    assert 3 not in prior.nearest(alpha, torch.tensor([5]), exclude=torch.tensor([3])).tolist()[0]


def test_a_camera_head_kept_to_the_coarse_stage_is_frozen_after_it(tmp_path, data_overrides, head_run):
    """model.camera.stages=[coarse]: the head learns in the coarse stage and then neither its weights
    nor its batch-norm statistics move, nor does it log a loss; the rest of the network trains as
    with a head in every stage, bit for bit."""
    kept, every = _pixel_run(tmp_path / "kept", data_overrides, "model.camera.stages=[coarse]"), head_run[1]
    head = [k for k in kept["coarse"] if k.startswith("net.camera.")]
    assert head
    assert_same({k: kept["coarse"][k] for k in head}, {k: every["coarse"][k] for k in head}, "coarse: the head")
    # The refine stage starts from the coarse stage's best checkpoint and leaves the head as it was there.
    assert_same({k: kept["refine"][k] for k in head}, {k: kept["coarse_best"][k] for k in head}, "refine: the frozen head")
    assert_same({k: v for k, v in kept["refine"].items() if k not in head},
                {k: v for k, v in every["refine"].items() if k not in head}, "refine: the rest")
    assert "train/camera" not in metrics_columns(tmp_path / "kept" / "refine")


# ------------------------------------------------------------------------------------------------
# learning and robustness


def test_overfits_one_batch(data_overrides):
    torch.manual_seed(0)
    cfg = compose_train(tiny_overrides(data_overrides, 2, "loss.render_size=32", "stage.coarse.optimizer.lr=3e-3"))
    dm = instantiate(cfg.data)
    dm.prepare_data()
    batch = next(iter(dm.train_dataloader()))
    module = build_module(build_settings(cfg), instantiate(cfg.model), "coarse", dm)
    opt = module.configure_optimizers()
    losses = []
    for _ in range(30):
        loss = module.compute_loss(batch, module(batch.images[:, 0])).total
        assert torch.isfinite(loss)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert sum(losses[-5:]) / 5 < 0.6 * sum(losses[:5]) / 5, losses


class NaNLoss(SVRLightningModule):
    """Every step's loss is NaN, or (``bad_gradient``) finite with a NaN gradient."""

    bad_gradient = False

    def compute_loss(self, batch, sdf):
        terms = super().compute_loss(batch, sdf)
        if self.bad_gradient:
            poison = torch.sqrt(sdf.abs().amin() * 0.0) * 0.0  # value 0, gradient 0 * inf = NaN
            return type(terms)(terms.total + poison, terms.silhouette, terms.shading, terms.eikonal,
                               terms.laplacian)
        return type(terms)(terms.total * float("nan"), terms.silhouette, terms.shading, terms.eikonal,
                           terms.laplacian)


def test_turning_the_progress_bar_off_is_one_setting(tmp_path, data_overrides):
    """trainer.enable_progress_bar=false alone (callbacks.progress_bar stays the default TQDM bar):
    the trainer is built without the bar; before, Lightning refused the pair in a multi-line error."""
    overrides = [o for o in tiny_overrides(data_overrides) if o != "callbacks.progress_bar=null"]
    cfg = compose_train(overrides)
    assert cfg.callbacks.progress_bar is not None and cfg.trainer.enable_progress_bar is False
    trainer = build_trainer(build_settings(cfg), "coarse", RunFolder(tmp_path), StopRequest(tmp_path))
    assert trainer.progress_bar_callback is None
    shown = build_trainer(build_settings(compose_train([*overrides, "trainer.enable_progress_bar=true"])),
                          "coarse", RunFolder(tmp_path / "b"), StopRequest(tmp_path / "b"))
    assert shown.progress_bar_callback is not None


@pytest.mark.parametrize("bad_gradient", [False, True])
def test_non_finite_steps_are_skipped(tmp_path, data_overrides, bad_gradient):
    cfg = compose_train(tiny_overrides(data_overrides, 3, "trainer.val_check_interval=100"))
    dm = instantiate(cfg.data)
    net = instantiate(cfg.model)
    module = build_module(build_settings(cfg), net, "coarse", dm)
    module.__class__ = NaNLoss
    module.bad_gradient = bad_gradient
    before = {k: v.clone() for k, v in net.state_dict().items() if "running" not in k and "num_batches" not in k}
    trainer = build_trainer(build_settings(cfg), "coarse", RunFolder(tmp_path), StopRequest(tmp_path))
    with pytest.warns(RuntimeWarning, match="skipping the optimiser step"):
        trainer.fit(module, datamodule=dm)
    assert module.skipped_steps == 3
    after = net.state_dict()
    for k, v in before.items():
        assert torch.equal(v, after[k]), f"{k} changed on a skipped step"
    with open(tmp_path / "coarse" / "csv" / "metrics.csv") as f:
        rows = [r for r in csv.DictReader(f) if r.get("train/skipped_steps")]
    assert rows and float(rows[-1]["train/skipped_steps"]) == 3


def test_checkpoint_files_are_never_half_written(tmp_path, monkeypatch):
    io = AtomicCheckpointIO()
    path = tmp_path / "ckpts" / "last.ckpt"
    io.save_checkpoint({"step": 1, "w": torch.ones(3)}, path)

    def dies_halfway(obj, f, *args, **kwargs):
        f.write(b"partial bytes of a checkpoint")
        raise KeyboardInterrupt("killed while writing")

    monkeypatch.setattr(torch, "save", dies_halfway)
    with pytest.raises(KeyboardInterrupt):
        io.save_checkpoint({"step": 2, "w": torch.zeros(3)}, path)
    monkeypatch.undo()
    assert torch.load(path, weights_only=True)["step"] == 1  # the previous complete checkpoint
    assert [p.name for p in path.parent.iterdir()] == ["last.ckpt"]  # no temporary left behind


# ------------------------------------------------------------------------------------------------
# configs and the command line


def test_experiment_configs_compose():
    demo = compose_train(["experiment=demo"])
    assert demo.data._target_.endswith("ProceduralDataModule")
    assert list(demo.stage.schedule) == ["coarse", "refine", "joint"]
    bench = compose_train(["experiment=bench"])
    assert bench.data.train == 400 and bench.stage.coarse.scheduler.total_steps == bench.stage.coarse.max_steps
    for name in ("demo", "bench"):  # the demo and the bench schedules build (schedulers included)
        cfg = compose_train([f"experiment={name}"])
        opt = torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
        for stage in ("coarse", "refine", "joint"):
            sched = instantiate(cfg.stage[stage].scheduler)(opt)
            assert sched.get_last_lr()[0] < 1.0  # the warm-up starts below the stage's rate
    paper = compose_train(["experiment=paper_nmr"])
    assert paper.data._target_.endswith("NMRDataModule")
    assert paper.model.encoder.latent_dim == 512  # model=paper
    with pytest.raises(Exception, match="data.root|root"):
        instantiate(paper.data)


@pytest.mark.slow
def test_command_line_multirun_and_killed_run_resumes(tmp_path, data_overrides):
    """train.py -m runs one folder per job, each with its resolved config; a run killed with
    SIGKILL resumes from its last.ckpt."""
    base = [sys.executable, str(REPO / "train.py"), *tiny_overrides(data_overrides, 2)]
    # Hydra's flags go before the overrides: argparse does not take a flag after its positional list.
    sweep = subprocess.run([base[0], base[1], "-m", *base[2:], "seed=0,1", "stage=coarse",
                            f"hydra.sweep.dir={tmp_path / 'sweep'}"],
                           cwd=REPO, capture_output=True, text=True, timeout=600)
    assert sweep.returncode == 0, sweep.stderr[-3000:]
    for job in ("0", "1"):
        assert (tmp_path / "sweep" / job / "config.yaml").is_file()
        assert (tmp_path / "sweep" / job / "coarse" / "checkpoints" / "final.ckpt").is_file()

    run = tmp_path / "killed"
    proc = subprocess.Popen([*base, "stage=coarse", "stage.coarse.max_steps=100000", f"hydra.run.dir={run}"],
                            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    last = run / "coarse" / "checkpoints" / "last.ckpt"
    deadline = time.time() + 300
    while time.time() < deadline and not (last.is_file() and load_checkpoint(last)["global_step"] >= 3):
        time.sleep(0.5)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    step = load_checkpoint(last)["global_step"]  # loads: never half-written
    assert step >= 3
    resumed = subprocess.run([*base, "stage=coarse", f"stage.coarse.max_steps={step + 2}", f"ckpt_path={last}",
                              f"hydra.run.dir={tmp_path / 'resumed'}"], cwd=REPO, capture_output=True, text=True,
                             timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert load_checkpoint(tmp_path / "resumed" / "coarse" / "checkpoints" / "final.ckpt")["global_step"] == step + 2


def test_pixel_model_trains_and_its_mirror_axis_is_measured_from_the_training_voxels(tmp_path, data_overrides):
    from svr.data.symmetry import symmetry_axis
    from svr.inference.prediction import load_model, predict_sdf

    cfg = compose_train(tiny_overrides(data_overrides, 2, "stage=coarse", "model=pixel",
                                       "model.local.mirror_axis=auto"))
    settings = build_settings(cfg)
    dm = instantiate(cfg.data)
    resolved = stages.resolve_mirror_axis(settings, dm)
    train_set = dm.dataset("train")
    expected = symmetry_axis(torch.stack([train_set.voxels(g) for g in range(len(train_set))]).numpy())
    assert resolved.model["local"]["mirror_axis"] == expected
    assert settings.model["local"]["mirror_axis"] == "auto"  # the command's record keeps what was asked

    # The camera head's elevation "auto": an output only where training draws extra views.
    assert settings.model["camera"]["elevation"] == "auto"
    assert stages.resolve_model(settings, dm).model["camera"]["elevation"] is False
    dm.extra_view_share, share = 0.25, dm.extra_view_share
    assert stages.resolve_camera_elevation(settings, dm).model["camera"]["elevation"] is True
    dm.extra_view_share = share

    result = train(cfg, tmp_path / "run")
    ckpt = result.stages[0].best
    assert load_checkpoint(ckpt)["sdfdiff"]["model_config"]["local"]["mirror_axis"] == expected
    assert load_checkpoint(ckpt)["sdfdiff"]["model_config"]["camera"]["elevation"] is False
    model = load_model(ckpt, "cpu")
    assert model.net.needs_views and model.net.local.mirror_axis == expected
    images = torch.stack([train_set.views(0, [3])[0]])
    with pytest.raises(ValueError, match="views"):
        predict_sdf(model, images)
    assert predict_sdf(model, images, views=[3]).final.shape[0] == 1
