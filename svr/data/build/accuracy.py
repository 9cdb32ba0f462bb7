"""The builder checked against answers known exactly (issue 30, point 3), as pure functions of the
build settings and the mesh resolution, used by tests/svr/test_build_accuracy.py at toy size and by
``python -m benchmarks.mesh_build_accuracy`` for docs/mesh_build.md. ``check_solids``: voxels of the
analytic solids' meshes, clean and damaged (``examples.damage``), against the benchmark's voxels of
the exact solid (``voxelize_shape(rule="protocol")``: what the procedural data stores), beside the
benchmark protocol's own voxels of the same mesh (surface + flood fill, which a hole defeats).
``check_renders``: the builder's renders of a shape's mesh against the procedural renderer on its
exact SDF (``render_shape``, the same cameras, light and colour): silhouette IoU and the mean RGB
error where both cover the pixel. ``check_procedural``: procedural shapes exported as meshes and
rebuilt, against the procedural data's voxels and silhouettes.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from svr.data.build.dataset import build_mesh
from svr.data.build.examples import DAMAGES, SOLIDS, damage, shape_mesh
from svr.data.build.meshes import normalised_mesh
from svr.data.build.settings import BuildSettings
from svr.data.procedural.csg import CSGShape
from svr.data.procedural.generator import make_shape, render_shape, voxelize_shape
from svr.evaluation.voxels import voxelize_mesh_nmr


@dataclass(frozen=True)
class SolidCheck:
    """One solid and damage: its triangles, the IoU of the builder's voxels and of the benchmark
    protocol's voxels of the same mesh with the exact solid's voxels, and the builder's leak score."""

    solid: str
    damage: str
    triangles: int
    iou_builder: float
    iou_protocol: float
    leak_score: float


@dataclass(frozen=True)
class RenderCheck:
    """Renders of one shape: silhouette IoU (alpha >= 128 in both) over all views, the mean
    absolute alpha difference and the mean absolute RGB difference over the pixels both cover
    fully (alpha 255), in 0..255 units."""

    shape: str
    triangles: int
    silhouette_iou: float
    alpha_error: float
    shading_error: float


@dataclass(frozen=True)
class RoundTrip:
    """A procedural shape exported as a mesh and rebuilt: voxel IoU with the procedural data's
    voxels and its render check."""

    category: str
    seed: int
    voxel_iou: float
    render: RenderCheck


def voxel_iou(a: np.ndarray, b: np.ndarray) -> float:
    """|a and b| / |a or b| of two bool grids (1 when both are empty)."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def compare_renders(name: str, triangles: int, ours: np.ndarray, reference: np.ndarray) -> RenderCheck:
    """``RenderCheck`` of two (V, 4, H, W) uint8 render sets."""
    a, b = ours[:, 3] >= 128, reference[:, 3] >= 128
    full = (ours[:, 3] == 255) & (reference[:, 3] == 255)
    diff = np.abs(ours[:, :3].astype(np.float64) - reference[:, :3].astype(np.float64))
    shading = float(diff.transpose(1, 0, 2, 3)[:, full].mean()) if full.any() else float("nan")
    alpha = float(np.abs(ours[:, 3].astype(np.float64) - reference[:, 3]).mean())
    return RenderCheck(name, triangles, voxel_iou(a, b), alpha, shading)


def check_solids(settings: BuildSettings, mesh_resolution: int, solids: Sequence[str] = tuple(SOLIDS),
                 damages: Sequence[str] = DAMAGES) -> list[SolidCheck]:
    """Voxels of each solid's mesh, clean and damaged (see the module docstring)."""
    out = []
    for name in solids:
        shape = SOLIDS[name]()
        truth = voxelize_shape(shape, rule="protocol")
        vertices, faces = shape_mesh(shape, mesh_resolution)
        for kind in damages:
            v, f = damage(vertices, faces, kind)
            _, _, vox, _ = build_mesh(normalised_mesh(v, f), settings)
            # The protocol sees the mesh as the builder does: normalised.
            mesh = normalised_mesh(v, f)
            protocol = voxelize_mesh_nmr(mesh.vertices, mesh.faces)
            out.append(SolidCheck(name, kind, len(f), voxel_iou(vox.voxels, truth), voxel_iou(protocol, truth),
                                  vox.leak_score))
    return out


def check_render(name: str, shape: CSGShape, settings: BuildSettings, mesh_resolution: int) -> tuple[RenderCheck, np.ndarray]:
    """The builder's renders of a shape's mesh against ``render_shape`` of the exact shape, both in
    the neutral colour; also returns the builder's voxels."""
    v, f = shape_mesh(shape, mesh_resolution)
    _, images, vox, _ = build_mesh(normalised_mesh(v, f), settings)
    reference = render_shape(shape, None, supersample=settings.supersample, image_size=settings.image_size,
                             num_views=settings.views)
    return compare_renders(name, len(f), images, reference), vox.voxels


def check_renders(settings: BuildSettings, mesh_resolution: int, solids: Sequence[str] = tuple(SOLIDS)) -> list[RenderCheck]:
    """``check_render`` of each analytic solid."""
    return [check_render(name, SOLIDS[name](), settings, mesh_resolution)[0] for name in solids]


def check_procedural(settings: BuildSettings, mesh_resolution: int, categories: Sequence[str],
                     seeds: Sequence[int] = (0,)) -> list[RoundTrip]:
    """Procedural shapes (``make_shape(category, [seed])``) exported as meshes and rebuilt."""
    out = []
    for category in categories:
        for seed in seeds:
            shape = make_shape(category, [int(seed)])
            render, voxels = check_render(category, shape, settings, mesh_resolution)
            out.append(RoundTrip(category, int(seed), voxel_iou(voxels, voxelize_shape(shape, rule="protocol")), render))
    return out


__all__ = ["SolidCheck", "RenderCheck", "RoundTrip", "voxel_iou", "compare_renders", "check_solids", "check_render",
           "check_renders", "check_procedural"]
