"""The "standard" lighting model of lecture notes ``000_b5f942c329dc4daf.txt`` — a renderer's
shading function (not a BRDF), for the simulator's camera.

c = k_a c_a + Σ_l c_l (k_d max(L_l·n, 0) + k_s (h_l·n)^s)

with L_l the direction to light l, h_l = normalize(L_l + v) the half vector (Blinn 1977) and c_l
the light's colour at the point: its normal irradiance (:meth:`gonio.lights.Light.incident`,
W/m², distance and spot falloff included). With ``schlick=True`` the power t^s is replaced by
Schlick's rational approximation t/(s − s t + t) (C. Schlick, "A Fast Alternative to Phong's
Specular Model", Graphics Gems IV, 1994; lecture notes 000). The specular term is 0 where the light
is behind the surface (L·n ≤ 0) and h·n is clipped at 0, so the result is finite and ≥ 0.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from gonio.brdf.fresnel import schlick_rational_power
from gonio.brdf.phong import cosine_power
from gonio.errors import ConfigError
from gonio.geometry import dot, normalize

__all__ = ["shade"]


def _rgb(field: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise ConfigError.field(None, f"lighting.{field}", value, "must be a finite number >= 0 or 3 of them (R, G, B)")
    return a


def shade(points, normals, view_dirs, lights: Iterable, *, ka=0.0, ca=0.0, kd=0.5, ks=0.5, s=20.0,
          schlick: bool = False) -> np.ndarray:
    """Colour c of surface points under ``lights`` by the lighting-model form (module docstring).

    Parameters
    ----------
    points, normals, view_dirs : array_like, ``(..., 3)``
        World positions (m), surface normals and directions from the point toward the viewer
        (normalized here; broadcast together).
    lights : iterable of :class:`gonio.lights.Light`
    ka, ca : float or 3 floats
        Ambient coefficient and ambient colour.
    kd, ks : float or 3 floats
        Diffuse and specular colours.
    s : float
        Shininess exponent, ≥ 0.
    schlick : bool
        Use t/(s − s t + t) instead of t^s.

    Returns
    -------
    ndarray ``(..., 3)``
    """
    ka, ca, kd, ks = _rgb("ka", ka), _rgb("ca", ca), _rgb("kd", kd), _rgb("ks", ks)
    if not (np.isfinite(s) and s >= 0):
        raise ConfigError.field(None, "lighting.s", s, "must be a finite number >= 0")
    points = np.asarray(points, dtype=np.float64)
    n = normalize(normals)
    v = normalize(view_dirs)
    shape = np.broadcast_shapes(points.shape, n.shape, v.shape)[:-1]
    color = np.broadcast_to(ka * ca, shape + (3,)).copy()
    for light in lights:  # a handful of lights, not samples
        to_light, c_l = light.incident(points)
        ln = dot(to_light, n)
        h = normalize(to_light + v, fallback=n)
        t = np.clip(dot(h, n), 0.0, 1.0)
        spec = schlick_rational_power(t, s) if schlick else cosine_power(t, s)
        spec = np.where(ln > 0.0, spec, 0.0)
        color = color + c_l * (kd * np.maximum(ln, 0.0)[..., None] + ks * spec[..., None])
    return color
