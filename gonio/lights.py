"""Light sources: point, directional and spot (lecture notes ``004_6b0fa14dcb48ed2f.txt``,
"Point Lights", "Directional Lights", "Spot Lights"; lecture notes ``000_b5f942c329dc4daf.txt``).

Every light is a small immutable object with two methods over surface points ``(..., 3)`` (metres,
world frame):

- ``incident(points) -> (to_light, e_normal)``: unit direction from each point toward the light,
  and the *normal irradiance* (W/m², RGB): the irradiance on a surface facing the light, without
  the cos θ law (the lighting model's light colour c_l).
- ``illuminate(points, normals) -> (to_light, irradiance)``: irradiance on the surface,
  E = e_normal · max(0, n·L) (Lambert's cosine law, clamped at 0 behind the surface).

Lights add linearly: :func:`total_irradiance` sums them. Directions of propagation (``direction`` of
directional and spot lights) point *from* the light; ``to_light`` points *toward* it, like wi.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

import numpy as np

from gonio.errors import ConfigError
from gonio.geometry import dot, normalize

__all__ = ["Light", "PointLight", "DirectionalLight", "SpotLight", "total_irradiance", "MIN_DISTANCE"]

#: Distances below this (metres) are clamped, so a point at the light gives a large, finite value.
MIN_DISTANCE = 1e-9


def _rgb(name: str, field: str, value) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError.field(None, f"{name}.{field}", value, "must be a number or 3 numbers (R, G, B)") from None
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ConfigError.field(None, f"{name}.{field}", value, "must be a finite number >= 0 or 3 of them (R, G, B)")
    a.setflags(write=False)
    return a


def _vec3(name: str, field: str, value, unit: bool) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.shape != (3,) or not np.all(np.isfinite(a)) or (unit and np.linalg.norm(a) < 1e-12):
        raise ConfigError.field(None, f"{name}.{field}", value,
                                "must be 3 finite numbers" + (", not all zero" if unit else ""))
    a = a / np.linalg.norm(a) if unit else a.copy()
    a.setflags(write=False)
    return a


def _attenuation(name: str, value) -> tuple[float, float, float]:
    try:
        a, b, c = (float(x) for x in value)
    except (TypeError, ValueError):
        raise ConfigError.field(None, f"{name}.attenuation", value, "must be 3 numbers (a, b, c) of 1/(a r^2 + b r + c)") from None
    if min(a, b, c) < 0 or not np.isfinite([a, b, c]).all() or a + b + c <= 0:
        raise ConfigError.field(None, f"{name}.attenuation", value, "must be finite, >= 0, and not all 0")
    return a, b, c


def _falloff(att: tuple[float, float, float], r: np.ndarray) -> np.ndarray:
    """Distance falloff 1/(a r² + b r + c); (1, 0, 0) is the inverse-square law (lecture notes 004,
    "Intensity as Function of Distance")."""
    a, b, c = att
    r = np.maximum(r, MIN_DISTANCE)
    return 1.0 / (a * r * r + b * r + c)


class Light:
    """Base of the lights: :meth:`illuminate` from the subclass's ``incident(points)``."""

    def illuminate(self, points, normals) -> tuple[np.ndarray, np.ndarray]:
        """``(to_light, irradiance)``: E = e_normal · max(0, n·L), RGB on the last axis."""
        to_light, e = self.incident(points)
        cos = np.maximum(dot(normalize(normals), to_light), 0.0)
        return to_light, e * cos[..., None]


@dataclass(frozen=True, init=False, eq=False)
class PointLight(Light):
    """Isotropic point light of radiant intensity I (W/sr, RGB) at ``position``.

    e_normal = I · 1/(a r² + b r + c), default (a, b, c) = (1, 0, 0): the inverse-square law
    E = I cos θ / r² (lecture notes 004, "Point Lights"; the 1/(a r² + b r + c) form is OpenGL's).
    """

    position: np.ndarray
    intensity: np.ndarray
    attenuation: tuple[float, float, float]

    def __init__(self, position, intensity=1.0, attenuation=(1.0, 0.0, 0.0)):
        object.__setattr__(self, "position", _vec3("point_light", "position", position, unit=False))
        object.__setattr__(self, "intensity", _rgb("point_light", "intensity", intensity))
        object.__setattr__(self, "attenuation", _attenuation("point_light", attenuation))

    def incident(self, points):
        d = self.position - np.asarray(points, dtype=np.float64)
        r = np.linalg.norm(d, axis=-1)
        return normalize(d), self.intensity * _falloff(self.attenuation, r)[..., None]


