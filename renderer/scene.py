"""Scene: which effects a render needs, the lights, the material and the background."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Union

import math

EFFECTS = ("silhouette", "depth", "normal", "shading")
INTERSECTIONS = ("conservative", "exact")
GRADIENTS = ("paper", "visibility")


def _vec3(x, name: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(c) for c in x)
    except TypeError:
        raise ValueError(f"{name} must be a 3-vector, got {x!r}") from None
    if len(v) != 3 or not all(math.isfinite(c) for c in v):
        raise ValueError(f"{name} must be a finite 3-vector, got {x!r}")
    return v  # type: ignore[return-value]


@dataclass(frozen=True)
class DirectionalLight:
    """A light at infinity. ``direction`` points from the scene towards the light (world)."""

    direction: tuple[float, float, float] = (0.0, 1.0, 1.0)
    intensity: float = 1.0

    def __post_init__(self) -> None:
        d = _vec3(self.direction, "DirectionalLight.direction")
        if math.sqrt(sum(c * c for c in d)) == 0:
            raise ValueError("DirectionalLight.direction must be non-zero")
        object.__setattr__(self, "direction", d)


@dataclass(frozen=True)
class PointLight:
    """A point light at ``position`` (world); with ``falloff`` its intensity drops as 1/distance^2."""

    position: tuple[float, float, float] = (0.0, 2.0, 2.0)
    intensity: float = 1.0
    falloff: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _vec3(self.position, "PointLight.position"))


Light = Union[DirectionalLight, PointLight]


@dataclass(frozen=True)
class Scene:
    """What to render and how.

    Attributes:
        effects: the outputs wanted, any of ``EFFECTS``. Only the passes these need run: a
            silhouette-only render builds no hit points, normals or lights.
        lights: directional and point lights.
        camera_light: intensity of a point light at each camera's eye (None: none). With
            ``camera_light_falloff`` it falls off as 1/distance^2 (the authors' code used 10 with it).
        ambient: ambient term added to the diffuse one.
        albedo: per-channel diffuse albedo; its length is the number of image channels C.
        background: the image's value where rays miss: a scalar or one value per channel.
        silhouette_sigma: width of the soft silhouette in pixels (the SDF at the closest approach,
            divided by ``sigma * pixel footprint``, goes through a sigmoid). 0.3 gives about the
            slope of a box-filtered (anti-aliased) edge.
        intersection: how the hit point is found from the traced point: "conservative" is the
            paper's ``p = s + f(s) v``; "exact" the root of the trilinear SDF along the ray, with
            gradients by implicit differentiation (renderer/exact.py).
        gradient: which gradient the image gets. "paper": local shading at fixed hit points only
            (the paper's; no gradient moves an edge, the soft silhouette being a separate output).
            "visibility": that, plus the motion of the image's edges, the outline against the
            background and self-occlusion edges alike (renderer/shading.py, ``edge_gradient``);
            it needs grazing points from the march, which ``render`` asks for. Only the shaded
            image gets it; depth, normals and the silhouette keep the paper's gradient.
        visibility_band: with ``gradient="visibility"``, the width in pixels of the band beside
            each edge whose pixels carry the edge's gradient (larger: smoother and more biased).
    """

    effects: tuple[str, ...] = ("silhouette", "depth", "normal", "shading")
    lights: tuple[Light, ...] = (DirectionalLight(),)
    camera_light: Optional[float] = None
    camera_light_falloff: bool = True
    ambient: float = 0.2
    albedo: tuple[float, ...] = (1.0, 1.0, 1.0)
    background: Union[float, tuple[float, ...]] = 0.0
    silhouette_sigma: float = 0.3
    intersection: str = "conservative"
    gradient: str = "paper"
    visibility_band: float = 1.0

    def __post_init__(self) -> None:
        effects = (self.effects,) if isinstance(self.effects, str) else tuple(self.effects)
        if not effects:
            raise ValueError(f"effects must name at least one of {EFFECTS}")
        for e in effects:
            if e not in EFFECTS:
                raise ValueError(f"unknown effect {e!r} in effects; expected any of {EFFECTS}")
        object.__setattr__(self, "effects", effects)
        lights = tuple(self.lights) if isinstance(self.lights, Sequence) else (self.lights,)
        for light in lights:
            if not isinstance(light, (DirectionalLight, PointLight)):
                raise TypeError(f"lights must hold DirectionalLight/PointLight, got {type(light).__name__}")
        object.__setattr__(self, "lights", lights)
        albedo = (float(self.albedo),) if isinstance(self.albedo, (int, float)) else tuple(float(a) for a in self.albedo)
        if not albedo:
            raise ValueError("albedo must have at least one channel")
        object.__setattr__(self, "albedo", albedo)
        bg = self.background
        if not isinstance(bg, (int, float)):
            bg = tuple(float(b) for b in bg)
            if len(bg) not in (1, len(albedo)):
                raise ValueError(f"background must be a scalar or have {len(albedo)} channels, got {len(bg)}")
        object.__setattr__(self, "background", bg)
        if not self.silhouette_sigma > 0:
            raise ValueError(f"silhouette_sigma must be positive, got {self.silhouette_sigma}")
        if self.intersection not in INTERSECTIONS:
            raise ValueError(f"intersection must be one of {INTERSECTIONS}, got {self.intersection!r}")
        if self.gradient not in GRADIENTS:
            raise ValueError(f"gradient must be one of {GRADIENTS}, got {self.gradient!r}")
        if not (self.visibility_band > 0 and math.isfinite(self.visibility_band)):
            raise ValueError(f"visibility_band must be a positive number of pixels, got {self.visibility_band!r}")

    @property
    def channels(self) -> int:
        return len(self.albedo)

    def wants(self, effect: str) -> bool:
        return effect in self.effects

    def needs_hit_points(self) -> bool:
        return any(e in self.effects for e in ("depth", "normal", "shading"))

    def needs_normals(self) -> bool:
        return any(e in self.effects for e in ("normal", "shading"))

    def needs_grazing(self) -> bool:
        """Whether stage 2 reads the rays' grazing points: the visibility gradient of the image."""
        return self.gradient == "visibility" and "shading" in self.effects


SILHOUETTE_ONLY = Scene(effects=("silhouette",))
