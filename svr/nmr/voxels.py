"""The benchmark's geometry: clipping to the object box, the NMR voxel frame and voxelisation
(SPEC section 5). Marching cubes lives in ``sdfcommon.numerics.meshing``."""
from __future__ import annotations

from typing import Union

import numba
import numpy as np
import torch

import renderer
from sdfcommon.numerics.meshing import BoundLike, sdf_to_mesh
from sdfcommon.tooling.checks import check_int, check_positive, check_shape, check_tensor

# Objects are normalised into [-0.5, 0.5]^3 (longest side 1), where the outermost benchmark voxel
# centres lie. A quarter voxel (1/31) beyond them keeps those centres inside and stays within the
# benchmark's 32^3 grid (``u = 31 v + 16 < 32``), whose voxeliser drops geometry outside it.
OBJECT_BOX_HALF = 0.5 + 0.25 / 31


def clip_to_box(values: torch.Tensor, bbox_min: BoundLike, bbox_max: BoundLike,
                half: float = OBJECT_BOX_HALF) -> torch.Tensor:
    """The SDF of the shape intersected with the cube ``[-half, half]^3``: ``max(sdf, box sdf)``.

    Why: a predicted surface that pokes out of the benchmark's voxel grid is cut open there by the
    benchmark voxeliser (it drops what lies outside), and its 6-connected fill from the border then
    leaks into the shape and leaves the inside empty. Intersecting the prediction with the box the
    objects are normalised into closes such shapes at the box instead. Inside the cube the values
    are unchanged.

    Args:
        values: (B, Nx, Ny, Nz) or (Nx, Ny, Nz) SDF samples (renderer.SDFGrid layout, world units)
            over the box ``[bbox_min, bbox_max]`` (scalars or 3-vectors).
        half: the cube's half side (world units).
    Returns:
        a tensor like ``values`` (same shape, dtype and device).
    """
    check_tensor(values, "values", "B, Nx, Ny, Nz", "Nx, Ny, Nz", floating=True)
    half = check_positive(half, "half")
    lo = torch.as_tensor(bbox_min, dtype=values.dtype, device=values.device).expand(3)
    hi = torch.as_tensor(bbox_max, dtype=values.dtype, device=values.device).expand(3)
    axes = [torch.linspace(float(lo[a]), float(hi[a]), values.shape[-3 + a], dtype=values.dtype,
                           device=values.device) for a in range(3)]
    q = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).abs() - float(half)
    box = q.clamp(min=0).norm(dim=-1) + q.amax(-1).clamp(max=0)
    return torch.maximum(values, box)


# ---------------------------------------------------------------------------------------------
# The NMR ShapeNet voxel frame and the benchmark's mesh voxelisation (SPEC section 5).
#
# Voxel ``vox[i, j, k]`` (axis 0 = +y, axis 1 = +x, axis 2 = -z) has its centre at the world point
# ``((j - c) / (R - 1), (i - c) / (R - 1), (c - k) / (R - 1))`` with ``c = (R - 1) / 2`` (R = 32: voxel
# size 1/31, centres spanning [-0.5, 0.5]). The benchmark scales a mesh by ``u = (R - 1) * v + R / 2``
# (world ``v`` -> voxel units ``u``; voxel n covers ``u`` in [n, n + 1)) and voxelises it in x, y, z
# index order before transposing to (y, x, -z): ``xyz_to_nmr_voxels`` is that transpose.

NMR_VOXEL_RESOLUTION = 32


def nmr_voxel_centres(resolution: int = NMR_VOXEL_RESOLUTION, dtype: torch.dtype = torch.float32,
                      device: Union[str, torch.device] = "cpu") -> torch.Tensor:
    """World positions of the voxel centres of an NMR-frame voxel grid.

    Returns:
        (R, R, R, 3) tensor: entry ``[i, j, k]`` is ``(x, y, z)`` of voxel ``vox[i, j, k]`` (world, y up).
    """
    check_int(resolution, "resolution", minimum=2)
    c = (resolution - 1) / 2.0
    n = torch.arange(resolution, dtype=dtype, device=device)
    s = (n - c) / (resolution - 1)
    i, j, k = torch.meshgrid(s, s, s, indexing="ij")
    # axis 0 -> +y, axis 1 -> +x, axis 2 -> -z
    return torch.stack([j, i, -k], dim=-1)


def _check_cube(voxels, name: str) -> None:
    check_shape(voxels, name, "..., R, R, R")