@dataclass(frozen=True, init=False, eq=False)
class DirectionalLight(Light):
    """Distant light travelling along ``direction`` with normal irradiance E (W/m², RGB):
    the same direction and E everywhere (lecture notes 004, "Directional Lights")."""

    direction: np.ndarray
    irradiance: np.ndarray

    def __init__(self, direction, irradiance=1.0):
        object.__setattr__(self, "direction", _vec3("directional_light", "direction", direction, unit=True))
        object.__setattr__(self, "irradiance", _rgb("directional_light", "irradiance", irradiance))

    def incident(self, points):
        shape = np.shape(points)[:-1]
        to_light = np.broadcast_to(-self.direction, shape + (3,))
        return to_light, np.broadcast_to(self.irradiance, shape + (3,))


@dataclass(frozen=True, init=False, eq=False)
class SpotLight(Light):
    """Spot light at ``position`` shining along ``direction``.

    I(θ) = I₀ · s(θ): full intensity inside the ``hotspot`` half-angle, 0 outside the ``falloff``
    half-angle, and the smooth step s = t²(3 − 2t), t = (cos θ − cos θ_falloff)/(cos θ_hotspot −
    cos θ_falloff) between them (pbrt-v4 ``SpotLight``; lecture notes 004, "Spot Lights"), times the
    distance falloff of :class:`PointLight`. Angles in radians, 0 ≤ hotspot ≤ falloff ≤ π.
    """

    position: np.ndarray
    direction: np.ndarray
    intensity: np.ndarray
    hotspot: float
    falloff: float
    attenuation: tuple[float, float, float]

    def __init__(self, position, direction, intensity=1.0, hotspot=np.radians(20), falloff=np.radians(30),
                 attenuation=(1.0, 0.0, 0.0)):
        object.__setattr__(self, "position", _vec3("spot_light", "position", position, unit=False))
        object.__setattr__(self, "direction", _vec3("spot_light", "direction", direction, unit=True))
        object.__setattr__(self, "intensity", _rgb("spot_light", "intensity", intensity))
        for field, v in (("hotspot", hotspot), ("falloff", falloff)):
            if not (isinstance(v, (int, float, np.floating, np.integer)) and 0.0 <= float(v) <= np.pi):
                raise ConfigError.field(None, f"spot_light.{field}", v, "must be an angle in [0, pi] radians")
        if float(hotspot) > float(falloff):
            raise ConfigError.field(None, "spot_light.hotspot", hotspot, f"must be <= falloff ({float(falloff):g})")
        object.__setattr__(self, "hotspot", float(hotspot))
        object.__setattr__(self, "falloff", float(falloff))
        object.__setattr__(self, "attenuation", _attenuation("spot_light", attenuation))

    def cone(self, cos_theta) -> np.ndarray:
        """Angular factor s(θ) ∈ [0, 1] for cos θ to the spot axis."""
        c0, c1 = np.cos(self.falloff), np.cos(self.hotspot)
        if c1 - c0 <= 0.0:  # hard edge (hotspot == falloff)
            return np.where(cos_theta >= c1, 1.0, 0.0)
        t = np.clip((cos_theta - c0) / (c1 - c0), 0.0, 1.0)
        return t * t * (3.0 - 2.0 * t)

    def incident(self, points):
        d = self.position - np.asarray(points, dtype=np.float64)
        r = np.linalg.norm(d, axis=-1)
        to_light = normalize(d, fallback=-self.direction)
        s = self.cone(dot(-to_light, self.direction))
        return to_light, self.intensity * (s * _falloff(self.attenuation, r))[..., None]


def total_irradiance(lights: Iterable[Light], points, normals) -> np.ndarray:
    """Σ over ``lights`` of their irradiance on the surface (lights add linearly), shape ``(..., 3)``."""
    total = np.zeros(np.broadcast_shapes(np.shape(points), np.shape(normals))[:-1] + (3,))
    for light in lights:  # a handful of lights, not samples
        total = total + light.illuminate(points, normals)[1]
    return total


