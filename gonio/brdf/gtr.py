"""Burley 2012's generalized Trowbridge-Reitz (GTR) specular lobe."""

from __future__ import annotations

import numpy as np

from gonio.brdf.base import BRDF, Param
from gonio.brdf.fresnel import one_minus_cos_d, schlick
from gonio.brdf.microfacet import ALPHA_MIN, _tiny, half_vector, smith_g2

__all__ = ["GTR", "gtr_d"]

#: Roughness ceiling: the normalization has a removable singularity at α = 1 (a uniform distribution).
ALPHA_MAX = 0.999


def gtr_d(cos_h, alpha, gamma) -> np.ndarray:
    """Normalized GTR distribution of microfacet normals (B. Burley, "Physically-Based Shading at Disney",
    SIGGRAPH 2012 course notes, §5.4 and Appendix B):

    D(θh) = c / (α² cos²θh + sin²θh)^γ,  c = (1 − α²)(1 − γ) / (π (1 − (α²)^(1−γ)))  (γ ≠ 1),
    c = (1 − α²) / (π ln(1/α²))  (γ = 1),

    so that ∫ D cos θh dω = 1 (derived by u = 1 − (1 − α²) cos²θh). γ = 2 is GGX (c = α²/π), γ = 1 Burley's
    clearcoat lobe; small γ gives the long tails of measured materials. 1 − (α²)^(1−γ) is formed with
    ``expm1`` so γ → 1 is continuous. α is clamped to [1e-4, 0.999].
    """
    a2 = np.clip(alpha, ALPHA_MIN, ALPHA_MAX) ** 2
    lna2 = np.log(a2)
    g1 = 1.0 - gamma
    if abs(g1) < 1e-9:
        c = (1.0 - a2) / (np.pi * -lna2)
    else:
        c = (1.0 - a2) * g1 / (np.pi * -np.expm1(g1 * lna2))
    c2 = np.clip(cos_h, 0.0, 1.0) ** 2
    q = a2 * c2 + (1.0 - c2)
    return np.where(cos_h > 0.0, c * np.exp(-gamma * np.log(np.maximum(q, _tiny(q)))), 0.0)


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

    def _eval(self, wi, wo):
        h = half_vector(wi, wo)
        d = gtr_d(h[..., 2], self.alpha, self.gamma)
        g = smith_g2("ggx", wi, wo, h, self.alpha)
        oh = np.sum(wo * h, axis=-1)
        denom = 4.0 * np.maximum(wi[..., 2] * wo[..., 2], _tiny(wi))
        spec = (d * g / denom)[..., None] * schlick(self.f0, oh, one_minus_cos_d(wi, wo, h))
        return self.kd / np.pi + self.ks * spec