def nmr_to_xyz_voxels(voxels):
    """Reorders NMR-frame voxels ``vox[..., i, j, k]`` (y, x, -z) to ``out[..., a, b, c]`` indexed by
    (x, y, z) increasing, i.e. renderer.SDFGrid's layout: ``out[..., j, i, R - 1 - k] = vox[..., i, j, k]``.

    Args:
        voxels: (..., R, R, R) numpy array or torch tensor, any dtype.
    Returns:
        the same type and shape (a view where possible).
    """
    _check_cube(voxels, "voxels")
    if isinstance(voxels, torch.Tensor):
        return voxels.transpose(-3, -2).flip(-1)
    return np.swapaxes(voxels, -3, -2)[..., ::-1]


def xyz_to_nmr_voxels(grid):
    """Inverse of ``nmr_to_xyz_voxels``: (x, y, z)-indexed (..., R, R, R) -> NMR frame (y, x, -z)."""
    _check_cube(grid, "grid")
    if isinstance(grid, torch.Tensor):
        return grid.flip(-1).transpose(-3, -2)
    return np.swapaxes(grid[..., ::-1], -3, -2)


def voxels_to_sdf(voxels, pad: int = 2) -> tuple[np.ndarray, float, float]:
    """A signed distance grid (renderer.SDFGrid layout) whose zero level bounds the occupied voxels.

    Each voxel centre gets the Euclidean distance (world units) from the voxel-centre lattice to the
    other class, minus half a voxel (outside positive, inside negative), so the surface lies halfway
    between an occupied and an empty centre.

    Args:
        voxels: (R, R, R) bool in the NMR frame.
        pad: empty voxels added on every side (so the surface never touches the box).
    Returns:
        values: (R + 2 pad,)^3 float64, ``values[a, b, c]`` at world ``(x_a, y_b, z_c)``;
        bbox_min, bbox_max: the scalar box of the samples (``-/+ (0.5 + pad / (R - 1))``).
    """
    from scipy import ndimage  # heavy: only the voxel-to-SDF conversions need it

    v = np.asarray(voxels)
    check_shape(v, "voxels", "R, R, R")
    check_int(pad, "pad", minimum=0)
    r = v.shape[0]
    occ = np.pad(np.ascontiguousarray(nmr_to_xyz_voxels(v.astype(bool))), pad)
    size = 1.0 / (r - 1)
    if not occ.any():
        values = np.full(occ.shape, 0.5 * size * (1 + 2 * pad), dtype=np.float64)
    elif occ.all():
        values = np.full(occ.shape, -0.5 * size, dtype=np.float64)
    else:
        outside = ndimage.distance_transform_edt(~occ)  # > 0 at empty centres
        inside = ndimage.distance_transform_edt(occ)    # > 0 at occupied centres
        values = np.where(occ, -(inside - 0.5), outside - 0.5) * size
    half = 0.5 + pad * size
    return values, -half, half


def fill_enclosed(voxels) -> np.ndarray:
    """The benchmark's fill: every voxel that an empty, 6-connected path cannot reach from an empty
    border voxel becomes occupied (cavities are filled; a shell with a hole stays hollow).

    Args:
        voxels: (..., R, R, R) bool (any frame: the rule is symmetric).
    Returns:
        (..., R, R, R) bool numpy array.
    """
    from scipy import ndimage  # heavy: only the voxel-to-SDF conversions need it

    v = np.asarray(voxels).astype(bool)
    _check_cube(v, "voxels")
    flat = v.reshape(-1, *v.shape[-3:])
    out = np.empty_like(flat)
    six = ndimage.generate_binary_structure(3, 1)
    for n, vol in enumerate(flat):
        labels, _ = ndimage.label(~vol, structure=six)
        border = np.concatenate([labels[0].ravel(), labels[-1].ravel(), labels[:, 0].ravel(),
                                 labels[:, -1].ravel(), labels[:, :, 0].ravel(), labels[:, :, -1].ravel()])
        outside = np.isin(labels, np.unique(border[border > 0]))
        out[n] = ~outside
    return out.reshape(v.shape)


