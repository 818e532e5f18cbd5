"""Löw et al. 2012's ABC models: the microfacet variant and the smooth-surface variant.

J. Löw, J. Kronander, A. Ynnerman, J. Unger, "BRDF Models for Accurate and Efficient Rendering of
Glossy Surfaces", ACM Transactions on Graphics 31(1), 2012. The ABC function
S(x) = A / (1 + B x)^C (the K-correlation / "ABC" power spectral density of Church et al., written
with x = the squared spatial frequency) describes the specular lobe of measured glossy materials with
far fewer parameters than a tabulated lobe; Löw et al. fit it to the 100 MERL materials. The
parameters of those fits are tabulated in J. Dupuy's ``dj_brdf.h`` (``djb::abc``, GitHub
jdupuy/dj_brdf), whose evaluation the microfacet variant reproduces exactly.
"""

from __future__ import annotations

import numpy as np

from gonio._jit import jitable, power
from gonio.brdf.base import BRDF, Param
from gonio.brdf.fresnel import dielectric_core, dielectric_parts
from gonio.brdf.microfacet import vgroove_g_parts
from gonio.brdf.pairs import Lobe, cos_d, split_value

__all__ = ["ABCMicrofacet", "ABCSmooth", "abc_s", "abc_s_core", "abc_base", "abc_spec", "abc_spec_split",
           "abc_smooth_spec", "abc_smooth_spec_split", "abc_smooth_x", "abc_fresnel"]

#: Upper bound of B: ~1/B is the lobe width in (1 − cos θh); 1e7 resolves lobes far narrower than a
#: MERL cell at θh = 0 (Löw's fits reach B ≈ 6·10⁶ for fabrics' grazing lobes).
B_MAX = 1e8
#: Lower bound of B: below it the lobe is flat over the hemisphere (B x ≤ 10⁻² · 4); it is also where the
#: (log-scaled) search of B starts, so broad lobes (Löw's fits of paints reach B ≈ 25) are reached.
B_MIN = 1e-2


def abc_s(x, A, B, C) -> np.ndarray:
    """The ABC function S(x) = A / (1 + B x)^C (Löw et al. 2012, eq. 7, with x the squared frequency).

    Computed as A · exp(−C · log(1 + B x)) so large B·x underflows to 0 instead of overflowing. (``log``,
    not ``log1p``: the absolute error of log(1 + B x) is ≤ ε however small B x is, which bounds the
    relative error of S by C ε ≤ 6e-15, and ``log`` is about half the cost in the compiled loop.)
    ``A`` may be RGB (last axis 3); ``x`` has the sample shape. The formula is :func:`abc_s_core`.
    """
    return abc_s_core(x, B, C)[..., None] * A


@jitable
def abc_s_core(x, B, C):
    """S(x)/A = (1 + B x)^−C = exp(−C · log(1 + B x)) (Löw et al. 2012, eq. 7; see :func:`abc_s`), x clamped
    at 0; arrays or scalars (:func:`gonio._jit.power` of :func:`abc_base`)."""
    return power(abc_base(x, B), -C)


@jitable
def abc_base(x, B):
    """The base 1 + B x of the ABC function's power (:func:`abc_s_core`), x clamped at 0."""
    return 1.0 + B * np.maximum(x, 0.0)


@jitable
def abc_spec(p, B, C, eta):
    """The lobe of :class:`ABCMicrofacet` without its colour A: D F G / (π cos θi cos θo) with
    D/A = (1 + B (1 − cos θh))^−C (:func:`abc_s_core`), F the exact dielectric Fresnel at θd
    (:func:`gonio.brdf.fresnel.dielectric_parts`) and G the V-groove shadowing
    (:func:`gonio.brdf.microfacet.vgroove_g_parts`) (Löw et al. 2012, §5, eqs. 12–13), on the shared
    geometry ``p`` (:func:`gonio.brdf.pairs.pair_geometry`); F and G are fractions, divided once: the
    :func:`~gonio.brdf.pairs.split_value` of :func:`abc_spec_split`."""
    return split_value(*abc_spec_split(p, B, C, eta))


@jitable
def abc_spec_split(p, B, C, eta):
    """:func:`abc_spec` as ``(base, exponent, factor)`` (:func:`gonio.brdf.pairs.split_value`): D/A =
    :func:`abc_base` (1 − cos θh, B) ^ −C and the factor F G / (π cos θi cos θo)."""
    cd = cos_d(p)
    fn, fd = dielectric_parts(np.minimum(np.maximum(cd, 0.0), 1.0), eta)
    gn, gd = vgroove_g_parts(p.iz, p.oz, p.hz, cd, p.tiny)
    return abc_base(1.0 - np.minimum(np.maximum(p.hz, 0.0), 1.0), B), -C, fn * gn / (fd * gd * (np.pi * p.cc))


@jitable
def abc_smooth_x(p):
    """x = ‖wi⊥ + wo⊥‖², the squared projection of wi + wo on the surface plane (the frequency of Löw et al.
    2012, §4, without the wavelength), from the pair geometry ``p``: wi + wo = |wi + wo| h and, for unit wi, wo,
    |wi + wo| = 2 wi·h, so x = 4 (cos θd)² (h_x² + h_y²) with cos θd = wi·h (:func:`~gonio.brdf.pairs.cos_d`) (products of positive terms: no cancellation at the
    specular peak, where x → 0)."""
    cd = cos_d(p)
    return 4.0 * (cd * cd) * p.s2h


