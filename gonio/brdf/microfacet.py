"""Shared microfacet pieces (written once, composed by the models): half vector, normal distributions
D, shadowing-masking G, and the Walter et al. 2007 microfacet model itself.

Conventions: directions are unit vectors in the local frame (z = normal), arrays ``(..., 3)``;
the functions keep the floating dtype of their input (float64 or float32).

Roughness floor: every α (and Cook-Torrance's m) is clamped at :data:`ALPHA_MIN` = 1e-4 inside the
formulas, so a perfectly smooth surface (α → 0) gives a very narrow but finite lobe instead of a
division by zero. Exponentials are formed so that they underflow to 0 instead of producing 0/0.

References
----------
- B. Walter, S. Marschner, H. Li, K. Torrance, "Microfacet Models for Refraction through Rough
  Surfaces", EGSR 2007 (eqs. 20, 25, 27, 33, 34).
- E. Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs", JCGT 3(2),
  2014 (anisotropic forms, separable Smith G2 = G1(wi) G1(wo)).
- R. Cook, K. Torrance, "A Reflectance Model for Computer Graphics", ACM ToG 1(1), 1982, and
  J. Blinn, "Models of Light Reflection for Computer Synthesized Pictures", SIGGRAPH 1977
  (the V-groove G); lecture notes ``004_6b0fa14dcb48ed2f.txt`` ("Full Cook-Torrance Lobe").
- Mitsuba 3, ``include/mitsuba/render/microfacet.h`` (the same Beckmann G1 approximation).
"""

from __future__ import annotations

import numpy as np

from gonio._jit import jitable, select
from gonio.brdf.base import BRDF, Param
from gonio.brdf.pairs import Lobe
from gonio.geometry import half_vector  # re-exported: the models import it from here

__all__ = [
    "ALPHA_MIN",
    "DISTRIBUTIONS",
    "clamp_alpha",
    "half_vector",
    "beckmann_d",
    "ggx_d",
    "distribution_d",
    "smith_g1",
    "smith_g2",
    "vgroove_g",
    "ggx_spec",
    "beckmann_spec",
    "Microfacet",
]

#: Roughness floor applied inside every formula (documented contract of gonio.brdf).
ALPHA_MIN = 1e-4
#: Names of the normal distributions.
DISTRIBUTIONS = ("ggx", "beckmann")


def _tiny(x) -> float:
    """Smallest normal number of ``x``'s dtype: a guard that survives float32."""
    return float(np.finfo(np.asarray(x).dtype if np.asarray(x).dtype.kind == "f" else np.float64).tiny)


@jitable
def clamp_alpha(alpha):
    """Roughness clamped at the floor :data:`ALPHA_MIN` (keeps the dtype of ``alpha``)."""
    return np.maximum(alpha, ALPHA_MIN)


def _stretch(hx, hy, ax, ay):
    """h_x²/α_x² + h_y²/α_y² (the anisotropic stretch of Heitz 2014, eq. 85)."""
    return (hx / ax) ** 2 + (hy / ay) ** 2


def beckmann_d(h, alpha_x, alpha_y=None) -> np.ndarray:
    """Normalized Beckmann distribution of microfacet normals ``h``.

    D(h) = exp(−(h_x²/α_x² + h_y²/α_y²) / h_z²) / (π α_x α_y h_z⁴)   for h_z > 0, else 0

    (Walter et al. 2007, eq. 25; anisotropic form as in Mitsuba 3). Isotropic when ``alpha_y`` is
    omitted. ∫ D(h) (h·n) dω_h = 1. The formula is :func:`beckmann_d_core`.
    """
    ax = clamp_alpha(alpha_x)
    ay = ax if alpha_y is None else clamp_alpha(alpha_y)
    return beckmann_d_core(_stretch(h[..., 0], h[..., 1], ax, ay), h[..., 2], ax, ay, _tiny(h))


@jitable
def beckmann_d_core(e, hz, ax, ay, tiny):
    """Beckmann D(h) = exp(−e / h_z²) / (π α_x α_y h_z⁴) for h_z > 0, else 0, from the stretched slope
    e = h_x²/α_x² + h_y²/α_y² (Walter et al. 2007, eq. 25; Mitsuba 3's anisotropic form). The exponential
    is evaluated before the division so grazing half vectors give 0, not 0/0."""
    c2 = np.maximum(hz * hz, tiny)
    d = np.exp(-(e / c2)) / (np.pi * ax * ay * np.maximum(c2 * c2, tiny))
    return select(hz > 0.0, d, 0.0)


