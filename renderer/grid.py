"""SDFGrid: a batch of signed distance fields sampled on a regular grid, in world coordinates:
``values[b, i, j, k]`` is the SDF at the world point ``(x_i, y_j, z_k)`` with
``x_i = bbox_min.x + i * (bbox_max.x - bbox_min.x) / (Nx - 1)`` (samples lie on the box faces), as
``torch.meshgrid(x, y, z, indexing="ij")`` gives them. The continuous SDF is the trilinear
interpolation of the samples; points outside the box are clamped onto it. Every sampling here is
plain PyTorch, differentiated by autograd with respect to the grid values and the query points
(renderer/shared_gradient.py gathers for two of them into one shared gradient buffer, for speed).
"""
from __future__ import annotations

import math
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


def _version(t: torch.Tensor) -> int | None:
    """torch's count of in-place changes of ``t``; None for inference tensors, which keep none."""
    try:
        return t._version
    except RuntimeError:
        return None


def require_finite(values: torch.Tensor, name: str) -> None:
    """Raises ValueError naming ``name`` when ``values`` (any shape) holds NaN or Inf.

    One min/max pass over the tensor (NaN propagates to both): cheap beside a march.
    """
    lowest, highest = torch.aminmax(values.detach())
    if not (math.isfinite(lowest) and math.isfinite(highest)):
        raise ValueError(f"{name} contains NaN or Inf; expected finite SDF samples")


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
        require_finite(values, "values")
        self._checked = (values, _version(values))  # what require_finite saw (see ``unchanged_since_checked``)
        self.values = values
        # The box is checked and kept on the host too (``host_box``): the kernels' parameters are
        # made from it without waiting for the GPU.
        lo = _as_bound(bbox_min, "bbox_min", values.dtype, torch.device("cpu"))
        hi = _as_bound(bbox_max, "bbox_max", values.dtype, torch.device("cpu"))
        if not bool((hi > lo).all()):
            raise ValueError(f"bbox_max must exceed bbox_min on every axis, got {lo.tolist()} and {hi.tolist()}")
        self._box_cpu = (lo, hi)
        self.bbox_min, self.bbox_max = lo.to(values.device), hi.to(values.device)

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

    def host_box(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(bbox_min, bbox_max) as CPU tensors (the grid's dtype), copied from the device once."""
        box = getattr(self, "_box_cpu", None)
        if box is None:
            box = self._box_cpu = (self.bbox_min.detach().cpu(), self.bbox_max.detach().cpu())
        return box

    def host_voxel_size(self) -> torch.Tensor:
        """``voxel_size`` as a CPU tensor (the same arithmetic, on the host box)."""
        lo, hi = self.host_box()
        return (hi - lo) / (torch.tensor(self.resolution, dtype=lo.dtype) - 1)

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

    def unchanged_since_checked(self) -> bool:
        """Whether ``values`` is still the tensor this grid checked for NaN/Inf when it was built, with
        no in-place change since (torch counts them in ``Tensor._version``), so the check still holds."""
        tensor, version = getattr(self, "_checked", (None, None))
        return tensor is self.values and version is not None and version == _version(self.values)

    def detach(self) -> "SDFGrid":
        """The same grid cut from autograd: ``values.detach()`` (shares memory, no copy) and the
        same box, e.g. for sampling it without recording gradients. Not checked again (this grid was)."""
        out = SDFGrid._unchecked(self.values.detach(), self.bbox_min.detach(), self.bbox_max.detach())
        out._box_cpu = getattr(self, "_box_cpu", None)
        return out

    @staticmethod
    def _unchecked(values: torch.Tensor, bbox_min: torch.Tensor, bbox_max: torch.Tensor) -> "SDFGrid":
        """A grid from parts of a grid already checked (``__init__`` would check and convert again)."""
        out = SDFGrid.__new__(SDFGrid)
        out.values, out.bbox_min, out.bbox_max = values, bbox_min, bbox_max
        return out

    def __repr__(self) -> str:
        return (f"SDFGrid(batch={self.batch_size}, resolution={self.resolution}, dtype={self.dtype}, "
                f"bbox_min={self.bbox_min.tolist()}, bbox_max={self.bbox_max.tolist()})")

    # ------------------------------------------------------------------ sampling
    @property
    def _index_dtype(self) -> torch.dtype:
        """The integer type of flat indices into ``values``: int32 while they fit (gathers and
        scatters with int32 indices are faster on the CPU than with int64), else int64."""
        return torch.int32 if self.values.numel() < 2**31 else torch.int64

    def _cells(self, points: torch.Tensor):
        """Cell indices (R, 3) (``_index_dtype``) and fractions (R, 3) for world points (R, 3),
        clamped to the box."""
        res = torch.tensor(self.resolution, device=points.device, dtype=self._index_dtype)
        u = (points - self.bbox_min) / self.voxel_size
        u = torch.minimum(torch.clamp(u, min=0.0), (res - 1).to(u.dtype))
        i0 = torch.minimum(torch.floor(u.detach()).to(res.dtype), res - 2)
        return i0, u - i0.to(u.dtype)

    def _flat_index(self, b: torch.Tensor, i: torch.Tensor, j: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        nx, ny, nz = self.resolution
        return ((b.to(i.dtype) * nx + i) * ny + j) * nz + k

    def sample(self, points: torch.Tensor, batch_index: torch.Tensor | None = None) -> torch.Tensor:
        """Trilinear SDF at world points.

        Args:
            points: (R, 3) world points, or (B, ..., 3) with one leading entry per grid.
            batch_index: (R,) long, the grid each point reads; required for (R, 3) points when B > 1.
        Returns:
            (R,) or (B, ...) SDF values, differentiable w.r.t. values and points.
        """
        flat, b, shape = self._flatten(points, batch_index)
        return self._sample_flat(flat, b).reshape(shape)

    def sample_gradient(self, points: torch.Tensor, batch_index: torch.Tensor | None = None) -> torch.Tensor:
        """Central-difference SDF gradient at the grid vertices, trilinearly interpolated at points.

        This is the paper's normal construction (before normalisation). Only the vertices around
        the queried points are touched, so the cost grows with the number of points, not the grid.

        Returns:
            (R, 3) or (B, ..., 3) gradient (world units), differentiable w.r.t. values and points.
        """
        flat, b, shape = self._flatten(points, batch_index)
        i0, w = self._cells(flat)
        dt, dev = self.values.dtype, self.values.device
        tables = _stencil_tables(dev, self.resolution, dt)
        # The 32 distinct vertices the central differences at the cell's 8 corners read, as flat
        # indices (K, 32); on the box faces the differences are one-sided (the clamp repeats a
        # vertex): those few cells are redone with the clamp.
        vertex = self._flat_index(b, i0[:, 0], i0[:, 1], i0[:, 2])[:, None] + tables["offsets"].to(i0.dtype)
        low = i0 == 0
        high = i0 == torch.tensor(self.resolution, device=dev, dtype=i0.dtype) - 2
        on_face = (low | high).any(dim=1).nonzero().squeeze(1)
        if on_face.numel():
            vertex[on_face] = self._clamped_stencil(b[on_face], i0[on_face], tables["positions"])
        # Spacing of each corner's difference: 2 voxels, 1 where one-sided; (K, 24) inverses, per corner and axis.
        vox = self.voxel_size
        spans = torch.cat([(2 - low.to(dt)) * vox, (2 - high.to(dt)) * vox], dim=1)  # (K, 6): bit 0, bit 1
        inv_span = (1 / spans).index_select(1, tables["span"])
        return self._interpolate_stencil(vertex, w, inv_span, tables).reshape(*shape, 3)

    def _clamped_stencil(self, b: torch.Tensor, i0: torch.Tensor, positions: torch.Tensor) -> torch.Tensor:
        """Flat indices (K, 32) of the stencil vertices at ``positions`` (32, 3) (per axis 0..3 for
        i0 - 1 .. i0 + 2), each coordinate clamped into the grid."""
        nx, ny, nz = self.resolution
        top = torch.tensor(self.resolution, device=i0.device, dtype=i0.dtype) - 1
        coords = torch.minimum(torch.clamp(i0[:, None, :] + (positions.to(i0.dtype) - 1), min=0), top)  # (K, 32, 3)
        return self._flat_index(b[:, None], coords[..., 0], coords[..., 1], coords[..., 2])

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

    def _sample_flat(self, points: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        i0, w = self._cells(points)
        base = self._flat_index(b, i0[:, 0], i0[:, 1], i0[:, 2])
        offsets = (_CORNER_BITS.to(points.device) * torch.tensor(
            [self.resolution[1] * self.resolution[2], self.resolution[2], 1], device=points.device)).sum(-1)
        offsets = offsets.to(base.dtype)
        # The 8 corners in one gather, ordered c000, c001, c010, ..., c111 (bits x, y, z).
        corners = base[:, None] + offsets  # (R, 8)
        return self._interpolate_corners(corners, w)

    def _interpolate_corners(self, corners: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """Trilinear interpolation (R,) of the values at the flat indices ``corners`` (R, 8) (order
        c000, ..., c111) with the fractions w (R, 3). Plain autograd; renderer/shared_gradient.py
        overrides the gather."""
        return lerp_corners(self.values.reshape(-1).index_select(0, corners.reshape(-1)).view(corners.shape), w)

    def _interpolate_stencil(self, vertex: torch.Tensor, w: torch.Tensor, inv_span: torch.Tensor,
                             tables: dict[str, torch.Tensor]) -> torch.Tensor:
        """The normal construction of ``sample_gradient`` (K, 3), as 2-D products with the constant
        tables of ``_stencil_tables`` (column e = 3 * corner + axis): gather the 32 stencil vertices
        ``vertex`` (K, 32); ``d = (stencil @ diff) * inv_span`` (K, 24) are the central differences
        at the cell's 8 corners along x, y, z; the gradient is their trilinear interpolation with the
        fractions w (K, 3), ``(weight24 * d) @ axis_sum``. Plain autograd;
        renderer/shared_gradient.py overrides the gather."""
        k = vertex.shape[0]
        stencil = self.values.reshape(-1).index_select(0, vertex.reshape(-1)).view(k, 32)
        return stencil_gradient(stencil, w, inv_span, tables)

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


def _build_stencil_tables() -> dict[str, torch.Tensor]:
    """Where, among the 32 gathered stencil vertices of ``sample_gradient``, each corner's central
    difference finds its two ends.

    Vertices are positions (x, y, z) in the per-axis coordinates i0 - 1 .. i0 + 2 (0..3), ordered
    as ``sample_gradient`` gathers them: the cell's own 8 (all in 1..2), then those beyond the x
    faces (x in 0, 3), the y faces, the z faces, each group in C order. hi, lo (24,): for corner c
    and axis a (entry 3 c + a), the vertex after and before the corner along a; span (24,): which
    spacing it divides by, in (bit 0: x, y, z, bit 1: x, y, z). positions (32, 3): the vertices.
    """
    inner, outer = (1, 2), (0, 3)
    groups = [(inner, inner, inner), (outer, inner, inner), (inner, outer, inner), (inner, inner, outer)]
    vertices = [(x, y, z) for gx, gy, gz in groups for x in gx for y in gy for z in gz]
    where = {v: n for n, v in enumerate(vertices)}
    hi, lo = [], []
    for c in range(8):
        bits = ((c >> 2) & 1, (c >> 1) & 1, c & 1)
        for a in range(3):
            up = [1 + d for d in bits]
            down = list(up)
            up[a], down[a] = bits[a] + 2, bits[a]
            hi.append(where[tuple(up)])
            lo.append(where[tuple(down)])
    span = [3 * ((c >> (2 - a)) & 1) + a for c in range(8) for a in range(3)]
    return {"hi": torch.tensor(hi), "lo": torch.tensor(lo), "span": torch.tensor(span),
            "positions": torch.tensor(vertices)}


_STENCIL = _build_stencil_tables()
_STENCIL_ON: dict[tuple, dict[str, torch.Tensor]] = {}


def _stencil_tables(device: torch.device, resolution: tuple[int, int, int],
                    dtype: torch.dtype) -> dict[str, torch.Tensor]:
    """The stencil tables on ``device``: ``offsets`` (32,), the vertices' flat offsets from the
    cell's first corner in a grid of this resolution; and constant matrices in ``dtype`` for
    ``stencil_gradient`` (column e = 3 * corner + axis): ``diff`` (32, 24), +1 at (hi[e], e) and
    -1 at (lo[e], e), so ``stencil @ diff`` is every difference ``hi - lo``; ``repeat`` (8, 24),
    each corner to its 3 columns; ``axis_sum`` (24, 3), the sum over corners."""
    key = (device, resolution, dtype)
    if key not in _STENCIL_ON:
        strides = torch.tensor([resolution[1] * resolution[2], resolution[2], 1])
        offsets = ((_STENCIL["positions"] - 1) * strides).sum(-1)
        entries = torch.arange(24)
        diff = torch.zeros(32, 24, dtype=dtype)
        diff[_STENCIL["hi"], entries] = 1.0
        diff[_STENCIL["lo"], entries] = -1.0
        repeat = torch.zeros(8, 24, dtype=dtype)
        repeat[entries // 3, entries] = 1.0
        axis_sum = torch.zeros(24, 3, dtype=dtype)
        axis_sum[entries, entries % 3] = 1.0
        mats = {"diff": diff, "repeat": repeat, "axis_sum": axis_sum}
        _STENCIL_ON[key] = {**{k: v.to(device) for k, v in _STENCIL.items()}, "offsets": offsets.to(device),
                            **{k: v.to(device) for k, v in mats.items()}}
    return _STENCIL_ON[key]


def lerp_corners(c: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Trilinear interpolation of corner values c (R, 8) (order c000, c001, ..., c111) with
    fractions w (R, 3): halved along z, y, x (unbind rather than strided slices: cheaper in backward)."""
    wx, wy, wz = w.unbind(1)
    c0, c1 = c.view(-1, 4, 2).unbind(-1)
    c = c0 + (c1 - c0) * wz[:, None]  # c00, c01, c10, c11
    c0, c1 = c.view(-1, 2, 2).unbind(-1)
    c = c0 + (c1 - c0) * wy[:, None]  # c0, c1
    c0, c1 = c.unbind(-1)
    return c0 + (c1 - c0) * wx


def corner_weights(w: torch.Tensor) -> torch.Tensor:
    """(R, 8) trilinear weights of the corners (order c000, ..., c111) for fractions w (R, 3):
    ``(x * y) * z`` per corner. Products of (R,) vectors, then one stack: broadcasting over the
    size-2 axes instead measured several times slower."""
    wx, wy, wz = w.unbind(1)
    x, y, z = (1 - wx, wx), (1 - wy, wy), (1 - wz, wz)
    xy = [x[i] * y[j] for i in (0, 1) for j in (0, 1)]
    return torch.stack([xy[c >> 1] * z[c & 1] for c in range(8)], dim=1)


def stencil_gradient(stencil: torch.Tensor, w: torch.Tensor, inv_span: torch.Tensor,
                     tables: dict[str, torch.Tensor]) -> torch.Tensor:
    """(K, 3) the trilinear interpolation with fractions w (K, 3) of the central differences at a
    cell's corners, from its 32 stencil values (K, 32) and inverse spacings (K, 24) (see
    ``SDFGrid._interpolate_stencil``)."""
    d = stencil @ tables["diff"] * inv_span
    weight24 = corner_weights(w) @ tables["repeat"]  # each corner's weight in its 3 columns
    return (weight24 * d) @ tables["axis_sum"]


def _resolution3(resolution: Union[int, Sequence[int]]) -> tuple[int, int, int]:
    if isinstance(resolution, int):
        res = (resolution,) * 3
    else:
        res = tuple(int(r) for r in resolution)
    if len(res) != 3 or min(res) < 2:
        raise ValueError(f"resolution must be an int or 3 ints, each >= 2, got {resolution!r}")
    return res  # type: ignore[return-value]
