"""SVRLightningModule: the three-stage training of the single-view network (paper section 6). In
the ``coarse`` stage the encoder and decoder train on the coarse SDF's loss and the refiner is not
run; in ``refine`` the refiner trains alone on the refined SDF's loss, with the encoder and
decoder frozen (``requires_grad`` False, batch norm in eval mode, kept so whatever calls
``.train()``, and run without building a graph); in ``joint`` all three train on the refined
SDF's loss. How a non-finite step is skipped and how several processes agree is in the class
docstring.
"""
from __future__ import annotations

import time
import warnings
from typing import Any, Callable, Iterable, Optional, Sequence

import pytorch_lightning as pl
import torch

import renderer

from sdfcommon.tooling.checks import check_instance, check_int
from svr.data.types import SVRBatch
from svr.distributed import gather_unique
from svr.losses import LossTerms, LossWeights, hull_loss, image_loss, total_loss, voxel_loss
from svr.models.checkpoint_layout import CHECKPOINT_KEY, check_stage
from svr.models.network import SVRNet
from svr.nmr.metrics import iou_direct, iou_table


OptimizerFactory = Callable[[Iterable[torch.nn.Parameter]], torch.optim.Optimizer]
SchedulerFactory = Callable[[torch.optim.Optimizer], Any]


def _default_optimizer(params: Iterable[torch.nn.Parameter]) -> torch.optim.Optimizer:
    return torch.optim.Adam(params, lr=1e-4)


