"""SDFGrid: a batch of signed distance fields sampled on a regular grid.

Coordinate frame: world coordinates. ``values[b, i, j, k]`` is the SDF at the world point
``(x_i, y_j, z_k)`` with ``x_i = bbox_min.x + i * (bbox_max.x - bbox_min.x) / (Nx - 1)`` (samples lie
on the box faces), which is what ``torch.meshgrid(x, y, z, indexing="ij")`` produces.

The continuous SDF is the trilinear interpolation of the samples; points outside the box are
clamped onto it. Every sampling routine here is plain PyTorch and differentiable with respect to
the grid values (and the query points).
"""
from __future__ import annotations

from typing import Callable, Sequence, Union

import torch

BoundLike = Union[float, Sequence[float], torch.Tensor]


def _as_bound(value: BoundLike, name: str, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    t = torch.as_tensor(value, dtype=dtype, device=device).detach().clone()
    if t.ndim == 0:
        t = t.expand(3).clone()
    if t.shape != (3,):
        raise ValueError(f"{name} must be a scalar or a 3-vector, got shape {tuple(t.shape)}")
    if not torch.isfinite(t).all():
        raise ValueError(f"{name} must be finite, got {t.tolist()}")
    return t


class SDFGrid:
    """A batch of SDF grids with an axis-aligned bounding box.

    Args:
        values: (B, Nx, Ny, Nz) or (Nx, Ny, Nz) float32/float64 tensor of SDF samples (world units).
            It is kept as given (no copy), so gradients flow back to it.
        bbox_min, bbox_max: scalars or 3-vectors: the world positions of the first and last samples.
    """

    def __init__(self, values: torch.Tensor, bbox_min: BoundLike = -1.0, bbox_max: BoundLike = 1.0):
        if not isinstance(values, torch.Tensor):
            raise TypeError(f"values must be a torch.Tensor, got {type(values).__name__}")
        if values.dtype not in (torch.float32, torch.float64):
            raise TypeError(f"values must be float32 or float64, got {values.dtype}")
        if values.ndim == 3:
            values = values.unsqueeze(0)
        if values.ndim != 4:
            raise ValueError(
                f"values must have shape (B, Nx, Ny, Nz) or (Nx, Ny, Nz), got {tuple(values.shape)}"
            )
        if values.shape[0] < 1:
            raise ValueError("values must hold at least one grid (B >= 1)")
        if min(values.shape[1:]) < 2:
            raise ValueError(f"values needs at least 2 samples per axis, got {tuple(values.shape[1:])}")
        if not bool(torch.isfinite(values.detach()).all()):
            raise ValueError("values contains NaN or Inf")
        self.values = values
        self.bbox_min = _as_bound(bbox_min, "bbox_min", values.dtype, values.device)
        self.bbox_max = _as_bound(bbox_max, "bbox_max", values.dtype, values.device)
        if not bool((self.bbox_max > self.bbox_min).all()):
            raise ValueError(
                f"bbox_max must exceed bbox_min on every axis, got {self.bbox_min.tolist()} and "
                f"{self.bbox_max.tolist()}"
            )

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_function(
        cls,
        fn: Callable[[torch.Tensor], torch.Tensor],
        resolution: Union[int, Sequence[int]],
        bbox_min: BoundLike = -1.0,
        bbox_max: BoundLike = 1.0,
        dtype: torch.dtype = torch.float32,
        device: Union[str, torch.device] = "cpu",
    ) -> "SDFGrid":
        """Samples ``fn`` (world points (..., 3) -> SDF (...)) on a grid of the given resolution."""
        res = _resolution3(resolution)
        lo = _as_bound(bbox_min, "bbox_min", dtype, torch.device(device))
        hi = _as_bound(bbox_max, "bbox_max", dtype, torch.device(device))
        axes = [torch.linspace(float(lo[a]), float(hi[a]), res[a], dtype=dtype, device=device) for a in range(3)]
        pts = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1)
        return cls(fn(pts).to(dtype), lo, hi)

    # ------------------------------------------------------------------ properties
    @property
    def batch_size(self) -> int:
        return self.values.shape[0]

    @property
    def resolution(self) -> tuple[int, int, int]:
        return tuple(self.values.shape[1:])  # type: ignore[return-value]

    @property
    def voxel_size(self) -> torch.Tensor:
        """(3,) spacing between samples along x, y, z (world units)."""
        res = torch.tensor(self.resolution, dtype=self.values.dtype, device=self.values.device)
        return (self.bbox_max - self.bbox_min) / (res - 1)

    @property
    def dtype(self) -> torch.dtype:
        return self.values.dtype

    @property
    def device(self) -> torch.device:
        return self.values.device

    def points(self) -> torch.Tensor:
        """(Nx, Ny, Nz, 3) world positions of the samples."""
        axes = [
            torch.linspace(float(self.bbox_min[a]), float(self.bbox_max[a]), self.resolution[a],
                           dtype=self.dtype, device=self.device)
            for a in range(3)
        ]
        return torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1)

    def with_values(self, values: torch.Tensor) -> "SDFGrid":
        """A grid with the same box and new values."""
        return SDFGrid(values, self.bbox_min, self.bbox_max)

    def __repr__(self) -> str:
        return (f"SDFGrid(batch={self.batch_size}, resolution={self.resolution}, dtype={self.dtype}, "
                f"bbox_min={self.bbox_min.tolist()}, bbox_max={self.bbox_max.tolist()})")

    # ------------------------------------------------------------------ sampling
    def _cells(self, points: torch.Tensor):
        """Cell indices (R, 3) long and fractions (R, 3) for world points (R, 3), clamped to the box."""
        res = torch.tensor(self.resolution, device=points.device)
        u = (points - self.bbox_min) / self.voxel_size
        u = torch.minimum(torch.clamp(u, min=0.0), (res - 1).to(u.dtype))
        i0 = torch.minimum(torch.floor(u.detach()).long(), res - 2)
        return i0, u - i0.to(u.dtype)

    def _flat_index(self, b: torch.Tensor, i: torch.Tensor, j: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        nx, ny, nz = self.resolution
        return ((b * nx + i) * ny + j) * nz + k

    def sample(self, points: torch.Tensor, batch_index: torch.Tensor | None = None) -> torch.Tensor:
        """Trilinear SDF at world points.

        Args:
            points: (R, 3) world points, or (B, ..., 3) with one leading entry per grid.
            batch_index: (R,) long, the grid each point reads; required for (R, 3) points when B > 1.
        Returns:
            (R,) or (B, ...) SDF values, differentiable w.r.t. values and points.
        """
        flat, b, shape = self._flatten(points, batch_index)
        out = self._sample_flat(self.values.reshape(-1), flat, b)
        return out.reshape(shape)

    def sample_gradient(self, points: torch.Tensor, batch_index: torch.Tensor | None = None) -> torch.Tensor:
        """Central-difference SDF gradient at the grid vertices, trilinearly interpolated at points.

        This is the paper's normal construction (before normalisation). Only the vertices around
        the queried points are touched, so the cost grows with the number of points, not the grid.

        Returns:
            (R, 3) or (B, ..., 3) gradient (world units), differentiable w.r.t. values and points.
        """
        flat, b, shape = self._flatten(points, batch_index)
        i0, w = self._cells(flat)
        values = self.values.reshape(-1)
        dt, dev = values.dtype, values.device
        size = torch.tensor(self.resolution, device=dev)
        strides = torch.tensor([self.resolution[1] * self.resolution[2], self.resolution[2], 1], device=dev)
        bits = _CORNER_BITS.to(dev)
        corner = i0[:, None, :] + bits  # (R, 8, 3) vertex indices of the cell's corners
        # One-sided differences on the box faces: divide by the real spacing.
        hi = torch.minimum(corner + 1, size - 1)
        lo = torch.clamp(corner - 1, min=0)
        span = (hi - lo).to(dt) * self.voxel_size
        at = self._flat_index(b[:, None], corner[..., 0], corner[..., 1], corner[..., 2])  # (R, 8)
        stencil = at[..., None, None] + torch.stack([(hi - corner) * strides, (lo - corner) * strides], dim=-1)
        # All 48 stencil values in one gather: one scatter into the grid's gradient in backward.
        ends = _gather(values, stencil)  # (R, 8, 3, 2)
        comps = (ends[..., 0] - ends[..., 1]) / span  # (R, 8, 3): the gradient at each corner
        wsel = torch.where(bits.bool(), w[:, None, :], 1 - w[:, None, :])
        terms = (wsel[..., 0] * wsel[..., 1] * wsel[..., 2])[..., None] * comps
        grad = torch.zeros(flat.shape[0], 3, dtype=dt, device=dev)
        for c in range(8):  # summed corner by corner, in a fixed order
            grad = grad + terms[:, c]
        return grad.reshape(*shape, 3)

    def _flatten(self, points: torch.Tensor, batch_index: torch.Tensor | None):
        if points.shape[-1] != 3:
            raise ValueError(f"points must end in a dimension of 3, got {tuple(points.shape)}")
        if batch_index is None:
            if points.ndim == 2:
                if self.batch_size != 1:
                    raise ValueError("batch_index is required for (R, 3) points when the grid batch > 1")
                b = torch.zeros(points.shape[0], dtype=torch.long, device=points.device)
            else:
                if points.shape[0] != self.batch_size:
                    raise ValueError(
                        f"points' leading dimension {points.shape[0]} must equal the grid batch {self.batch_size}"
                    )
                per = points[0, ..., 0].numel()
                b = torch.arange(self.batch_size, device=points.device).repeat_interleave(per)
            shape = points.shape[:-1]
        else:
            if points.ndim != 2 or batch_index.shape != points.shape[:1]:
                raise ValueError("with batch_index, points must be (R, 3) and batch_index (R,)")
            b = batch_index.long()
            shape = points.shape[:-1]
        return points.reshape(-1, 3).to(self.dtype), b, shape

    def _sample_flat(self, values: torch.Tensor, points: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        i0, w = self._cells(points)
        base = self._flat_index(b, i0[:, 0], i0[:, 1], i0[:, 2])
        offsets = (_CORNER_BITS.to(points.device) * torch.tensor(
            [self.resolution[1] * self.resolution[2], self.resolution[2], 1], device=points.device)).sum(-1)
        # The 8 corners in one gather, ordered c000, c001, c010, ..., c111 (bits x, y, z).
        c = _gather(values, base[:, None] + offsets)  # (R, 8)
        c = c[:, 0::2] + (c[:, 1::2] - c[:, 0::2]) * w[:, 2:3]  # along z: c00, c01, c10, c11
        c = c[:, 0::2] + (c[:, 1::2] - c[:, 0::2]) * w[:, 1:2]  # along y: c0, c1
        return c[:, 0] + (c[:, 1] - c[:, 0]) * w[:, 0]

    # ------------------------------------------------------------------ whole-grid operations
    def vertex_gradient(self) -> torch.Tensor:
        """(B, Nx, Ny, Nz, 3) central finite differences at every vertex (one-sided on the faces)."""
        v = self.values
        vox = self.voxel_size
        comps = []
        for axis in range(3):
            d = torch.gradient(v, spacing=(float(vox[axis]),), dim=axis + 1, edge_order=1)[0]
            comps.append(d)
        return torch.stack(comps, dim=-1)

    def resample(self, resolution: Union[int, Sequence[int]]) -> "SDFGrid":
        """Trilinear resampling onto a grid of another resolution over the same box (coarse to fine)."""
        res = _resolution3(resolution)
        v = self.values.unsqueeze(1)
        out = torch.nn.functional.interpolate(v, size=res, mode="trilinear", align_corners=True)
        return SDFGrid(out.squeeze(1), self.bbox_min, self.bbox_max)


# (8, 3) the offsets of a cell's corners, corner c = (c >> 2 & 1, c >> 1 & 1, c & 1).
_CORNER_BITS = torch.tensor([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)])


def _gather(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """values (M,) at a long index of any shape. index_select, whose backward is one index_add_ into
    the gradient (a plain ``values[index]`` is slower both ways)."""
    return values.index_select(0, index.reshape(-1)).view(index.shape)


def _resolution3(resolution: Union[int, Sequence[int]]) -> tuple[int, int, int]:
    if isinstance(resolution, int):
        res = (resolution,) * 3
    else:
        res = tuple(int(r) for r in resolution)
    if len(res) != 3 or min(res) < 2:
        raise ValueError(f"resolution must be an int or 3 ints, each >= 2, got {resolution!r}")
    return res  # type: ignore[return-value]
