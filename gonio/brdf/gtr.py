"""Burley 2012's generalized Trowbridge-Reitz (GTR) specular lobe."""

from __future__ import annotations

import numpy as np

from gonio._jit import jitable, power, select
from gonio.brdf.base import BRDF, Param
from gonio.brdf.microfacet import ALPHA_MIN, clamp_alpha, ggx_g1_den
from gonio.brdf.pairs import Lobe, split_value

__all__ = ["GTR", "gtr_d", "gtr_norm", "gtr_shape", "gtr_shape_c2", "gtr_base", "gtr_spec", "gtr_spec_split"]

#: Roughness ceiling: the normalization has a removable singularity at α = 1 (a uniform distribution).
ALPHA_MAX = 0.999


def gtr_d(cos_h, alpha, gamma) -> np.ndarray:
    """Normalized GTR distribution of microfacet normals (B. Burley, "Physically-Based Shading at Disney",
    SIGGRAPH 2012 course notes, §5.4 and Appendix B):

    D(θh) = c / (α² cos²θh + sin²θh)^γ,  c = (1 − α²)(1 − γ) / (π (1 − (α²)^(1−γ)))  (γ ≠ 1),
    c = (1 − α²) / (π ln(1/α²))  (γ = 1),

    so that ∫ D cos θh dω = 1 (derived by u = 1 − (1 − α²) cos²θh). γ = 2 is GGX (c = α²/π), γ = 1 Burley's
    clearcoat lobe; small γ gives the long tails of measured materials. α is clamped to [1e-4, 0.999].
    The formulas are :func:`gtr_norm` (c) and :func:`gtr_shape_c2`.
    """
    return gtr_shape(cos_h, alpha, gamma, gtr_norm(alpha, gamma))


@jitable
def gtr_norm(alpha, gamma):
    """The normalization c of :func:`gtr_d` (Burley 2012, Appendix B; scalars): (1 − α²)(1 − γ) /
    (π (1 − (α²)^(1−γ))) with 1 − (α²)^(1−γ) formed by ``expm1`` so γ → 1 is continuous, and
    (1 − α²) / (π ln(1/α²)) at γ = 1."""
    a2 = np.minimum(np.maximum(alpha, ALPHA_MIN), ALPHA_MAX) ** 2
    lna2 = np.log(a2)
    g1 = 1.0 - gamma
    if abs(g1) < 1e-9:
        return (1.0 - a2) / (np.pi * -lna2)
    return (1.0 - a2) * g1 / (np.pi * -np.expm1(g1 * lna2))


def gtr_shape(cos_h, alpha, gamma, c):
    """D(θh) = c / (α² cos²θh + sin²θh)^γ of :func:`gtr_d` given its normalization ``c`` (:func:`gtr_norm`);
    0 for cos θh ≤ 0 (:func:`gtr_shape_c2` of cos²θh)."""
    return select(cos_h > 0.0, gtr_shape_c2(np.minimum(np.maximum(cos_h, 0.0), 1.0) ** 2, alpha, gamma, c), 0.0)


@jitable
def gtr_shape_c2(c2, alpha, gamma, c):
    """D(θh) = c / (α² cos²θh + sin²θh)^γ of :func:`gtr_d` (Burley 2012, Appendix B) for cos θh > 0, from
    c2 = cos²θh ≤ 1, as c · exp(−γ ln(α² c2 + 1 − c2)) (:func:`gonio._jit.power`); the base is ≥ α² > 0."""
    return c * power(gtr_base(c2, alpha), -gamma)


@jitable
def gtr_base(c2, alpha):
    """The base α² c2 + 1 − c2 of :func:`gtr_shape_c2`'s power (α clamped as there), ≥ α² > 0."""
    a2 = np.minimum(np.maximum(alpha, ALPHA_MIN), ALPHA_MAX) ** 2
    return a2 * c2 + (1.0 - c2)


@jitable
def gtr_spec(p, alpha, gamma, c):
    """The GTR lobe of :class:`GTR` without colour and Fresnel: D_GTR G2 / (4 cos θi cos θo) (Walter et al.
    2007, eq. 20 with D of :func:`gtr_d` and the GGX Smith G1 of eq. 34, Burley 2012 §5.6) on the shared
    geometry ``p`` (:func:`gonio.brdf.pairs.pair_geometry`); G1(v) = 2 cos θ_v / S_v
    (:func:`gonio.brdf.microfacet.ggx_g1_den`), so D G2 / (4 cos θi cos θo) = D / (S_i S_o). ``c`` is D's
    normalization :func:`gtr_norm` (computed once per model). The :func:`~gonio.brdf.pairs.split_value` of
    :func:`gtr_spec_split`."""
    return split_value(*gtr_spec_split(p, alpha, gamma, c))


@jitable
def gtr_spec_split(p, alpha, gamma, c):
    """:func:`gtr_spec` as ``(base, exponent, factor)`` (:func:`gonio.brdf.pairs.split_value`): the power of
    :func:`gtr_shape_c2` (:func:`gtr_base` of min(cos²θh, 1), −γ) and the factor c / (S_i S_o) where the
    microfacet is visible, else 0."""
    a = clamp_alpha(alpha)
    a2 = a * a
    s = ggx_g1_den(p.iz, p.iz2, a2 * p.si2) * ggx_g1_den(p.oz, p.oz2, a2 * p.so2)
    return gtr_base(np.minimum(p.hz2, 1.0), alpha), -gamma, select(p.vis > 0.0, c / s, 0.0)


class GTR(BRDF):
    r"""Microfacet model with Burley 2012's GTR distribution, plus a Lambertian term:

    f(wi, wo) = kd/π + ks · D_GTR(h) G2(wi, wo, h) F(θd) / (4 cos θi cos θo)

    (Walter et al. 2007, eq. 20 with D of :func:`gtr_d`). G2 is the separable Smith shadowing of GGX with
    the same α (Burley 2012 §5.6 takes the GGX-derived G for the GTR specular lobe; exact for γ = 2),
    F Schlick's approximation with normal-incidence reflectance f0. The lobe's shape (α, γ) is shared
    by R, G, B; colour is in kd, ks (and f0). With ks, f0 ≤ 1 the lobe's albedo stays ≤ ks for γ = 2
    (measured for other γ in tests: the GGX G is not GTR's own Smith G).

    Parameters
    ----------
    kd, ks : float or 3 floats
        Diffuse albedo and specular weight in [0, 1].
    alpha : float
        Roughness α in [1e-4, 0.999].
    gamma : float
        Tail exponent γ in [0.5, 10] (2 = GGX, 1 = Burley's clearcoat, → ∞ approaches Beckmann-like tails).
    f0 : float or 3 floats
        Fresnel reflectance at normal incidence in [0, 1].
    """

    name = "gtr"
    PARAMS = {
        "kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo, per RGB channel"),
        "ks": Param("rgb", 0.0, 1.0, 1.0, doc="specular weight, per RGB channel"),
        "alpha": Param("scalar", ALPHA_MIN, ALPHA_MAX, 0.1, doc="roughness alpha of the GTR lobe"),
        "gamma": Param("scalar", 0.5, 10.0, 2.0, doc="GTR tail exponent gamma (2 = GGX)"),
        "f0": Param("rgb", 0.0, 1.0, 1.0, doc="Fresnel reflectance at normal incidence (Schlick)"),
    }
    energy_conserving = False

    def _lobes(self):
        return self.kd / np.pi, [Lobe(gtr_spec, (self.alpha, self.gamma, gtr_norm(self.alpha, self.gamma)), self.ks,
                                      self.f0)]