def ggx_d(h, alpha_x, alpha_y=None) -> np.ndarray:
    """GGX (Trowbridge-Reitz) distribution of microfacet normals ``h``.

    D(h) = 1 / (π α_x α_y (h_x²/α_x² + h_y²/α_y² + h_z²)²)   for h_z > 0, else 0

    (Walter et al. 2007, eq. 33, written with h_x, h_y, h_z instead of tan θ_h so it is exact at
    θ_h = 0 and 90°; anisotropic form of Heitz 2014, eq. 85). ∫ D(h) (h·n) dω_h = 1. The formula is
    :func:`ggx_d_core`.
    """
    ax = clamp_alpha(alpha_x)
    ay = ax if alpha_y is None else clamp_alpha(alpha_y)
    return ggx_d_core(_stretch(h[..., 0], h[..., 1], ax, ay), h[..., 2], ax, ay)


@jitable
def ggx_d_core(e, hz, ax, ay):
    """GGX D(h) = 1 / (π α_x α_y (e + h_z²)²) for h_z > 0, else 0, from the stretched slope
    e = h_x²/α_x² + h_y²/α_y² (Walter et al. 2007, eq. 33; Heitz 2014, eq. 85)."""
    q = e + hz * hz
    d = 1.0 / (np.pi * ax * ay * q * q)
    return select(hz > 0.0, d, 0.0)


def distribution_d(name: str, h, alpha_x, alpha_y=None) -> np.ndarray:
    """D of the distribution called ``name`` (``"ggx"`` or ``"beckmann"``)."""
    if name == "ggx":
        return ggx_d(h, alpha_x, alpha_y)
    if name == "beckmann":
        return beckmann_d(h, alpha_x, alpha_y)
    raise ValueError(f"unknown microfacet distribution {name!r}; known: {', '.join(DISTRIBUTIONS)}")


def smith_g1(name: str, v, h, alpha_x, alpha_y=None) -> np.ndarray:
    """Smith masking function G1(v, h) of the distribution ``name``.

    With ``t² = (α_x² v_x² + α_y² v_y²) / v_z²`` (α² tan²θ_v, anisotropic as in Heitz 2014):

    - GGX (exact, Walter et al. 2007, eq. 34): G1 = 2 / (1 + √(1 + t²)) (:func:`ggx_g1_core`).
    - Beckmann (Walter et al. 2007, eq. 27, the rational approximation Mitsuba 3 uses):
      a = 1/t; G1 = (3.535 a + 2.181 a²) / (1 + 2.276 a + 2.577 a²) for a < 1.6, else 1
      (:func:`beckmann_g1_core`).

    G1 = 1 at normal incidence (t = 0) and 0 where the microfacet is seen from behind
    ((v·h) v_z ≤ 0), as in Mitsuba 3.
    """
    ax = clamp_alpha(alpha_x)
    ay = ax if alpha_y is None else clamp_alpha(alpha_y)
    vz = v[..., 2]
    tiny = _tiny(v)
    t2 = ((ax * v[..., 0]) ** 2 + (ay * v[..., 1]) ** 2) / np.maximum(vz * vz, tiny)
    visible = (v[..., 0] * h[..., 0] + v[..., 1] * h[..., 1] + v[..., 2] * h[..., 2]) * vz > 0.0
    if name == "ggx":
        return ggx_g1_core(t2, visible)
    if name == "beckmann":
        return beckmann_g1_core(t2, visible, tiny)
    raise ValueError(f"unknown microfacet distribution {name!r}; known: {', '.join(DISTRIBUTIONS)}")


@jitable
def ggx_g1_core(t2, visible):
    """GGX Smith G1 = 2 / (1 + √(1 + t²)) from t² = α² tan²θ_v (Walter et al. 2007, eq. 34); 0 where not
    ``visible`` ((v·h) v_z ≤ 0)."""
    g = 2.0 / (1.0 + np.sqrt(1.0 + t2))
    return select(visible, g, 0.0)


@jitable
def beckmann_g1_core(t2, visible, tiny):
    """Beckmann Smith G1 from t² = α² tan²θ_v, Walter et al. 2007, eq. 27 (Mitsuba 3's rational
    approximation): a = 1/t, G1 = (3.535 a + 2.181 a²) / (1 + 2.276 a + 2.577 a²) for a < 1.6, else 1;
    1 at t = 0; 0 where not ``visible``."""
    a = 1.0 / np.sqrt(np.maximum(t2, tiny))
    g = select(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a))
    return select(visible, select(t2 == 0.0, 1.0, g), 0.0)


def smith_g2(name: str, wi, wo, h, alpha_x, alpha_y=None) -> np.ndarray:
    """Separable Smith shadowing-masking G2 = G1(wi, h) · G1(wo, h) (Walter et al. 2007, eq. 23;
    Heitz 2014, eq. 98). This is the form Mitsuba 3 evaluates."""
    return smith_g1(name, wi, h, alpha_x, alpha_y) * smith_g1(name, wo, h, alpha_x, alpha_y)


def vgroove_g(wi, wo, h) -> np.ndarray:
    """V-groove shadowing-masking of Torrance-Sparrow / Blinn 1977 / Cook-Torrance 1982
    (:func:`vgroove_g_core` on the cosines)."""
    oh = wo[..., 0] * h[..., 0] + wo[..., 1] * h[..., 1] + wo[..., 2] * h[..., 2]
    return vgroove_g_core(wi[..., 2], wo[..., 2], h[..., 2], oh, _tiny(h))


