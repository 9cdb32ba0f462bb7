"""Built-in analytic target shapes: implicit functions whose zero set is the surface, each given in
its own frame with its exact bounding box. ``mvr.targets`` meshes them finely (marching cubes,
vertices projected onto the zero set) and normalises them like any mesh file, so that a built-in
shape and a mesh file go through the same ray caster and the same evaluation.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

ImplicitFn = Callable[[torch.Tensor], torch.Tensor]


def sphere_sdf(p: torch.Tensor, radius: float = 1.0) -> torch.Tensor:
    """Exact SDF of a sphere at the origin. p: (..., 3) -> (...)."""
    return p.norm(dim=-1) - radius


def torus_sdf(p: torch.Tensor, major: float = 1.0, minor: float = 0.4) -> torch.Tensor:
    """Exact SDF of a torus around the y axis (its ring in the xz plane). p: (..., 3) -> (...)."""
    ring = torch.sqrt(p[..., 0] ** 2 + p[..., 2] ** 2) - major
    return torch.sqrt(ring**2 + p[..., 1] ** 2) - minor


def _shifted(p: torch.Tensor, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> torch.Tensor:
    return p - torch.tensor([x, y, z], dtype=p.dtype, device=p.device)


def double_torus_sdf(p: torch.Tensor) -> torch.Tensor:
    """Genus 2: two tori (major 1, minor 0.42) side by side along x, their tubes merged at the centre.

    The union (min) of exact SDFs is exact outside the shape.
    """
    return torch.minimum(torus_sdf(_shifted(p, x=-1.0), 1.0, 0.42), torus_sdf(_shifted(p, x=1.0), 1.0, 0.42))


def triple_torus_sdf(p: torch.Tensor) -> torch.Tensor:
    """Genus 3: three tori (major 0.8, minor 0.32) in a row along x, neighbours merged."""
    d = torus_sdf(_shifted(p, x=-1.55), 0.8, 0.32)
    d = torch.minimum(d, torus_sdf(p, 0.8, 0.32))
    return torch.minimum(d, torus_sdf(_shifted(p, x=1.55), 0.8, 0.32))


def _smooth_min(a: torch.Tensor, b: torch.Tensor, k: float) -> torch.Tensor:
    """Polynomial smooth minimum (blend width k): a blob-like union."""
    h = torch.clamp(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def _capsule(p: torch.Tensor, a, b, radius: float) -> torch.Tensor:
    a_t = torch.tensor(a, dtype=p.dtype, device=p.device)
    b_t = torch.tensor(b, dtype=p.dtype, device=p.device)
    pa, ba = p - a_t, b_t - a_t
    h = torch.clamp((pa * ba).sum(-1) / (ba * ba).sum(), 0.0, 1.0)
    return (pa - h[..., None] * ba).norm(dim=-1) - radius


def blob_sdf(p: torch.Tensor) -> torch.Tensor:
    """A bunny-like blob: a body, a head and two long ears, smoothly blended (an implicit function
    with the right zero set, not an exact SDF)."""
    body = sphere_sdf(_shifted(p, y=-0.35), 0.75)
    head = sphere_sdf(_shifted(p, x=0.45, y=0.35, z=0.1), 0.42)
    ear1 = _capsule(p, (0.45, 0.55, 0.25), (0.3, 1.25, 0.35), 0.12)
    ear2 = _capsule(p, (0.45, 0.55, -0.05), (0.55, 1.2, -0.3), 0.12)
    tail = sphere_sdf(_shifted(p, x=-0.8, y=-0.45), 0.22)
    d = _smooth_min(body, head, 0.25)
    d = _smooth_min(d, ear1, 0.12)
    d = _smooth_min(d, ear2, 0.12)
    return _smooth_min(d, tail, 0.1)


def rounded_box_sdf(p: torch.Tensor, half=(1.0, 0.6, 0.45), radius: float = 0.12) -> torch.Tensor:
    """Exact SDF of a box with rounded edges (flat faces, tight curvature at the edges)."""
    h = torch.tensor(half, dtype=p.dtype, device=p.device) - radius
    q = p.abs() - h
    outside = torch.clamp(q, min=0.0).norm(dim=-1)
    inside = torch.clamp(q.amax(dim=-1), max=0.0)
    return outside + inside - radius


def dented_box_sdf(p: torch.Tensor) -> torch.Tensor:
    """A rounded box (half sides 1, 0.6, 1) with a spherical dent 0.4 deep, 0.63 in radius, in its
    top face (+y): a concavity no silhouette reveals, only shading (an implicit function with the
    right zero set, exact outside the dent)."""
    dent = sphere_sdf(_shifted(p, y=0.9), 0.7)
    return torch.maximum(rounded_box_sdf(p, (1.0, 0.6, 1.0), 0.1), -dent)



@dataclass(frozen=True)
class Shape:
    """A built-in shape: ``fn`` maps (..., 3) points to (...) values, negative inside; the zero set
    lies strictly inside the box ``bounds_min``..``bounds_max`` (its own frame), the region meshed."""

    fn: ImplicitFn
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]
    genus: int
    description: str


SHAPES: dict[str, Shape] = {
    "sphere": Shape(sphere_sdf, (-1.1, -1.1, -1.1), (1.1, 1.1, 1.1), 0, "unit sphere"),
    "torus": Shape(torus_sdf, (-1.5, -0.5, -1.5), (1.5, 0.5, 1.5), 1, "torus, radii 1 and 0.4"),
    "double_torus": Shape(double_torus_sdf, (-2.55, -0.55, -1.55), (2.55, 0.55, 1.55), 2,
                          "two merged tori (genus 2)"),
    "triple_torus": Shape(triple_torus_sdf, (-2.8, -0.45, -1.25), (2.8, 0.45, 1.25), 3,
                          "three merged tori in a row (genus 3)"),
    "blob": Shape(blob_sdf, (-1.2, -1.25, -1.0), (1.2, 1.5, 1.0), 0,
                  "bunny-like blob: body, head, ears, tail"),
    "rounded_box": Shape(rounded_box_sdf, (-1.1, -0.7, -0.55), (1.1, 0.7, 0.55), 0,
                         "box 2 x 1.2 x 0.9 with edges rounded by 0.12"),
    "dented_box": Shape(dented_box_sdf, (-1.1, -0.7, -1.1), (1.1, 0.7, 1.1), 0,
                        "box 2 x 1.2 x 2 with a dent 0.4 deep in its top face (a concavity only shading shows)"),
}
