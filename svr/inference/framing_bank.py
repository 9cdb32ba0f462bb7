"""Framing a photo by retrieval: where a photo's object would sit in a training render is read off
the training renders whose silhouettes look most like it. A photo shows its object at an unknown
size and place, so ``svr.infer`` first frames it to the training renders' median
(``framing.TRAINING_FRAMING``), then must find the framing that object has in a render from the
estimated camera, which depends on the object's shape and view (the longest side of the bounding
box spans 31 to 56 of 64 pixels). The bank holds every training render's silhouette framed to the
median, as a photo's is, beside the framing that render really had; a photo's framing is the
similarity-weighted mean of its ``BANK_NEIGHBOURS`` most similar entries'. On the demo preset's
photos at random cameras, given the true view, it scored 0.418 against 0.375 for the camera
head's framing (docs/photo_inference_demo_random.md). It reads only what NMR-format data holds
(the training split's alpha channels), is built after training and kept in the checkpoint
(``store_framing_bank``), 129 bytes a render. Each entry also keeps the NMR view it was rendered
from, so the nearest entries vote for the photo's view (``FramingBank.view_votes``), which
``svr.inference.input_camera`` weighs with the camera head's estimate.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np
import torch
import torch.nn.functional as F

from sdfcommon.tooling.checks import check_int
from sdfcommon.tooling.outputs import write_torch
from svr.inference.checkpoints import load_checkpoint
from svr.inference.framing import TRAINING_FRAMING, Framing
from svr.models.checkpoint_layout import CHECKPOINT_KEY
from svr.nmr.format import NUM_VIEWS

BANK_SIDE = 32           # silhouettes compared at 32^2 (2x2 means of the 64^2 alpha, then >= 0.5)
BANK_NEIGHBOURS = 16     # entries averaged per photo (4, 8, 16, 32 measured: 16 best, by 0.005)
WEIGHT_POWER = 4         # each neighbour weighs its IoU with the photo to this power
SUPERSAMPLE = 4          # as framing.frame_image: sub-samples per framed pixel and axis
MAX_RENDERS = 50_000     # a bank holds at most this many (6.5 MB in the checkpoint): the demo's 9709
VOTE_NEIGHBOURS = 32     # entries that vote for a photo's view (32, 128, 512 tried on the demo's validation photos)


def bank_features(alpha: np.ndarray | torch.Tensor) -> torch.Tensor:
    """(N, S, S) alpha (uint8 0..255 or float 0..1), S = 2 * BANK_SIDE -> (N, BANK_SIDE^2) bool:
    the 2x2 means at least half covered."""
    a = torch.as_tensor(np.asarray(alpha) if not isinstance(alpha, torch.Tensor) else alpha)
    if a.ndim != 3 or a.shape[1] != a.shape[2] or a.shape[1] != 2 * BANK_SIDE:
        raise ValueError(f"alpha must be (N, {2 * BANK_SIDE}, {2 * BANK_SIDE}), got shape {tuple(a.shape)}")
    a = a.float() / 255.0 if a.dtype == torch.uint8 else a.float()
    n = a.shape[0]
    return a.reshape(n, BANK_SIDE, 2, BANK_SIDE, 2).mean((2, 4)).reshape(n, BANK_SIDE ** 2) >= 0.5


def frame_alphas(alpha: np.ndarray, framing: Framing = TRAINING_FRAMING) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """(N, S, S) uint8 alpha channels framed as ``framing.frame_image`` frames a photo (the
    silhouette's box, alpha >= 128, scaled to ``framing``'s extent and centre; bilinear sub-samples
    averaged over each pixel; transparent outside), all at once.

    Returns:
        (M, S, S) float alpha in [0, 1] of the M renders whose silhouette is clear of the border,
        (M, 3) float32 rows of each one's own framing (extent, centre_x, centre_y), and (M,) int
        their indices in the input.
    """
    alpha = np.asarray(alpha)
    size = alpha.shape[-1]
    mask = alpha >= 128
    rows, cols = mask.any(axis=2), mask.any(axis=1)
    clear = rows.any(axis=1) & ~rows[:, 0] & ~rows[:, -1] & ~cols[:, 0] & ~cols[:, -1]
    keep = np.flatnonzero(clear)
    if not len(keep):
        return torch.zeros(0, size, size), np.zeros((0, 3), np.float32), keep
    rows, cols = rows[keep], cols[keep]
    top = rows.argmax(axis=1).astype(np.float64)
    bottom = size - rows[:, ::-1].argmax(axis=1).astype(np.float64)
    left = cols.argmax(axis=1).astype(np.float64)
    right = size - cols[:, ::-1].argmax(axis=1).astype(np.float64)
    extent = np.maximum(right - left, bottom - top)
    own = np.stack([extent / size, (left + right) / 2 / size, (top + bottom) / 2 / size], axis=1).astype(np.float32)
    scale = framing.extent * size / extent
    offset_x = framing.centre_x * size - scale * (left + right) / 2
    offset_y = framing.centre_y * size - scale * (top + bottom) / 2
    sub = (torch.arange(size * SUPERSAMPLE, dtype=torch.float64) + 0.5) / SUPERSAMPLE  # framed coordinates
    s = torch.from_numpy(scale)[:, None]
    xs = (sub[None] - torch.from_numpy(offset_x)[:, None]) / s  # photo coordinates, pixel edges at integers
    ys = (sub[None] - torch.from_numpy(offset_y)[:, None]) / s
    gx, gy = xs * (2.0 / size) - 1.0, ys * (2.0 / size) - 1.0  # grid_sample, align_corners=False
    m = len(keep)
    k = size * SUPERSAMPLE
    grid = torch.stack([gx[:, None, :].expand(m, k, k), gy[:, :, None].expand(m, k, k)], dim=-1).float()
    src = torch.from_numpy(alpha[keep]).float()[:, None] / 255.0
    out = F.grid_sample(src, grid, mode="bilinear", padding_mode="zeros", align_corners=False)[:, 0]
    out = out.reshape(m, size, SUPERSAMPLE, size, SUPERSAMPLE).mean((2, 4))
    return out, own, keep


_BITS = np.array([bin(i).count("1") for i in range(256)], dtype=np.uint8)


def _popcount(packed: np.ndarray) -> np.ndarray:
    """Set bits of each byte (numpy's bitwise_count where it has one, numpy >= 2.0)."""
    count = getattr(np, "bitwise_count", None)
    return count(packed) if count is not None else _BITS[packed]


@dataclass(frozen=True)
class FramingBank:
    """Training renders' silhouettes framed as photos are, and the framings the renders had.

    Attributes:
        silhouettes: (N, BANK_SIDE^2) bool (``bank_features`` of each render framed to ``framing``).
        framings: (N, 3) float32 rows of (extent, centre_x, centre_y), as ``Framing``'s fields.
        framing: the framing the silhouettes were put into (a photo's is the same).
        views: (N,) int64 NMR view (0..23) of each render, or None (a bank stored before they were
            kept: it votes for no view).
    """

    silhouettes: torch.Tensor
    framings: torch.Tensor
    framing: Framing = TRAINING_FRAMING
    views: Optional[torch.Tensor] = None

    def __post_init__(self) -> None:
        if self.silhouettes.ndim != 2 or self.silhouettes.shape[1] != BANK_SIDE ** 2:
            raise ValueError(f"silhouettes must be (N, {BANK_SIDE ** 2}), got {tuple(self.silhouettes.shape)}")
        if self.framings.shape != (len(self.silhouettes), 3):
            raise ValueError(f"framings must be ({len(self.silhouettes)}, 3), got {tuple(self.framings.shape)}")
        if self.views is not None:
            views = torch.as_tensor(self.views).to("cpu", torch.int64)
            if views.shape != (len(self.silhouettes),) or bool(((views < 0) | (views >= NUM_VIEWS)).any()):
                span = f", values {int(views.min())}..{int(views.max())}" if views.numel() else ""
                raise ValueError(f"views must be ({len(self.silhouettes)},) NMR views in [0, {NUM_VIEWS}), "
                                 f"got shape {tuple(views.shape)}{span}")
            object.__setattr__(self, "views", views)
        if len(self.silhouettes) == 0:
            raise ValueError("a framing bank needs at least one render (every silhouette touched the border?)")
        packed = np.packbits(self.silhouettes.numpy().astype(np.uint8), axis=1)  # compared as bits
        object.__setattr__(self, "_packed", packed)
        object.__setattr__(self, "_area", _popcount(packed).sum(1, dtype=np.int64))

    def __len__(self) -> int:
        return len(self.silhouettes)

    def _similarity(self, framed_alpha: np.ndarray) -> torch.Tensor:
        """(N,) float64: each entry's silhouette IoU with a framed (S, S) alpha."""
        q = np.packbits(bank_features(np.asarray(framed_alpha)[None])[0].numpy().astype(np.uint8))
        inter = _popcount(self._packed & q).sum(1, dtype=np.int64)
        union = self._area + int(_popcount(q).sum()) - inter
        return torch.from_numpy(inter / np.maximum(union, 1))

    def _nearest(self, iou: torch.Tensor, neighbours: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The indices of the ``neighbours`` entries of highest ``iou`` and their weights (the IoU to
        the power ``WEIGHT_POWER``)."""
        top = torch.topk(iou, min(int(neighbours), len(self))).indices
        return top, iou[top].double() ** WEIGHT_POWER

    def _framing_of(self, iou: torch.Tensor, neighbours: int) -> Framing:
        top, w = self._nearest(iou, neighbours)
        if float(w.sum()) <= 0.0:  # nothing overlaps at all: the median framing
            return self.framing
        f = (self.framings[top].double() * w[:, None]).sum(0) / w.sum()
        return Framing(*(float(x) for x in f))

    def _votes_of(self, iou: torch.Tensor, neighbours: int) -> Optional[torch.Tensor]:
        if self.views is None:
            return None
        top, w = self._nearest(iou, neighbours)
        if float(w.sum()) <= 0.0:
            return None
        votes = torch.zeros(NUM_VIEWS, dtype=torch.float64).index_add_(0, self.views[top], w)
        return votes / votes.sum()

    def estimate(self, framed_alpha: np.ndarray, neighbours: int = BANK_NEIGHBOURS) -> Framing:
        """The framing of a photo whose (S, S) uint8 alpha has been framed to ``self.framing``: the
        mean of its ``neighbours`` nearest entries' framings (by silhouette IoU), weighted by the IoU
        to the power ``WEIGHT_POWER``."""
        return self._framing_of(self._similarity(framed_alpha), neighbours)

    def view_votes(self, framed_alpha: np.ndarray, neighbours: int = VOTE_NEIGHBOURS) -> Optional[torch.Tensor]:
        """(24,) float64 summing to 1: the views of the ``neighbours`` entries nearest a photo's
        framed alpha (as ``estimate`` reads it), each weighted as there; None for a bank without
        views, or when nothing overlaps the photo."""
        return self._votes_of(self._similarity(framed_alpha), neighbours)

    def look_up(self, framed_alpha: np.ndarray) -> tuple[Framing, Optional[torch.Tensor]]:
        """``estimate`` and ``view_votes`` of one photo (their default neighbours), from one pass over
        the bank."""
        iou = self._similarity(framed_alpha)
        return self._framing_of(iou, BANK_NEIGHBOURS), self._votes_of(iou, VOTE_NEIGHBOURS)

    def record(self) -> dict[str, Any]:
        """What the checkpoint keeps (``from_record`` reads it back): the silhouettes bit-packed."""
        out = {"side": BANK_SIDE, "silhouettes": torch.from_numpy(self._packed.copy()),
               "framings": self.framings.clone(),
               "framing": [self.framing.extent, self.framing.centre_x, self.framing.centre_y]}
        if self.views is not None:
            out["views"] = self.views.to(torch.int8)
        return out

    @classmethod
    def from_record(cls, record: dict, name: str = "framing bank") -> "FramingBank":
        """Raises ValueError naming ``name`` when the record is not a bank of this version."""
        try:
            if int(record["side"]) != BANK_SIDE:
                raise ValueError(f"silhouettes of side {record['side']}, this version compares {BANK_SIDE}")
            # A checkpoint loaded onto a GPU holds the record's tensors there: read them on the host.
            packed = torch.as_tensor(record["silhouettes"]).cpu().numpy().astype(np.uint8)
            bits = np.unpackbits(packed, axis=1)[:, :BANK_SIDE ** 2]
            views = record.get("views")
            return cls(torch.from_numpy(bits.astype(bool)),
                       torch.as_tensor(record["framings"]).detach().to("cpu", torch.float32),
                       Framing(*(float(x) for x in record["framing"])),
                       None if views is None else torch.as_tensor(views).to("cpu", torch.int64))
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"{name}: not a readable framing bank ({err})") from None


def build_framing_bank(dataset, progress: Optional[Callable[[int], None]] = None,
                       framing: Framing = TRAINING_FRAMING, max_renders: int = MAX_RENDERS) -> FramingBank:
    """The bank of every view of ``dataset``'s objects (an ``NMRDataset``'s training split:
    ``silhouettes(view)``), of every object, or of every k-th where that would hold more than
    ``max_renders`` renders; renders whose silhouette touches the border are left out.
    ``progress`` is called with 1 after each view."""
    check_int(max_renders, "max_renders", minimum=NUM_VIEWS)
    stride = -(-len(dataset) * NUM_VIEWS // max_renders)
    sils, frames, views = [], [], []
    for v in range(NUM_VIEWS):
        framed, own, _ = frame_alphas(dataset.silhouettes(v)[::stride], framing)
        sils.append(bank_features(framed))
        frames.append(torch.from_numpy(own))
        views.append(torch.full((len(own),), v, dtype=torch.int64))
        if progress is not None:
            progress(1)
    return FramingBank(torch.cat(sils), torch.cat(frames), framing, torch.cat(views))


def stored_framing_bank(path) -> Optional[FramingBank]:
    """The bank a checkpoint holds (``store_framing_bank``), or None."""
    record = load_checkpoint(path)[CHECKPOINT_KEY].get("framing_bank")
    return None if record is None else FramingBank.from_record(record, f"{path}: framing bank")


def store_framing_bank(path, bank: FramingBank) -> Path:
    """Writes ``bank`` into the checkpoint at ``path`` (atomically; the rest unchanged), where
    ``svr.inference.prediction.load_model`` finds it."""
    ckpt = load_checkpoint(path)
    ckpt[CHECKPOINT_KEY]["framing_bank"] = bank.record()
    return write_torch(Path(path), ckpt)


__all__ = ["BANK_NEIGHBOURS", "BANK_SIDE", "VOTE_NEIGHBOURS", "FramingBank", "bank_features", "build_framing_bank",
           "frame_alphas", "store_framing_bank", "stored_framing_bank"]
