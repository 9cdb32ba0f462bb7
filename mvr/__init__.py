"""Multi-view 3D reconstruction with the differentiable SDF renderer (SDFDiff, paper section 5):
from a target (a built-in shape or a watertight mesh file) rendered from the 26 views of a cube
rig, fit an SDF grid coarse to fine, starting from a sphere, and measure the error of its mesh.
The command line is ``python -m mvr target=torus out_dir=outputs/mvr/torus`` (configs/mvr.yaml);
docs/mvr.md shows the Python API (``reconstruct``, ``Schedule``) as well.
"""
from .losses import view_image_losses, view_silhouette_losses
from .metrics import SurfaceDistances, surface_distances
from .optimize import CameraPoses, LevelReport, OptimSettings, ViewLosses, fill_cavities, optimise_level
from .reconstruct import (GridSettings, NoiseSettings, ReconstructionResult, RigSettings, ScoringSettings,
                          TargetSettings, default_scene, reconstruct)
from .runtime import configure_runtime
from .schedule import Schedule, rule_image_size
from .settings import reconstruct_with_overrides
from .shapes import SHAPES, Shape
from .targets import MESH_FORMATS, Target, TargetImages, load_mesh, make_target, normalise_mesh, shape_mesh

__all__ = [
    "reconstruct", "ReconstructionResult", "reconstruct_with_overrides",
    "RigSettings", "GridSettings", "TargetSettings", "NoiseSettings", "ScoringSettings", "Schedule", "OptimSettings",
    "default_scene", "configure_runtime",
    "Target", "TargetImages", "make_target", "load_mesh", "normalise_mesh", "shape_mesh", "MESH_FORMATS",
    "SHAPES", "Shape",
    "ViewLosses", "CameraPoses", "LevelReport", "optimise_level", "fill_cavities", "rule_image_size",
    "view_image_losses", "view_silhouette_losses",
    "surface_distances", "SurfaceDistances",
]