@jitable
def vgroove_g_core(iz, oz, hz, oh, tiny):
    """V-groove shadowing-masking of Torrance-Sparrow / Blinn 1977 / Cook-Torrance 1982:

    G = min(1, 2 (n·h)(n·wo) / (wo·h), 2 (n·h)(n·wi) / (wo·h))

    (lecture notes ``004_6b0fa14dcb48ed2f.txt``, "Full Cook-Torrance Lobe"), from n·wi = ``iz``,
    n·wo = ``oz``, n·h = ``hz`` and wo·h = ``oh``. wo·h is guarded against 0 (only reached for wi = −wo,
    where h = n by convention).
    """
    oh = np.maximum(oh, tiny)
    g = np.minimum(1.0, np.minimum(2.0 * hz * oz / oh, 2.0 * hz * iz / oh))
    return np.maximum(g, 0.0)


@jitable
def ggx_spec(p, alpha):
    """GGX lobe of :class:`Microfacet` without colour and Fresnel: D G2 / (4 cos θi cos θo) (Walter et al.
    2007, eq. 20 with D eq. 33 (:func:`ggx_d_core`), separable Smith G2 eq. 23 of G1 eq. 34
    (:func:`ggx_g1_core`)) on the shared geometry ``p`` (:func:`gonio.brdf.pairs.pair_geometry`)."""
    a = clamp_alpha(alpha)
    a2 = a * a
    d = ggx_d_core(p.s2h / a2, p.hz, a, a)
    g = ggx_g1_core(a2 * p.ti2, p.ih * p.iz > 0.0) * ggx_g1_core(a2 * p.to2, p.oh * p.oz > 0.0)
    return d * g / (4.0 * p.cc)


@jitable
def beckmann_spec(p, alpha):
    """Beckmann lobe of :class:`Microfacet` without colour and Fresnel: D G2 / (4 cos θi cos θo) (Walter
    et al. 2007, eq. 20 with D eq. 25 (:func:`beckmann_d_core`) and G1 eq. 27 (:func:`beckmann_g1_core`))
    on the shared geometry ``p``."""
    a = clamp_alpha(alpha)
    a2 = a * a
    tiny = p.tiny
    d = beckmann_d_core(p.s2h / a2, p.hz, a, a, tiny)
    g = (beckmann_g1_core(a2 * p.ti2, p.ih * p.iz > 0.0, tiny)
         * beckmann_g1_core(a2 * p.to2, p.oh * p.oz > 0.0, tiny))
    return d * g / (4.0 * p.cc)


#: Spec function of each distribution.
SPECS = {"ggx": ggx_spec, "beckmann": beckmann_spec}


class Microfacet(BRDF):
    r"""Microfacet reflection model of Walter et al. 2007 plus a Lambertian term.

    f(wi, wo) = kd/π + ks · D(h) F(wo·h) G2(wi, wo, h) / (4 (n·wi)(n·wo))

    (Walter et al. 2007, eq. 20), h = normalize(wi + wo); D normalized Beckmann or GGX
    (:func:`beckmann_d`, :func:`ggx_d`), G2 the separable Smith form (:func:`smith_g2`; Beckmann
    with the rational G1 approximation, eq. 27, as Mitsuba 3), F Schlick's approximation with
    normal-incidence reflectance f0 (:func:`gonio.brdf.fresnel.schlick`). With ks = 1, f0 = 1 and
    kd = 0 this is Mitsuba 3's ``roughconductor`` with ``material = "none"``. Evaluated as one lobe
    (:func:`ggx_spec` / :func:`beckmann_spec`) on shared geometry (:mod:`gonio.brdf.pairs`).

    Parameters
    ----------
    kd : float or 3 floats
        Diffuse albedo in [0, 1].
    ks : float or 3 floats
        Specular weight in [0, 1].
    alpha : float
        Roughness α in [1e-4, 1] (clamped at :data:`ALPHA_MIN` inside the formulas).
    f0 : float or 3 floats
        Fresnel reflectance at normal incidence in [0, 1].
    distribution : {"ggx", "beckmann"}
    """

    name = "microfacet"
    PARAMS = {
        "kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo, per RGB channel"),
        "ks": Param("rgb", 0.0, 1.0, 1.0, doc="specular weight, per RGB channel"),
        "alpha": Param("scalar", ALPHA_MIN, 1.0, 0.1, doc="roughness alpha (GGX/Beckmann width)"),
        "f0": Param("rgb", 0.0, 1.0, 1.0, doc="Fresnel reflectance at normal incidence (Schlick)"),
        "distribution": Param("choice", default="ggx", choices=DISTRIBUTIONS, doc="normal distribution D"),
    }

    def _lobes(self):
        return self.kd / np.pi, [Lobe(SPECS[self.distribution], (self.alpha,), self.ks, self.f0)]
