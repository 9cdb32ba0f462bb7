"""Fused sphere-tracing marches (numba CPU and CUDA) sharing one per-ray routine.

They implement exactly the march of renderer/reference.py, which stays the specification.
"""
from __future__ import annotations


def available(backend: str) -> tuple[bool, str]:
    """(True, "") if the fused ``backend`` ("cpu" or "cuda") can run here, else (False, reason)."""
    return False, "the fused kernels are not built in this version"


def march(backend, grid, origins, directions, grid_index, pixel_angle, settings):
    raise RuntimeError(available(backend)[1])
