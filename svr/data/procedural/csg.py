"""Analytic signed distance functions of CSG shapes: a small program of primitives and set
operations. A shape is a left-deep CSG program: ``d = prim_0``, then for each later row ``d = op(d,
prim_i)`` with op union (min), subtract (``max(d, -prim)``) or intersect (max). Every primitive is
exact (its SDF is the Euclidean distance); the set operations keep a lower bound of the distance
(outside the shape the value never exceeds the true distance), so sphere tracing with it never steps
through the surface. Two evaluators of the same program: ``CSGShape.sdf`` in PyTorch (the reference,
differentiable) and a numba kernel (``sdf_numpy``, ``trace_rays``, ``surface_normals``) for the
renders of the procedural dataset; tests/svr/data/procedural/test_procedural.py checks that they agree. Frames:
world coordinates, y up. ``CSGShape.scale`` and ``CSGShape.offset`` map the program's own frame to
the world: ``sdf_world(p) = scale * sdf_program(p / scale + offset)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence

import numba
import numpy as np
import torch

import renderer
from sdfcommon.tooling.checks import check_shape

# The parallel kernels below share numba's process-wide thread pool with the renderer's march,
# which must start it itself (its layer cannot change later; renderer.start_cpu_thread_pool says why).
renderer.start_cpu_thread_pool()

# Primitive kinds (column 0) and their parameters (columns 14..18), in the primitive's local frame:
BOX = 0       # half extents a, b, c along x, y, z; edge rounding radius d
SPHERE = 1    # radius a
CYLINDER = 2  # axis y: radius a, half height b
CAPSULE = 3   # segment on the y axis from -a to a, radius b
TORUS = 4     # in the local xz plane around the y axis: major radius a, tube radius b
CONE = 5      # capped cone on the y axis: half height a, radius b at y = -a, radius c at y = +a
KINDS = {"box": BOX, "sphere": SPHERE, "cylinder": CYLINDER, "capsule": CAPSULE, "torus": TORUS, "cone": CONE}

# Set operations (column 1).
UNION = 0
SUBTRACT = 1
INTERSECT = 2

# Row layout: kind, op, M (3x3 world->local rotation, row-major, 2..10), centre (11..13), params (14..18),
# bounding radius (19: the primitive lies within this distance of its centre; filled in by CSGShape),
# part (20: index into CSGShape.parts, the named part the primitive's surface belongs to).
ROW = 21
_M = slice(2, 11)
_C = slice(11, 14)
_P = slice(14, 19)


@dataclass(frozen=True, eq=False)
class CSGShape:
    """A CSG program with its placement in the world.

    Attributes:
        program: (P, 21) float64 rows (see the module constants).
        scale, offset: world placement, ``sdf_world(p) = scale * sdf_program(p / scale + offset)``.
        parts: the part names (e.g. "legs", "seat") the program's column 20 indexes: the surface
            a row makes belongs to its part (``part_at``), which is how objects get part colours.
        bounds: ((3,), (3,)) world box that contains the shape (tight after ``normalized()``,
            otherwise a conservative union of the primitives' boxes).
    """

    program: np.ndarray
    scale: float = 1.0
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bounds: Optional[tuple[np.ndarray, np.ndarray]] = field(default=None)
    parts: tuple[str, ...] = ("body",)

    def __post_init__(self) -> None:
        prog = np.ascontiguousarray(np.asarray(self.program, dtype=np.float64))
        check_shape(prog, "program", f"P, {ROW}", at_least={"P": 1})
        if not np.isfinite(prog).all():
            raise ValueError("program contains NaN or Inf")
        if not self.scale > 0:  # inf is allowed: a shape may be any size
            raise ValueError(f"scale must be > 0, got {self.scale!r}")
        object.__setattr__(self, "parts", tuple(str(p) for p in self.parts))
        if not self.parts or (prog[:, 20] < 0).any() or (prog[:, 20] >= len(self.parts)).any() \
                or (prog[:, 20] != np.round(prog[:, 20])).any():
            raise ValueError(f"program column 20 must index parts {list(self.parts)}")
        prog = prog.copy()
        for row in prog:
            row[19] = float(np.linalg.norm(_local_half_extents(int(row[0]), row[_P])))
        object.__setattr__(self, "program", prog)
        object.__setattr__(self, "offset", tuple(float(o) for o in self.offset))
        if self.bounds is None:
            object.__setattr__(self, "bounds", self._primitive_bounds())

    # ------------------------------------------------------------------ evaluation
    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        """The SDF in PyTorch (reference; differentiable w.r.t. points).

        Args:
            points: (..., 3) world points, float32/float64.
        Returns:
            (...) signed distances (world units; negative inside).
        """
        if points.shape[-1] != 3:
            raise ValueError(f"points must end in a dimension of 3, got {tuple(points.shape)}")
        dt, dev = points.dtype, points.device
        off = torch.tensor(self.offset, dtype=dt, device=dev)
        p = points / self.scale + off
        d = None
        for row in self.program:
            m = torch.tensor(row[_M].reshape(3, 3), dtype=dt, device=dev)
            c = torch.tensor(row[_C], dtype=dt, device=dev)
            q = (p - c) @ m.T
            e = _primitive_torch(int(row[0]), q, *(float(x) for x in row[_P]))
            op = int(row[1])
            if d is None:
                d = e
            elif op == UNION:
                d = torch.minimum(d, e)
            elif op == SUBTRACT:
                d = torch.maximum(d, -e)
            else:
                d = torch.maximum(d, e)
        return d * self.scale

    def sdf_numpy(self, points: np.ndarray) -> np.ndarray:
        """The same SDF by the numba kernel. points: (..., 3) float -> (...) float64."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64))
        if pts.shape[-1] != 3:
            raise ValueError(f"points must end in a dimension of 3, got {pts.shape}")
        flat = pts.reshape(-1, 3)
        out = np.empty(len(flat), dtype=np.float64)
        _sdf_many(self.program, self.scale, np.asarray(self.offset), flat, out)
        return out.reshape(pts.shape[:-1])

    # ------------------------------------------------------------------ placement
    def _primitive_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """A box containing the union of the primitives (world): subtractions and intersections
        only remove material, so it also contains the shape."""
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for n, row in enumerate(self.program):
            if n > 0 and int(row[1]) != UNION:
                continue
            half = _local_half_extents(int(row[0]), row[_P])
            m = row[_M].reshape(3, 3)
            # local -> program frame rotation is m.T; the box of a rotated box is |R| @ half.
            ext = np.abs(m.T) @ half
            lo = np.minimum(lo, row[_C] - ext)
            hi = np.maximum(hi, row[_C] + ext)
        off = np.asarray(self.offset)
        return (lo - off) * self.scale, (hi - off) * self.scale

    def normalized(self, samples: int = 32) -> "CSGShape":
        """The shape centred on its bounding box, scaled so that the longest side is 1 (ShapeNet's
        normalisation), with tight ``bounds``.

        The box is measured on the surface: grid points near the surface (``samples``^3 in the
        conservative box) are projected onto it along the SDF gradient; the extremes of the
        projected points bound the shape to well under 1% of its size.
        """
        lo, hi = self.measure_bounds(samples)
        size = float((hi - lo).max())
        if not size > 0:
            raise ValueError("the shape is empty: it has no surface to normalise")
        centre = (lo + hi) / 2.0
        # world' = (world - centre) / size  =>  sdf'(p) = sdf(p * size + centre) / size
        new_scale = self.scale / size
        new_offset = np.asarray(self.offset) + centre / self.scale
        return CSGShape(self.program, new_scale, tuple(new_offset), ((lo - centre) / size, (hi - centre) / size),
                        self.parts)

    def measure_bounds(self, samples: int = 32) -> tuple[np.ndarray, np.ndarray]:
        """The shape's bounding box (world), measured on its surface (see ``normalized``)."""
        lo, hi = self._primitive_bounds()
        margin = 0.05 * float((hi - lo).max())
        lo, hi = lo - margin, hi + margin
        axes = [np.linspace(lo[a], hi[a], samples) for a in range(3)]
        pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        d = self.sdf_numpy(pts)
        cell = float(np.linalg.norm((hi - lo) / (samples - 1)))
        near = pts[np.abs(d) < cell]
        if len(near) == 0:
            raise ValueError("the shape has no surface inside its primitives' box")
        for _ in range(3):
            g = surface_normals(self, near)
            near = near - self.sdf_numpy(near)[:, None] * g
        ok = np.abs(self.sdf_numpy(near)) < 1e-6 * float((hi - lo).max()) + 1e-9
        surf = near[ok]
        inside = pts[d < 0]
        both = np.concatenate([surf, inside]) if len(inside) else surf
        return both.min(0), both.max(0)


def _local_half_extents(kind: int, p: np.ndarray) -> np.ndarray:
    a, b, c = p[0], p[1], p[2]
    if kind == BOX:
        return np.array([a, b, c])
    if kind == SPHERE:
        return np.array([a, a, a])
    if kind == CYLINDER:
        return np.array([a, b, a])
    if kind == CAPSULE:
        return np.array([b, a + b, b])
    if kind == TORUS:
        return np.array([a + b, b, a + b])
    if kind == CONE:
        r = max(b, c)
        return np.array([r, a, r])
    raise ValueError(f"unknown primitive kind {kind}")


# ---------------------------------------------------------------------------------------------
# PyTorch primitives (the reference)


def _seg_dist_torch(px, py, ax, ay, bx, by):
    """Distance from 2D points (px, py) to the segment a-b (scalars)."""
    ex, ey = bx - ax, by - ay
    ll = ex * ex + ey * ey
    h = torch.clamp(((px - ax) * ex + (py - ay) * ey) / ll, 0.0, 1.0) if ll > 0 else torch.zeros_like(px)
    return torch.sqrt((px - ax - h * ex) ** 2 + (py - ay - h * ey) ** 2)


def _primitive_torch(kind: int, q: torch.Tensor, a: float, b: float, c: float, d: float, e: float) -> torch.Tensor:
    x, y, z = q[..., 0], q[..., 1], q[..., 2]
    zero = torch.zeros((), dtype=q.dtype, device=q.device)
    if kind == BOX:
        w = q.abs() - torch.tensor([a - d, b - d, c - d], dtype=q.dtype, device=q.device)
        outside = torch.clamp(w, min=0.0).norm(dim=-1)
        inside = torch.minimum(w.amax(dim=-1), zero)
        return outside + inside - d
    if kind == SPHERE:
        return q.norm(dim=-1) - a
    if kind == CYLINDER:
        wx = torch.sqrt(x * x + z * z) - a
        wy = y.abs() - b
        return torch.minimum(torch.maximum(wx, wy), zero) + torch.sqrt(
            torch.clamp(wx, min=0.0) ** 2 + torch.clamp(wy, min=0.0) ** 2)
    if kind == CAPSULE:
        yy = y - torch.clamp(y, -a, a)
        return torch.sqrt(x * x + yy * yy + z * z) - b
    if kind == TORUS:
        rr = torch.sqrt(x * x + z * z) - a
        return torch.sqrt(rr * rr + y * y) - b
    if kind == CONE:
        rho = torch.sqrt(x * x + z * z)
        dist = torch.minimum(torch.minimum(_seg_dist_torch(rho, y, 0.0, -a, b, -a),
                                           _seg_dist_torch(rho, y, 0.0, a, c, a)),
                             _seg_dist_torch(rho, y, b, -a, c, a))
        radius = b + (c - b) * (y + a) / (2.0 * a)
        inside = (y.abs() <= a) & (rho <= radius)
        return torch.where(inside, -dist, dist)
    raise ValueError(f"unknown primitive kind {kind}")


# ---------------------------------------------------------------------------------------------
# numba kernels (same formulas)


@numba.njit(cache=True, inline="always")
def _seg_dist(px, py, ax, ay, bx, by):
    ex = bx - ax
    ey = by - ay
    ll = ex * ex + ey * ey
    h = 0.0
    if ll > 0.0:
        h = ((px - ax) * ex + (py - ay) * ey) / ll
        h = min(max(h, 0.0), 1.0)
    dx = px - ax - h * ex
    dy = py - ay - h * ey
    return math.sqrt(dx * dx + dy * dy)


@numba.njit(cache=True)
def _primitive(kind, x, y, z, a, b, c, d):
    if kind == BOX:
        wx = abs(x) - (a - d)
        wy = abs(y) - (b - d)
        wz = abs(z) - (c - d)
        ox = max(wx, 0.0)
        oy = max(wy, 0.0)
        oz = max(wz, 0.0)
        return math.sqrt(ox * ox + oy * oy + oz * oz) + min(max(wx, max(wy, wz)), 0.0) - d
    if kind == SPHERE:
        return math.sqrt(x * x + y * y + z * z) - a
    if kind == CYLINDER:
        wx = math.sqrt(x * x + z * z) - a
        wy = abs(y) - b
        ox = max(wx, 0.0)
        oy = max(wy, 0.0)
        return min(max(wx, wy), 0.0) + math.sqrt(ox * ox + oy * oy)
    if kind == CAPSULE:
        yy = y - min(max(y, -a), a)
        return math.sqrt(x * x + yy * yy + z * z) - b
    if kind == TORUS:
        rr = math.sqrt(x * x + z * z) - a
        return math.sqrt(rr * rr + y * y) - b
    # CONE
    rho = math.sqrt(x * x + z * z)
    dist = min(_seg_dist(rho, y, 0.0, -a, b, -a), _seg_dist(rho, y, 0.0, a, c, a))
    dist = min(dist, _seg_dist(rho, y, b, -a, c, a))
    radius = b + (c - b) * (y + a) / (2.0 * a)
    if abs(y) <= a and rho <= radius:
        return -dist
    return dist


@numba.njit(cache=True)
def _row_value(r, px, py, pz):
    """The primitive of row ``r`` at a program-frame point (its own exact SDF)."""
    dx = px - r[11]
    dy = py - r[12]
    dz = pz - r[13]
    qx = r[2] * dx + r[3] * dy + r[4] * dz
    qy = r[5] * dx + r[6] * dy + r[7] * dz
    qz = r[8] * dx + r[9] * dy + r[10] * dz
    return _primitive(int(r[0]), qx, qy, qz, r[14], r[15], r[16], r[17])


@numba.njit(cache=True)
def _sdf_source(prog, scale, off, wx, wy, wz):
    """(signed distance, the row whose surface is nearest in the CSG sense: the last row that set d)."""
    px = wx / scale + off[0]
    py = wy / scale + off[1]
    pz = wz / scale + off[2]
    d = 0.0
    src = 0
    for n in range(prog.shape[0]):
        r = prog[n]
        dx = px - r[11]
        dy = py - r[12]
        dz = pz - r[13]
        op = int(r[1])
        if n > 0 and op != INTERSECT:
            # The primitive is at least this far: skip it where it cannot change d (exactly).
            far = math.sqrt(dx * dx + dy * dy + dz * dz) - r[19]
            if (op == UNION and far >= d) or (op == SUBTRACT and far >= -d):
                continue
        qx = r[2] * dx + r[3] * dy + r[4] * dz
        qy = r[5] * dx + r[6] * dy + r[7] * dz
        qz = r[8] * dx + r[9] * dy + r[10] * dz
        e = _primitive(int(r[0]), qx, qy, qz, r[14], r[15], r[16], r[17])
        if n == 0 or (op == UNION and e < d) or (op == SUBTRACT and -e > d) or (op == INTERSECT and e > d):
            d = -e if (n > 0 and op == SUBTRACT) else e
            src = n
    return d * scale, src


@numba.njit(cache=True)
def _sdf_point(prog, scale, off, wx, wy, wz):
    return _sdf_source(prog, scale, off, wx, wy, wz)[0]


@numba.njit(cache=True, parallel=True)
def _sdf_many(prog, scale, off, pts, out):
    for n in numba.prange(pts.shape[0]):
        out[n] = _sdf_point(prog, scale, off, pts[n, 0], pts[n, 1], pts[n, 2])


@numba.njit(cache=True, parallel=True)
def _surface_many(prog, scale, off, pts, eps, out, out_part):
    for n in numba.prange(pts.shape[0]):
        src = _sdf_source(prog, scale, off, pts[n, 0], pts[n, 1], pts[n, 2])[1]
        r = prog[src]
        out_part[n] = int(r[20])
        x, y, z = pts[n, 0] / scale + off[0], pts[n, 1] / scale + off[1], pts[n, 2] / scale + off[2]
        h = eps / scale
        # The gradient of the row that makes the surface here (the CSG's own gradient but within
        # eps of a crease): tetrahedral central differences of that primitive alone.
        a = _row_value(r, x + h, y - h, z - h)
        b = _row_value(r, x - h, y - h, z + h)
        c = _row_value(r, x - h, y + h, z - h)
        e = _row_value(r, x + h, y + h, z + h)
        sign = -1.0 if (src > 0 and int(r[1]) == SUBTRACT) else 1.0
        gx = sign * (a - b - c + e)
        gy = sign * (-a - b + c + e)
        gz = sign * (-a + b - c + e)
        ln = math.sqrt(gx * gx + gy * gy + gz * gz)
        if ln > 0.0:
            out[n, 0] = gx / ln
            out[n, 1] = gy / ln
            out[n, 2] = gz / ln
        else:
            out[n, 0] = 0.0
            out[n, 1] = 1.0
            out[n, 2] = 0.0


@numba.njit(cache=True, parallel=True)
def _trace_many(prog, scale, off, eyes, eye_index, dirs, t_min, lo, hi, thr_k, cert_k, delta_k, max_steps,
                out_t, out_hit, out_cert, out_clear):
    for n in numba.prange(dirs.shape[0]):
        e = eye_index[n]
        ox, oy, oz = eyes[e, 0], eyes[e, 1], eyes[e, 2]
        dx, dy, dz = dirs[n, 0], dirs[n, 1], dirs[n, 2]
        # slab test against the box [lo, hi]
        t_near = -np.inf
        t_far = np.inf
        for a in range(3):
            da = dirs[n, a]
            if abs(da) < 1e-12:
                da = 1e-12 if da >= 0.0 else -1e-12
            t1 = (lo[a] - eyes[e, a]) / da
            t2 = (hi[a] - eyes[e, a]) / da
            t_near = max(t_near, min(t1, t2))
            t_far = min(t_far, max(t1, t2))
        t_start = max(t_near, t_min[n], 0.0)
        t = t_start
        t_cert = t_start
        chain = True
        hit = False
        clear = False
        if t_far < t_start:
            clear = True
        else:
            for step in range(max_steps):
                if t > t_far:
                    clear = chain
                    break
                s = _sdf_point(prog, scale, off, ox + t * dx, oy + t * dy, oz + t * dz)
                if chain:
                    if s > cert_k * t:
                        t_cert = t + s - delta_k * (t + s)
                    else:
                        chain = False
                        t_cert = max(t_start, t - delta_k * t)
                if s < thr_k * t:
                    hit = True
                    break
                t += s
        out_t[n] = t
        out_hit[n] = hit
        out_cert[n] = t_cert
        out_clear[n] = clear


def surface_normals(shape: CSGShape, points: np.ndarray, eps: float = 1e-5) -> np.ndarray:
    """Unit SDF gradients at world points (K, 3) -> (K, 3): tetrahedral differences of the primitive
    whose surface is nearest (``part_at``'s row), which is the CSG's gradient except within ``eps``
    of a crease, at a quarter of the cost of differencing the whole program."""
    return surface_normals_and_parts(shape, points, eps)[0]


def surface_normals_and_parts(shape: CSGShape, points: np.ndarray, eps: float = 1e-5) -> tuple[np.ndarray, np.ndarray]:
    """``surface_normals`` and ``part_at`` of the same points in one pass: ((K, 3), (K,) int64)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    out = np.empty_like(pts)
    part = np.empty(len(pts), dtype=np.int64)
    _surface_many(shape.program, shape.scale, np.asarray(shape.offset), pts, eps, out, part)
    return out, part


def part_at(shape: CSGShape, points: np.ndarray) -> np.ndarray:
    """The part (index into ``shape.parts``) whose surface is nearest each world point (K, 3) -> (K,)
    int64: of the row that last set the CSG value there, so a recess cut into a body has the part of
    the cut, and a hidden primitive never shows."""
    return surface_normals_and_parts(shape, points)[1]


@dataclass(frozen=True)
class CSGHits:
    """Sphere-tracing result for R rays (world frame).

    Attributes:
        t: (R,) distance along the ray of the hit (meaningless where not hit).
        hit: (R,) bool.
        t_certified: (R,) every ray within ``delta_k * t`` of this ray is free of the shape for
            distances below this value (a cone-tracing certificate from the sphere-tracing balls).
        clear: (R,) bool, the whole ray inside the box was certified: every such neighbouring ray
            misses the shape.
    """

    t: np.ndarray
    hit: np.ndarray
    t_certified: np.ndarray
    clear: np.ndarray


def trace_rays(shape: CSGShape, eyes: np.ndarray, directions: np.ndarray, hit_threshold: float,
               box: Optional[tuple[np.ndarray, np.ndarray]] = None, eye_index: Optional[np.ndarray] = None,
               t_min: Optional[np.ndarray] = None, cone_delta: float = 0.0, max_steps: int = 256) -> CSGHits:
    """Sphere-traces the analytic SDF along R rays, without gradients.

    Each ray marches from where it enters ``box`` (but not before ``t_min``) to where it leaves it.

    Args:
        eyes: (E, 3) ray origins (world); ray n starts at ``eyes[eye_index[n]]``.
        directions: (R, 3) unit world directions.
        hit_threshold: a ray hits where ``sdf < hit_threshold * t`` (a fraction of the pixel footprint).
        box: (lo, hi) world box that contains the shape (default: ``shape.bounds``).
        eye_index: (R,) int (default: ray n uses eye n, E = R).
        t_min: (R,) where the march may start at the earliest (default 0).
        cone_delta: neighbouring rays within ``cone_delta * t`` of this one are certified free of the
            shape as long as every sample has ``sdf > 2 cone_delta t`` (see ``CSGHits``); the box must
            then contain the shape with a margin of ``2 cone_delta t``.
        max_steps: samples per ray; a ray that runs out of them is a miss that is not ``clear``.
    """
    d = np.ascontiguousarray(directions, dtype=np.float64).reshape(-1, 3)
    e = np.ascontiguousarray(eyes, dtype=np.float64).reshape(-1, 3)
    r = len(d)
    idx = np.arange(r, dtype=np.int64) if eye_index is None else np.ascontiguousarray(eye_index, dtype=np.int64)
    if len(idx) != r:
        raise ValueError(f"eye_index ({len(idx)}) and directions ({r}) must have the same length")
    if r and (idx.min() < 0 or idx.max() >= len(e)):
        raise ValueError(f"eye_index must lie in [0, {len(e)})")
    tm = np.zeros(r) if t_min is None else np.ascontiguousarray(t_min, dtype=np.float64)
    lo, hi = shape.bounds if box is None else box
    out_t = np.empty(r)
    out_hit = np.empty(r, dtype=np.bool_)
    out_cert = np.empty(r)
    out_clear = np.empty(r, dtype=np.bool_)
    _trace_many(shape.program, shape.scale, np.asarray(shape.offset), e, idx, d, tm,
                np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64), float(hit_threshold),
                float(2.0 * cone_delta) if cone_delta > 0 else np.inf, float(cone_delta), int(max_steps),
                out_t, out_hit, out_cert, out_clear)
    return CSGHits(out_t, out_hit, out_cert, out_clear)


# ---------------------------------------------------------------------------------------------
# Building programs


def rotation(axis: Sequence[float], angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about ``axis`` (right-handed), local -> world."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def frame_with_y(direction: Sequence[float]) -> np.ndarray:
    """(3, 3) rotation (local -> world) whose local +y axis is ``direction``."""
    y = np.asarray(direction, dtype=np.float64)
    y = y / np.linalg.norm(y)
    helper = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(y, helper)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    return np.stack([x, y, z], axis=1)


class CSGBuilder:
    """Appends primitives to a left-deep CSG program (in order).

    Every method takes the primitive's centre (program frame), an optional local -> world rotation
    ``rot`` (3, 3) and ``op``: "union" (default), "subtract" or "intersect".
    """

    _OPS = {"union": UNION, "subtract": SUBTRACT, "intersect": INTERSECT}

    def __init__(self) -> None:
        self.rows: list[np.ndarray] = []
        self.parts: list[str] = ["body"]
        self._part = 0

    def part(self, name: str) -> "CSGBuilder":
        """Rows added from now on belong to the part ``name`` (new names are appended to the list;
        before any call, "body")."""
        if name not in self.parts:
            self.parts.append(str(name))
        self._part = self.parts.index(name)
        return self

    def _add(self, kind: int, centre, params, rot=None, op: str = "union") -> "CSGBuilder":
        if op not in self._OPS:
            raise ValueError(f"op must be one of {tuple(self._OPS)}, got {op!r}")
        row = np.zeros(ROW)
        row[0] = kind
        row[1] = self._OPS[op]
        r = np.eye(3) if rot is None else np.asarray(rot, dtype=np.float64)
        row[_M] = r.T.reshape(-1)  # world -> local
        row[_C] = np.asarray(centre, dtype=np.float64)
        row[14:14 + len(params)] = params
        row[20] = self._part
        self.rows.append(row)
        return self

    def box(self, centre, half, rot=None, op: str = "union", rounding: float = 0.0) -> "CSGBuilder":
        h = [float(x) for x in half]
        rounding = min(float(rounding), 0.999 * min(h))
        return self._add(BOX, centre, [*h, rounding], rot, op)

    def box_between(self, lo, hi, op: str = "union", rounding: float = 0.0) -> "CSGBuilder":
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        return self.box((lo + hi) / 2, np.abs(hi - lo) / 2, None, op, rounding)

    def sphere(self, centre, radius: float, op: str = "union") -> "CSGBuilder":
        return self._add(SPHERE, centre, [radius], None, op)

    def cylinder(self, centre, radius: float, half_height: float, rot=None, op: str = "union") -> "CSGBuilder":
        return self._add(CYLINDER, centre, [radius, half_height], rot, op)

    def rod(self, a, b, radius: float, op: str = "union") -> "CSGBuilder":
        """A cylinder from point a to point b (flat ends)."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        return self.cylinder((a + b) / 2, radius, np.linalg.norm(b - a) / 2, frame_with_y(b - a), op)

    def capsule(self, a, b, radius: float, op: str = "union") -> "CSGBuilder":
        """A capsule from point a to point b (rounded ends)."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        return self._add(CAPSULE, (a + b) / 2, [np.linalg.norm(b - a) / 2, radius], frame_with_y(b - a), op)

    def torus(self, centre, major: float, minor: float, rot=None, op: str = "union") -> "CSGBuilder":
        return self._add(TORUS, centre, [major, minor], rot, op)

    def cone(self, centre, half_height: float, r_bottom: float, r_top: float, rot=None,
             op: str = "union") -> "CSGBuilder":
        return self._add(CONE, centre, [half_height, r_bottom, r_top], rot, op)

    def shape(self) -> CSGShape:
        if not self.rows:
            raise ValueError("the program is empty")
        used = sorted({int(r[20]) for r in self.rows})  # drop names no row kept, renumbering
        prog = np.stack(self.rows)
        prog[:, 20] = np.searchsorted(used, prog[:, 20])
        return CSGShape(prog, parts=tuple(self.parts[k] for k in used))