@jitable
def abc_fresnel(p, eta):
    """The Fresnel factor of both ABC models: the exact dielectric reflectance at θd
    (:func:`gonio.brdf.fresnel.dielectric_core`; Born & Wolf §1.5) of cos θd (:func:`~gonio.brdf.pairs.cos_d`) clamped to [0, 1]."""
    return dielectric_core(np.minimum(np.maximum(cos_d(p), 0.0), 1.0), eta)


@jitable
def abc_smooth_spec(p, B, C, eta):
    """The lobe of :class:`ABCSmooth` without its colour A: S(x)/A · F(θd; η) (Löw et al. 2012, §4, eq. 7 with
    F in place of Q) with x of :func:`abc_smooth_x`, S of :func:`abc_s_core`, F of :func:`abc_fresnel`, on the
    shared geometry ``p`` (:func:`gonio.brdf.pairs.pair_geometry`): the :func:`~gonio.brdf.pairs.split_value`
    of :func:`abc_smooth_spec_split`."""
    return split_value(*abc_smooth_spec_split(p, B, C, eta))


@jitable
def abc_smooth_spec_split(p, B, C, eta):
    """:func:`abc_smooth_spec` as ``(base, exponent, factor)`` (:func:`gonio.brdf.pairs.split_value`): S(x)/A =
    :func:`abc_base` (x, B) ^ −C and the factor F(θd; η)."""
    return abc_base(abc_smooth_x(p), B), -C, abc_fresnel(p, eta)


class ABCMicrofacet(BRDF):
    r"""Löw et al. 2012's microfacet ABC model, as fitted to MERL (``djb::abc::eval``):

    f(wi, wo) = kd/π + F(θd; η) · D(h) · G(wi, wo, h) / (π cos θi cos θo),
    D(h) = A / (1 + B (1 − cos θh))^C,

    (Löw et al. 2012, §5, eqs. 12–13: the ABC distribution of microfacet normals in 1 − cos θh), with
    F the exact unpolarized dielectric Fresnel reflectance of index η (:func:`gonio.brdf.fresnel.dielectric`)
    and G the V-groove shadowing of Cook & Torrance 1982 (:func:`gonio.brdf.microfacet.vgroove_g`; dj_brdf
    takes min(G1(wi), G1(wo)), the same function). A (per channel) carries the colour and the lobe's
    scale; B and C its shape, shared by R, G, B. D is not normalized, so the directional albedo is not
    bounded by the parameters' ranges: fits check it (``gonio.fit.energy``).

    Parameters
    ----------
    kd : float or 3 floats
        Diffuse albedo in [0, 1].
    A : float or 3 floats
        Lobe scale (≥ 0, 1/sr).
    B : float
        Lobe sharpness, in [1e-2, 1e8].
    C : float
        Lobe fall-off exponent, in [0, 50].
    eta : float
        Index of refraction of the Fresnel term, in [1, 100] (dj_brdf's fits reach ~100 for metals, where F ≈ 1).
    """

    name = "abc"
    PARAMS = {
        "kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo, per RGB channel"),
        "A": Param("rgb", 0.0, np.inf, 1.0, doc="ABC lobe scale A (1/sr), per RGB channel"),
        "B": Param("scalar", B_MIN, B_MAX, 100.0, doc="ABC lobe sharpness B"),
        "C": Param("scalar", 1e-3, 50.0, 1.0, doc="ABC lobe fall-off exponent C"),
        "eta": Param("scalar", 1.0, 100.0, 1.5, doc="index of refraction of the Fresnel term"),
    }
    energy_conserving = False

    def _lobes(self):
        return self.kd / np.pi, [Lobe(abc_spec, (self.B, self.C, self.eta), self.A)]


class ABCSmooth(BRDF):
    r"""Löw et al. 2012's smooth-surface ABC model (§4, Rayleigh–Rice form with the ABC spectrum):

    f(wi, wo) = kd/π + F(θd; η) · S(‖wi⊥ + wo⊥‖²),     S(x) = A / (1 + B x)^C,

    where w⊥ is the projection of a direction onto the surface plane (x, y), so ‖wi⊥ + wo⊥‖ is the
    projected deviation from the mirror direction (zero at the specular peak: the spatial frequency of
    Rayleigh–Rice scattering, without the wavelength), F the exact unpolarized dielectric Fresnel
    reflectance at θd (Löw et al. use F(θd) in place of the polarization factor Q). A (per channel)
    carries the colour, B and C the shape. Not normalized: fits check the albedo (``gonio.fit.energy``).

    Parameters
    ----------
    kd : float or 3 floats
        Diffuse albedo in [0, 1].
    A : float or 3 floats
        Lobe scale (≥ 0, 1/sr).
    B, C : float
        Lobe sharpness in [1e-2, 1e8] and fall-off exponent in [1e-3, 50].
    eta : float
        Index of refraction in [1, 100].
    """

    name = "abc-smooth"
    PARAMS = dict(ABCMicrofacet.PARAMS)
    energy_conserving = False

    def _lobes(self):
        return self.kd / np.pi, [Lobe(abc_smooth_spec, (self.B, self.C, self.eta), self.A)]
