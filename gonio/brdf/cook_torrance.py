"""The Cook-Torrance model exactly in the form of the lecture notes."""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import BRDF, Param
from gonio.brdf.fresnel import one_minus_cos_d, schlick
from gonio.brdf.microfacet import ALPHA_MIN, _tiny, beckmann_d, half_vector, vgroove_g

__all__ = ["CookTorrance"]


class CookTorrance(BRDF):
    r"""Cook-Torrance (1982) as written in lecture notes ``004_6b0fa14dcb48ed2f.txt``
    ("Full Cook-Torrance Lobe"):

    f = kd/π + ks/π · D G F / ((n·wi)(n·wo))

    D = exp(−(tan δ / m)²) / (m² cos⁴ δ)   (δ = angle between h and n; = π × the normalized
    Beckmann D of :func:`gonio.brdf.microfacet.beckmann_d`),
    G = min(1, 2(n·h)(n·wo)/(wo·h), 2(n·h)(n·wi)/(wo·h))   (:func:`~gonio.brdf.microfacet.vgroove_g`),
    F = Schlick(f0, wo·h).

    R. Cook, K. Torrance, "A Reflectance Model for Computer Graphics", ACM ToG 1(1), 1982. Note the
    denominator (n·wi)(n·wo) without Walter's factor 4: the lobe's albedo can reach ~4·ks, so the
    model is not marked energy conserving (use ``microfacet`` for a normalized lobe). m is clamped
    at 1e-4 inside the formula.

    Parameters
    ----------
    kd, ks : float or 3 floats
        Diffuse albedo and specular coefficient ρ_s in [0, 1].
    roughness : float
        Beckmann slope m in [1e-4, 1].
    f0 : float or 3 floats
        Fresnel reflectance at normal incidence in [0, 1].
    """

    name = "cook-torrance"
    PARAMS = {
        "kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo, per RGB channel"),
        "ks": Param("rgb", 0.0, 1.0, 1.0, doc="specular coefficient rho_s, per RGB channel"),
        "roughness": Param("scalar", ALPHA_MIN, 1.0, 0.2, doc="Beckmann RMS slope m"),
        "f0": Param("rgb", 0.0, 1.0, 0.04, doc="Fresnel reflectance at normal incidence (Schlick)"),
    }
    energy_conserving = False

    def _eval(self, wi, wo):
        h = half_vector(wi, wo)
        d = np.pi * beckmann_d(h, self.roughness)
        g = vgroove_g(wi, wo, h)
        oh = wo[..., 0] * h[..., 0] + wo[..., 1] * h[..., 1] + wo[..., 2] * h[..., 2]
        denom = np.maximum(wi[..., 2] * wo[..., 2], _tiny(wi))
        spec = (d * g / denom)[..., None] * schlick(self.f0, oh, one_minus_cos_d(wi, wo, h))
        return self.kd / np.pi + self.ks / np.pi * spec
