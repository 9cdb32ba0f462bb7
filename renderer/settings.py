"""Settings of the sphere-tracing march (shared by the reference march and the fused kernels)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional


@dataclass(frozen=True)
class TraceSettings:
    """How rays are marched (renderer/reference.py gives the exact rule).

    Attributes:
        max_steps: SDF samples per ray before it counts as a miss.
        threshold: absolute hit threshold (world units); None uses ``threshold_scale`` times the
            pixel footprint at the current distance (what the paper's authors did).
        threshold_scale: the hit threshold in pixel footprints when ``threshold`` is None.
        inner_steps: samples spent behind a hit looking for the deepest point (soft silhouettes
            of hit pixels); 0 turns that search off.
        inner_depth: the search behind a hit stops once the SDF is below ``-inner_depth`` thresholds
            (the soft silhouette is saturated there).
    """

    max_steps: int = 256
    threshold: Optional[float] = None
    threshold_scale: float = 0.5
    inner_steps: int = 16
    inner_depth: float = 8.0

    def __post_init__(self) -> None:
        if not isinstance(self.max_steps, int) or self.max_steps < 1:
            raise ValueError(f"max_steps must be a positive int, got {self.max_steps!r}")
        if self.threshold is not None and not self.threshold > 0:
            raise ValueError(f"threshold must be positive or None, got {self.threshold!r}")
        if not self.threshold_scale > 0:
            raise ValueError(f"threshold_scale must be positive, got {self.threshold_scale!r}")
        if not isinstance(self.inner_steps, int) or self.inner_steps < 0:
            raise ValueError(f"inner_steps must be a non-negative int, got {self.inner_steps!r}")
        if not self.inner_depth > 0:
            raise ValueError(f"inner_depth must be positive, got {self.inner_depth!r}")
