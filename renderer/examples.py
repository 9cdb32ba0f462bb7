"""Example signed distance functions for demos and benchmarks (world units, points (..., 3))."""
from __future__ import annotations

import torch


def torus_and_sphere(p: torch.Tensor) -> torch.Tensor:
    """SDF of a torus (radii 0.45, 0.15) in the xz plane united with a sphere above it.

    Args:
        p: (..., 3) world points.
    Returns:
        (...) distances, ``p``'s dtype and device.
    """
    q = torch.stack([torch.linalg.norm(p[..., [0, 2]], dim=-1) - 0.45, p[..., 1]], dim=-1)
    torus = torch.linalg.norm(q, dim=-1) - 0.15
    sphere = torch.linalg.norm(p - torch.tensor([0.0, 0.35, 0.0]), dim=-1) - 0.25
    return torch.minimum(torus, sphere)