def _rasterize_triangles_py(tri: np.ndarray, surf: np.ndarray) -> None:
    """Marks the surface voxels of triangles (voxel units, (F, 3, 3), x/y/z order) in ``surf``
    (R, R, R) uint8, indexed (x, y, z). See ``voxelize_mesh_nmr`` for the rule."""
    r = surf.shape[0]
    for f in range(tri.shape[0]):
        for axis in range(3):
            # The lattice lines run along ``axis``; (a, b) are the two other axes in increasing order.
            a = 1 if axis == 0 else 0
            b = 1 if axis == 2 else 2
            p0a, p0b, p0z = tri[f, 0, a], tri[f, 0, b], tri[f, 0, axis]
            e1a, e1b, e1z = tri[f, 1, a] - p0a, tri[f, 1, b] - p0b, tri[f, 1, axis] - p0z
            e2a, e2b, e2z = tri[f, 2, a] - p0a, tri[f, 2, b] - p0b, tri[f, 2, axis] - p0z
            det = e1a * e2b - e2a * e1b
            if det == 0.0:
                continue  # edge-on in this projection: seen by the other two
            lo_a = max(int(np.ceil(min(p0a, p0a + e1a, p0a + e2a))), 0)
            hi_a = min(int(np.floor(max(p0a, p0a + e1a, p0a + e2a))), r - 1)
            lo_b = max(int(np.ceil(min(p0b, p0b + e1b, p0b + e2b))), 0)
            hi_b = min(int(np.floor(max(p0b, p0b + e1b, p0b + e2b))), r - 1)
            for la in range(lo_a, hi_a + 1):
                for lb in range(lo_b, hi_b + 1):
                    da, db = la - p0a, lb - p0b
                    # Barycentric coordinates of the lattice line in the projected triangle.
                    w1 = (da * e2b - db * e2a) / det
                    w2 = (db * e1a - da * e1b) / det
                    if w1 < 0.0 or w2 < 0.0 or w1 + w2 > 1.0:
                        continue
                    zi = int(np.floor(p0z + w1 * e1z + w2 * e2z))
                    if zi < 0 or zi >= r:
                        continue
                    # The line is shared by four voxels: (la, lb) and its -1 neighbours.
                    for ia in (la - 1, la):
                        for ib in (lb - 1, lb):
                            if ia < 0 or ib < 0:
                                continue
                            if axis == 0:
                                surf[zi, ia, ib] = 1
                            elif axis == 1:
                                surf[ia, zi, ib] = 1
                            else:
                                surf[ia, ib, zi] = 1


_rasterize_triangles = None


def _rasterizer():
    """The numba-compiled triangle rasteriser (compiled on first use, cached on disk)."""
    global _rasterize_triangles
    if _rasterize_triangles is None:
        _rasterize_triangles = numba.njit(cache=True)(_rasterize_triangles_py)
    return _rasterize_triangles


