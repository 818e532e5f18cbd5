"""The Cook-Torrance model exactly in the form of the lecture notes."""

from __future__ import annotations

import numpy as np

from gonio._jit import jitable, select
from gonio.brdf.base import BRDF, Param
from gonio.brdf.microfacet import ALPHA_MIN, beckmann_d_parts, clamp_alpha, vgroove_g_parts
from gonio.brdf.pairs import Lobe, cos_d

__all__ = ["CookTorrance", "cook_torrance_spec"]


@jitable
def cook_torrance_spec(p, roughness):
    """The Cook-Torrance lobe without colour and Fresnel, D G / ((n·wi)(n·wo)) with D = π × the normalized
    Beckmann D (:func:`gonio.brdf.microfacet.beckmann_d_parts`, Walter et al. 2007, eq. 25) and the V-groove
    G (:func:`gonio.brdf.microfacet.vgroove_g_parts`), on the shared geometry ``p``
    (:func:`gonio.brdf.pairs.pair_geometry`); Cook & Torrance 1982, lecture notes ``004_6b0fa14dcb48ed2f.txt``."""
    m = clamp_alpha(roughness)
    im = 1.0 / m
    tiny = p.tiny
    dn, dd = beckmann_d_parts(p.th2 * (im * im), np.maximum(p.hz2, tiny), m, m, tiny)
    gn, gd = vgroove_g_parts(p.iz, p.oz, p.hz, cos_d(p), tiny)
    return select(p.hz > 0.0, np.pi * dn * gn / (dd * gd * p.cc), 0.0)


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

    def _lobes(self):
        return self.kd / np.pi, [Lobe(cook_torrance_spec, (self.roughness,), self.ks / np.pi, self.f0)]
