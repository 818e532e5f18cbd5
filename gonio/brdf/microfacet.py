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
    "ggx_d_den",
    "beckmann_d_parts",
    "ggx_g1_den",
    "beckmann_g1_parts",
    "vgroove_g_parts",
    "ggx_spec",
    "ggx_spec_den",
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
    omitted. ∫ D(h) (h·n) dω_h = 1. The formula is :func:`beckmann_d_parts`.
    """
    ax = clamp_alpha(alpha_x)
    ay = ax if alpha_y is None else clamp_alpha(alpha_y)
    hz = h[..., 2]
    tiny = _tiny(h)
    c2 = np.maximum(hz * hz, tiny)
    num, den = beckmann_d_parts(_stretch(h[..., 0], h[..., 1], ax, ay) / c2, c2, ax, ay, tiny)
    return select(hz > 0.0, num / den, 0.0)


@jitable
def beckmann_d_parts(x, c2, ax, ay, tiny):
    """Beckmann D = num / den for h_z > 0 (Walter et al. 2007, eq. 25; Mitsuba 3's anisotropic form):
    num = exp(−x), den = π α_x α_y max(c2², tiny), with x = (h_x²/α_x² + h_y²/α_y²) / c2 and
    c2 = max(h_z², tiny). Returned as a fraction so a lobe divides once; the exponential underflows to 0 at
    grazing half vectors instead of giving 0/0."""
    return np.exp(-x), np.pi * ax * ay * np.maximum(c2 * c2, tiny)


def ggx_d(h, alpha_x, alpha_y=None) -> np.ndarray:
    """GGX (Trowbridge-Reitz) distribution of microfacet normals ``h``.

    D(h) = 1 / (π α_x α_y (h_x²/α_x² + h_y²/α_y² + h_z²)²)   for h_z > 0, else 0

    (Walter et al. 2007, eq. 33, written with h_x, h_y, h_z instead of tan θ_h so it is exact at
    θ_h = 0 and 90°; anisotropic form of Heitz 2014, eq. 85). ∫ D(h) (h·n) dω_h = 1. The formula is
    :func:`ggx_d_den`.
    """
    ax = clamp_alpha(alpha_x)
    ay = ax if alpha_y is None else clamp_alpha(alpha_y)
    hz = h[..., 2]
    return select(hz > 0.0, 1.0 / ggx_d_den(_stretch(h[..., 0], h[..., 1], ax, ay), hz * hz, ax, ay), 0.0)


@jitable
def ggx_d_den(e, hz2, ax, ay):
    """1/D of GGX for h_z > 0: π α_x α_y (e + h_z²)², from the stretched slope e = h_x²/α_x² + h_y²/α_y²
    and hz2 = h_z² (Walter et al. 2007, eq. 33; Heitz 2014, eq. 85). A reciprocal so a lobe divides once."""
    q = e + hz2
    return (np.pi * ax * ay) * (q * q)


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

    - GGX (exact, Walter et al. 2007, eq. 34): G1 = 2 / (1 + √(1 + t²)) = 2|v_z| / S
      (:func:`ggx_g1_den`).
    - Beckmann (Walter et al. 2007, eq. 27, the rational approximation Mitsuba 3 uses):
      a = 1/t; G1 = (3.535 a + 2.181 a²) / (1 + 2.276 a + 2.577 a²) for a < 1.6, else 1
      (:func:`beckmann_g1_parts`).

    G1 = 1 at normal incidence (t = 0), 0 at v_z = 0, and 0 where the microfacet is seen from behind
    ((v·h) v_z ≤ 0), as in Mitsuba 3.
    """
    ax = clamp_alpha(alpha_x)
    ay = ax if alpha_y is None else clamp_alpha(alpha_y)
    vz = v[..., 2]
    xy = (ax * v[..., 0]) ** 2 + (ay * v[..., 1]) ** 2
    if name == "ggx":
        g = 2.0 * np.abs(vz) / ggx_g1_den(np.abs(vz), vz * vz, xy)
    elif name == "beckmann":
        num, den = beckmann_g1_parts(np.abs(vz), np.sqrt(xy))
        g = num / den
    else:
        raise ValueError(f"unknown microfacet distribution {name!r}; known: {', '.join(DISTRIBUTIONS)}")
    visible = (v[..., 0] * h[..., 0] + v[..., 1] * h[..., 1] + v[..., 2] * h[..., 2]) * vz > 0.0
    return select(visible, select(xy == 0.0, 1.0, g), 0.0)


@jitable
def ggx_g1_den(c, c2, xy):
    """S = |v_z| + √(v_z² + xy) from c = |v_z|, c2 = v_z² and xy = α_x² v_x² + α_y² v_y²: the GGX Smith G1 of
    Walter et al. 2007, eq. 34, 2 / (1 + √(1 + α² tan²θ_v)), is 2|v_z| / S (multiplied through by |v_z|: no
    tan, finite at the horizon), so G1(v) / (2 cos θ_v) = 1/S."""
    return c + np.sqrt(c2 + xy)


@jitable
def beckmann_g1_parts(c, sa):
    """Beckmann Smith G1 = num / den from c = |cos θ_v| and sa = α sin θ_v (anisotropic: √(α_x² v_x² + α_y² v_y²)):
    Walter et al. 2007, eq. 27 (Mitsuba 3's rational approximation) in a = 1/(α tan θ_v) = c / sa,
    (3.535 a + 2.181 a²) / (1 + 2.276 a + 2.577 a²) for a < 1.6, else 1, with numerator and denominator
    multiplied by sa² (no division, no tan: exact at θ_v = 0 and 90°): num = 3.535 c sa + 2.181 c²,
    den = sa² + 2.276 c sa + 2.577 c²; (1, 1) where c ≥ 1.6 sa."""
    big = c >= 1.6 * sa
    return (select(big, 1.0, 3.535 * c * sa + 2.181 * c * c),
            select(big, 1.0, sa * sa + 2.276 * c * sa + 2.577 * c * c))


def smith_g2(name: str, wi, wo, h, alpha_x, alpha_y=None) -> np.ndarray:
    """Separable Smith shadowing-masking G2 = G1(wi, h) · G1(wo, h) (Walter et al. 2007, eq. 23;
    Heitz 2014, eq. 98). This is the form Mitsuba 3 evaluates."""
    return smith_g1(name, wi, h, alpha_x, alpha_y) * smith_g1(name, wo, h, alpha_x, alpha_y)


def vgroove_g(wi, wo, h) -> np.ndarray:
    """V-groove shadowing-masking of Torrance-Sparrow / Blinn 1977 / Cook-Torrance 1982
    (:func:`vgroove_g_parts` on the cosines)."""
    oh = wo[..., 0] * h[..., 0] + wo[..., 1] * h[..., 1] + wo[..., 2] * h[..., 2]
    num, den = vgroove_g_parts(wi[..., 2], wo[..., 2], h[..., 2], oh, _tiny(h))
    return num / den


@jitable
def vgroove_g_parts(iz, oz, hz, oh, tiny):
    """V-groove shadowing-masking of Torrance-Sparrow / Blinn 1977 / Cook-Torrance 1982:

    G = min(1, 2 (n·h)(n·wo) / (wo·h), 2 (n·h)(n·wi) / (wo·h)), clamped at 0

    (lecture notes ``004_6b0fa14dcb48ed2f.txt``, "Full Cook-Torrance Lobe"), from n·wi = ``iz``,
    n·wo = ``oz``, n·h = ``hz`` and wo·h = ``oh``, as G = num / den with den = max(wo·h, tiny) > 0 and
    num = max(min(den, 2 (n·h) min-term), 0) (the same value: the division by den > 0 is monotone).
    wo·h is guarded against 0 (only reached for wi = −wo, where h = n by convention).
    """
    den = np.maximum(oh, tiny)
    return np.maximum(np.minimum(den, np.minimum(2.0 * hz * oz, 2.0 * hz * iz)), 0.0), den


@jitable
def ggx_spec(p, alpha):
    """GGX lobe of :class:`Microfacet` without colour and Fresnel: D G2 / (4 cos θi cos θo) (Walter et al.
    2007, eq. 20 with D eq. 33 and separable Smith G2 eq. 23 of G1 eq. 34) on the shared geometry ``p``
    (:func:`gonio.brdf.pairs.pair_geometry`): 1 / :func:`ggx_spec_den` where the microfacet is visible
    (``p.vis``), else 0."""
    return select(p.vis > 0.0, 1.0 / ggx_spec_den(p, alpha), 0.0)


@jitable
def ggx_spec_den(p, alpha):
    """1 / (D G2 / (4 cos θi cos θo)) of GGX for pairs above the horizon with a visible microfacet (see
    :func:`ggx_spec`): with G1(v) = 2 cos θ_v / S_v (:func:`ggx_g1_den`; cos θ_v = |cos θ_v| above the horizon)
    the cosines cancel, D G2 / (4 cos θi cos θo) = 1 / (D⁻¹ S_i S_o), D⁻¹ of :func:`ggx_d_den`: one division."""
    a = clamp_alpha(alpha)
    a2 = a * a
    return (ggx_d_den(p.s2h * (1.0 / a2), p.hz2, a, a) * ggx_g1_den(p.iz, p.iz2, a2 * p.si2)
            * ggx_g1_den(p.oz, p.oz2, a2 * p.so2))


@jitable
def beckmann_spec(p, alpha):
    """Beckmann lobe of :class:`Microfacet` without colour and Fresnel: D G2 / (4 cos θi cos θo) (Walter
    et al. 2007, eq. 20 with D eq. 25 (:func:`beckmann_d_parts`) and G1 eq. 27 (:func:`beckmann_g1_parts`))
    on the shared geometry ``p``; the fractions are multiplied out and divided once."""
    a = clamp_alpha(alpha)
    tiny = p.tiny
    c2 = np.maximum(p.hz2, tiny)
    dn, dd = beckmann_d_parts(p.th2 * (1.0 / (a * a)), c2, a, a, tiny)
    gin, gid = beckmann_g1_parts(p.iz, a * p.si)
    gon, god = beckmann_g1_parts(p.oz, a * p.so)
    return select(p.vis > 0.0, (dn * gin * gon) / (dd * gid * god * (4.0 * p.cc)), 0.0)


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