def mesh_surface_voxels(vertices, faces, resolution: int = NMR_VOXEL_RESOLUTION) -> np.ndarray:
    """The surface voxels of a triangle mesh by the NMR benchmark's rules (SPEC section 5), before
    any fill.

    With ``u = (R - 1) * v + R / 2`` (world -> voxel units), per axis and per triangle not edge-on
    to that axis: every integer lattice line along the axis that meets the triangle (inclusive
    barycentric test) marks the voxel ``floor(u_axis)`` at the hit and its -1 neighbours in the two
    other axes (the line is shared by four voxels); every vertex marks its voxel. Geometry outside
    the grid is dropped. Computed in float64 (the benchmark's CUDA code used float32: a lattice line
    exactly on an edge can differ).

    Args:
        vertices: (V, 3) float world coordinates (x, y, z). faces: (F, 3) int vertex indices.
        resolution: R (32 for the benchmark).
    Returns:
        (R, R, R) bool indexed (x, y, z) increasing (``xyz_to_nmr_voxels`` gives the NMR frame).
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    check_shape(v, "vertices", "V, 3")
    check_shape(f, "faces", "F, 3")
    if f.size and not np.issubdtype(f.dtype, np.integer):
        raise TypeError(f"faces must be an integer array, got {f.dtype}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces index vertices out of range [0, {len(v)})")
    if not np.isfinite(v).all():
        raise ValueError("vertices contains NaN or Inf")
    r = check_int(resolution, "resolution", minimum=2)
    u = v * (r - 1) + r / 2.0
    surf = np.zeros((r, r, r), dtype=np.uint8)
    if len(f):
        _rasterizer()(np.ascontiguousarray(u[f]), surf)
    if len(u):
        idx = np.floor(u).astype(np.int64)
        ok = ((idx >= 0) & (idx < r)).all(axis=1)
        surf[idx[ok, 0], idx[ok, 1], idx[ok, 2]] = 1
    return surf.astype(bool)


def voxelize_mesh_nmr(vertices, faces, resolution: int = NMR_VOXEL_RESOLUTION) -> np.ndarray:
    """Solid voxels of a triangle mesh by the NMR benchmark's rules (SPEC section 5): its surface
    voxels (``mesh_surface_voxels``), then ``fill_enclosed`` fills whatever the border cannot reach.

    Args:
        vertices: (V, 3) float world coordinates (x, y, z). faces: (F, 3) int vertex indices.
        resolution: R (32 for the benchmark).
    Returns:
        (R, R, R) bool in the NMR frame (``vox[i, j, k]``: i = +y, j = +x, k = -z).
    """
    surf = mesh_surface_voxels(vertices, faces, resolution)
    return np.ascontiguousarray(xyz_to_nmr_voxels(fill_enclosed(surf)))


def voxelize_sdf_protocol(values, bbox_min: BoundLike = -1.0, bbox_max: BoundLike = 1.0, level: float = 0.0,
                          resolution: int = NMR_VOXEL_RESOLUTION) -> np.ndarray:
    """The benchmark's voxels of one SDF grid: marching-cubes mesh (``sdf_to_mesh``, closed at the
    box), then ``voxelize_mesh_nmr``.

    Args:
        values: (Nx, Ny, Nz) SDF samples in renderer.SDFGrid's layout over the box.
    Returns:
        (R, R, R) bool in the NMR frame; all empty when the grid has no surface.
    """
    mesh = sdf_to_mesh(values, bbox_min, bbox_max, level=level, close=True)
    if len(mesh.faces) == 0:
        # No crossing: everything inside (all negative) covers the box; nothing otherwise.
        v = values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else np.asarray(values)
        if v.size and float(np.max(v)) < level:
            lo = np.broadcast_to(np.asarray(bbox_min, float), (3,))
            hi = np.broadcast_to(np.asarray(bbox_max, float), (3,))
            pts = nmr_voxel_centres(resolution, dtype=torch.float64).numpy()
            return ((pts >= lo) & (pts <= hi)).all(-1)
        return np.zeros((resolution,) * 3, dtype=bool)
    return voxelize_mesh_nmr(mesh.vertices, mesh.faces, resolution)


def sdf_at_voxel_centres(values: torch.Tensor, bbox_min: BoundLike = -1.0, bbox_max: BoundLike = 1.0,
                         resolution: int = NMR_VOXEL_RESOLUTION) -> tuple[torch.Tensor, torch.Tensor]:
    """The trilinear SDF at the NMR voxel centres, differentiable in ``values``.

    Args:
        values: (B, Nx, Ny, Nz) float tensor in renderer.SDFGrid's layout over ``[bbox_min, bbox_max]``.
    Returns:
        ``(sdf, inside)``: (B, R, R, R) samples in the NMR frame and a (R, R, R) bool tensor of the
        centres inside the grid's box (elsewhere the samples are the border's).
    """
    grid = renderer.SDFGrid(values, bbox_min, bbox_max)
    pts = nmr_voxel_centres(resolution, dtype=grid.dtype, device=grid.device)
    b = grid.batch_size
    sdf = grid.sample(pts.unsqueeze(0).expand(b, -1, -1, -1, -1).reshape(b, -1, 3))
    inside_box = ((pts >= grid.bbox_min) & (pts <= grid.bbox_max)).all(-1)
    return sdf.reshape(b, resolution, resolution, resolution), inside_box


def voxelize_sdf_direct(values: torch.Tensor, bbox_min: BoundLike = -1.0, bbox_max: BoundLike = 1.0,
                        level: float = 0.0, resolution: int = NMR_VOXEL_RESOLUTION) -> torch.Tensor:
    """Fast voxels of SDF grids: the trilinear SDF at the NMR voxel centres is below ``level``.
    Centres outside the grid's box are empty (as the protocol's mesh is closed at the box).

    Args:
        values: (B, Nx, Ny, Nz) or (Nx, Ny, Nz) float tensor in renderer.SDFGrid's layout.
    Returns:
        (B, R, R, R) or (R, R, R) bool tensor in the NMR frame, on values' device.
    """
    check_tensor(values, "values")
    squeeze = values.ndim == 3
    v = values.detach()
    sdf, inside_box = sdf_at_voxel_centres(v.float() if v.dtype not in (torch.float32, torch.float64) else v,
                                           bbox_min, bbox_max, resolution)
    occ = (sdf < level) & inside_box
    return occ[0] if squeeze else occ