class SVRLightningModule(pl.LightningModule):
    """Trains an SVRNet by rendering its SDF predictions (renderer.render) against the dataset views.

    A non-finite prediction, loss or gradient never reaches the weights: the step is skipped
    (every gradient dropped before the optimiser sees it), a warning is issued and
    ``train/skipped_steps`` counts them (also kept in the checkpoint). Under distributed training
    the ranks agree: a step that is not finite on one rank is skipped on all of them (gradients are
    averaged after the loss, so a non-finite gradient already is everyone's), so the weights stay
    equal across ranks. Training metrics are averaged over the ranks (``sync_dist``); validation
    gathers every rank's per-image IoU and counts each image once (the evaluation samplers pad the
    ranks' shares to equal sizes), so ``val/iou`` is the single-process number on every rank.

    Args:
        net: the network.
        stage: "coarse", "refine" or "joint" (see the module docstring).
        loss_weights: LossWeights.
        scene: the renderer.Scene of the image loss: silhouettes only, or also shading when the
            dataset's shading model is known (``ShadingModel.scene()``).
        render_size: side of the training renders (the images are area-downsampled to it).
        trace_settings: the renderer's march settings.
        backend: renderer backend ("auto" picks the fused kernel where available).
        optimizer: a factory ``params -> torch.optim.Optimizer`` (hydra ``_partial_``); Adam(1e-4)
            if None.
        scheduler: a factory ``optimizer -> LR scheduler`` stepped every training step, or None.
        categories: (id, name) pairs of the data module, for per-category validation IoU.
        model_config: the plain-dict config the network was built from (hydra ``_target_`` form);
            stored in every checkpoint so that evaluation and inference can rebuild the network.
    """

    def __init__(
        self,
        net: SVRNet,
        stage: str = "coarse",
        loss_weights: LossWeights = LossWeights(),
        scene: renderer.Scene = renderer.Scene(effects=("silhouette",)),
        render_size: int = 64,
        trace_settings: renderer.TraceSettings = renderer.TraceSettings(),
        backend: str = "auto",
        optimizer: Optional[OptimizerFactory] = None,
        scheduler: Optional[SchedulerFactory] = None,
        categories: Optional[Sequence[tuple[str, str]]] = None,
        model_config: Optional[dict] = None,
    ) -> None:
        super().__init__()
        check_instance(net, "net", SVRNet, "an SVRNet")
        check_instance(loss_weights, "loss_weights", LossWeights)
        check_instance(scene, "scene", renderer.Scene, "a renderer.Scene")
        check_instance(trace_settings, "trace_settings", renderer.TraceSettings, "a renderer.TraceSettings")
        check_int(render_size, "render_size", minimum=1)
        self.net = net
        self.stage = check_stage(stage)
        self.loss_weights = loss_weights
        self.scene = scene
        self.render_size = render_size
        self.trace_settings = trace_settings
        self.backend = backend
        self.optimizer_factory = optimizer or _default_optimizer
        self.scheduler_factory = scheduler
        self.categories = [tuple(c) for c in categories] if categories is not None else None
        self.model_config = model_config
        self.skipped_steps = 0
        self.seconds_before = 0.0  # wall seconds this stage trained before a resume (from the checkpoint)
        self._fit_started: Optional[float] = None
        self._skip_this_step = False
        self.capture_visuals = False
        self.visuals: Optional[dict[str, torch.Tensor]] = None
        self._val_iou: list[torch.Tensor] = []
        self._val_iou_coarse: list[torch.Tensor] = []
        self._val_category: list[torch.Tensor] = []
        self._val_key: list[torch.Tensor] = []
        self.apply_stage()

    # ------------------------------------------------------------------ stages
    @property
    def frozen_modules(self) -> tuple[torch.nn.Module, ...]:
        """The submodules this stage does not train."""
        head = (self.net.camera,) if self.net.camera is not None and not self.net.camera.trains_in(self.stage) else ()
        if self.stage == "coarse":
            return (self.net.refiner, *head)
        if self.stage == "refine":
            return tuple(m for m in (self.net.encoder, self.net.decoder, self.net.local) if m is not None) + head
        return head

    def apply_stage(self) -> None:
        """Sets ``requires_grad`` and batch-norm modes for ``self.stage``."""
        for p in self.net.parameters():
            p.requires_grad_(True)
        for m in self.frozen_modules:
            for p in m.parameters():
                p.requires_grad_(False)
        self.train(self.training)

    def train(self, mode: bool = True) -> "SVRLightningModule":
        """As nn.Module.train, except that frozen submodules always stay in eval mode (their batch
        norm statistics never move), whoever calls this (Lightning does around validation)."""
        super().train(mode)
        for m in self.frozen_modules:
            m.eval()
        return self

    @property
    def uses_refiner(self) -> bool:
        return self.stage != "coarse"

    def stage_sdf(self, images: torch.Tensor, views: Optional[torch.Tensor] = None,
                  exclude: Optional[torch.Tensor] = None) -> tuple[torch.Tensor, Optional[torch.Tensor]]:
        """(B, 4, 64, 64) images (and their (B,) NMR view indices, which a network with a pixel-aligned
        head needs) -> the coarse (B, N, N, N) and refined SDF (None in the coarse stage) as this
        stage trains them (inference: ``svr.inference.prediction.predict_sdf``).

        Frozen parts run without a graph (they need no gradient). ``exclude``: (B,) training objects
        the shape prior must not retrieve."""
        prior = self.net.shape_prior(images, views, exclude)
        if self.stage == "refine":
            with torch.no_grad():
                coarse = self.net.coarse(images, views, prior)
        else:
            coarse = self.net.coarse(images, views, prior)
        refined = self.net.refiner(coarse) if self.uses_refiner else None
        return coarse, refined

    def forward(self, images: torch.Tensor, views: Optional[torch.Tensor] = None) -> torch.Tensor:
        """(B, 4, 64, 64) RGBA (and their (B,) NMR views) -> (B, N, N, N) the stage's output SDF
        (refined unless coarse stage)."""
        coarse, refined = self.stage_sdf(images, views)
        return refined if refined is not None else coarse

    # ------------------------------------------------------------------ training
    def compute_loss(self, batch: SVRBatch, sdf: torch.Tensor) -> LossTerms:
        """The stage's loss of predicted grids (B, N, N, N) against the batch's V views (rendered only
        where an image term has weight; their visual hull where the hull term has weight) and, where
        its weight is not 0, its voxels."""
        img = None
        if self.loss_weights.renders(self.scene.wants("shading")):
            img = image_loss(sdf, self.net.half_side, batch.images, batch.views, self.scene, self.render_size,
                             self.loss_weights.silhouette_kind, self.trace_settings, self.backend)
            if self.capture_visuals:
                self.visuals = {
                    "input": batch.images[:, 0].detach().cpu(),
                    "target": img.target.detach().cpu(),
                    "silhouette": img.silhouettes.detach().cpu(),
                    **({"colour": img.colours.detach().cpu()} if img.colours is not None else {}),
                }
        vox = (voxel_loss(sdf, self.net.half_side, batch.voxels, self.loss_weights.voxel_kind)
               if self.loss_weights.voxel > 0 else None)
        w = self.loss_weights
        hull = (hull_loss(sdf, self.net.half_side, batch.images[:, :, 3], batch.views, w.hull_margin, w.hull_tolerance,
                          w.hull_stride) if w.hull > 0 else None)
        return total_loss(img, sdf, self.net.voxel_size, self.loss_weights, vox, hull)

    def _trainable(self) -> list[torch.nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    def _skip(self, why: str) -> torch.Tensor:
        """Marks this step as skipped and returns a zero loss attached to the trainable weights
        (so backward runs the same on every process); the gradients are dropped before the step."""
        self._skip_this_step = True
        self.skipped_steps += 1
        warnings.warn(f"step {self.global_step}: {why}; skipping the optimiser step "
                      f"({self.skipped_steps} skipped so far)", RuntimeWarning)
        return sum((p.sum() * 0.0 for p in self._trainable()), torch.zeros((), device=self.device))

    def training_step(self, batch: SVRBatch, batch_idx: int) -> torch.Tensor:
        self._skip_this_step = False
        exclude = (self.net.prior.exclusion(batch.category, batch.object_index) if self.net.prior is not None
                   else None)  # the prior never retrieves a training input's own object
        coarse, refined = self.stage_sdf(batch.images[:, 0], batch.views[:, 0], exclude)
        sdf = refined if refined is not None else coarse
        terms, why = None, None
        if not bool(torch.isfinite(sdf.detach()).all()):
            why = "the predicted SDF is not finite"
        else:
            terms = self.compute_loss(batch, sdf)
            if not bool(torch.isfinite(terms.total.detach())):
                why = f"the loss is not finite ({float(terms.total.detach())})"
        if self._trainer is not None and self.trainer.world_size > 1:
            # Every rank must skip together, or the ranks' weights part (and their logging calls,
            # collectives with sync_dist, no longer match).
            if self.trainer.strategy.reduce_boolean_decision(why is not None, all=False) and why is None:
                why = "the step is not finite on another process"
        if why is not None:
            loss, terms = self._skip(why), None
        else:
            loss = terms.total
        bs = len(batch)
        if terms is not None:
            for name, value in terms.as_dict().items():
                self.log(f"train/{name}", value.detach(), batch_size=bs, prog_bar=name == "total", sync_dist=True)
            if self.net.camera is not None and self.net.camera.trains_in(self.stage):
                # The batch's first views (random but the input), with their known cameras; the
                # head's weights are its own.
                k = self.net.camera.train_views
                elevations = batch.cameras[:, :k, 1].flatten() if batch.cameras is not None else None
                camera, right = self.net.camera.loss(batch.images[:, :k].flatten(0, 1), batch.view_ids[:, :k].flatten(),
                                                     elevations)
                loss = loss + camera
                self.log("train/camera", camera.detach(), batch_size=bs, sync_dist=True)
                self.log("train/camera_views_right", right, batch_size=bs, sync_dist=True)
        return loss

    def on_train_batch_end(self, outputs: Any, batch: SVRBatch, batch_idx: int) -> None:
        # Logged after the optimiser hook, so a step skipped for its gradient is counted in its own row.
        self.log("train/skipped_steps", float(self.skipped_steps), batch_size=len(batch))

    def on_before_optimizer_step(self, optimizer: torch.optim.Optimizer) -> None:
        """Drops every gradient of a skipped step, or of a step with a non-finite gradient."""
        params = [p for group in optimizer.param_groups for p in group["params"] if p.grad is not None]
        if not self._skip_this_step:
            finite = all(bool(torch.isfinite(p.grad).all()) for p in params)
            if not finite:
                self.skipped_steps += 1
                warnings.warn(f"step {self.global_step}: non-finite gradient; skipping the optimiser step "
                              f"({self.skipped_steps} skipped so far)", RuntimeWarning)
                self._skip_this_step = True
        if self._skip_this_step:
            for p in params:
                p.grad = None
        self._skip_this_step = False

    def _camera_apart(self, params: list[torch.nn.Parameter]) -> tuple[list[torch.nn.Parameter],
                                                                         list[torch.nn.Parameter]]:
        """``params`` split into the rest of the network's and the camera head's (none without one)."""
        head = {id(p) for p in self.net.camera.parameters()} if self.net.camera is not None else set()
        return [p for p in params if id(p) not in head], [p for p in params if id(p) in head]

    def configure_gradient_clipping(self, optimizer: torch.optim.Optimizer, gradient_clip_val=None,
                                    gradient_clip_algorithm=None) -> None:
        """Lightning's clipping, except that a camera head's gradients are clipped on their own: the
        rest of the network's steps stay what they were without one."""
        if self.net.camera is None or not gradient_clip_val:
            self.clip_gradients(optimizer, gradient_clip_val, gradient_clip_algorithm)
            return
        for part in self._camera_apart([p for group in optimizer.param_groups for p in group["params"]]):
            if gradient_clip_algorithm in (None, "norm"):
                torch.nn.utils.clip_grad_norm_(part, float(gradient_clip_val))
            else:
                torch.nn.utils.clip_grad_value_(part, float(gradient_clip_val))

    def configure_optimizers(self):
        params = self._trainable()
        if not params:
            raise ValueError(f"stage {self.stage!r} has no trainable parameters")
        rest, head = self._camera_apart(params)
        if head and rest and self.net.camera.lr_scale != 1.0:
            # The camera head's own group, at its own rate (Adam's steps are per weight, so the rest
            # train exactly as without it).
            opt = self.optimizer_factory([{"params": rest}, {"params": head}])
            opt.param_groups[1]["lr"] = opt.defaults["lr"] * self.net.camera.lr_scale
        else:
            opt = self.optimizer_factory(params)
        if self.scheduler_factory is None:
            return opt
        return {"optimizer": opt, "lr_scheduler": {"scheduler": self.scheduler_factory(opt), "interval": "step"}}

    def on_train_start(self) -> None:
        self._fit_started = time.perf_counter()

    @property
    def train_seconds(self) -> float:
        """Wall seconds this stage has trained (validation included), over resumes."""
        now = time.perf_counter() - self._fit_started if self._fit_started is not None else 0.0
        return self.seconds_before + now

    # ------------------------------------------------------------------ validation
    def on_validation_epoch_start(self) -> None:
        self._val_iou, self._val_iou_coarse, self._val_category, self._val_key = [], [], [], []

    def validation_step(self, batch: SVRBatch, batch_idx: int) -> None:
        """Fast direct IoU (``svr.nmr.metrics.iou_direct``) of the stage's output and of the coarse SDF,
        one prediction per batch element from its first view."""
        coarse, refined = self.stage_sdf(batch.images[:, 0], batch.views[:, 0])
        hs = self.net.half_side
        iou_c = iou_direct(coarse, batch.voxels, -hs, hs).to(self.device)
        iou = iou_direct(refined, batch.voxels, -hs, hs).to(self.device) if refined is not None else iou_c
        self._val_iou.append(iou)
        self._val_iou_coarse.append(iou_c)
        self._val_category.append(batch.category.to(self.device))
        # What identifies an image across ranks: (category, object, view).
        self._val_key.append(torch.stack([batch.category, batch.object_index, batch.view_ids[:, 0]], 1)
                             .long().to(self.device))

    def on_validation_epoch_end(self) -> None:
        distributed = self.trainer.world_size > 1
        if not self._val_iou and not distributed:
            return
        def joined(parts: list[torch.Tensor], *shape: int, dtype=torch.float32) -> torch.Tensor:
            return torch.cat(parts) if parts else torch.zeros(0, *shape, dtype=dtype, device=self.device)

        iou, iou_c, cat = joined(self._val_iou), joined(self._val_iou_coarse), joined(self._val_category,
                                                                                     dtype=torch.long)
        if distributed:
            # Every rank calls this (a collective) even with nothing to add; shares may differ in
            # size, and an image two ranks scored (padding) counts once.
            _, iou, iou_c, cat = gather_unique(joined(self._val_key, 3, dtype=torch.long), iou, iou_c, cat)
            if not len(iou):
                return
        mean, per_cat = _category_mean(iou, cat, self.categories)
        self.log("val/iou", mean, prog_bar=True, sync_dist=False)
        self.log("val/images", float(len(iou)), sync_dist=False)  # what the means are over
        self.log("val/train_seconds", self.train_seconds, sync_dist=False)  # for IoU-against-time curves
        self.log("val/iou_coarse", _category_mean(iou_c, cat, self.categories)[0], sync_dist=False)
        for name, value in per_cat.items():
            self.log(f"val/iou_{name}", value, sync_dist=False)

    # ------------------------------------------------------------------ checkpoints
    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint[CHECKPOINT_KEY] = {
            "stage": self.stage,
            "skipped_steps": self.skipped_steps,
            "train_seconds": self.train_seconds,
            "model_config": self.model_config,
            "half_side": self.net.half_side,
            "grid_resolution": self.net.grid_resolution,
            "categories": [list(c) for c in self.categories] if self.categories is not None else None,
        }

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        meta = checkpoint.get(CHECKPOINT_KEY, {})
        self.skipped_steps = int(meta.get("skipped_steps", 0))
        self.seconds_before = float(meta.get("train_seconds", 0.0))


def _category_mean(iou: torch.Tensor, cat: torch.Tensor,
                   categories: Optional[Sequence[tuple[str, str]]]) -> tuple[float, dict[str, float]]:
    """The benchmark's mean (per-category means, then their unweighted mean) and the per-category
    means by name, over the categories present."""
    cat = cat.long().cpu()
    if categories is None:
        n = int(cat.max()) + 1 if cat.numel() else 0
        categories = [(str(c), str(c)) for c in range(n)]
    table = iou_table(iou.cpu(), cat, categories)
    return table.mean, {r.name: r.iou for r in table.rows if r.images > 0}
