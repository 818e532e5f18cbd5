"""Löw et al. 2012's smooth-surface ABC lobe with a conductor's Fresnel factor (a complex index η + i k): the model a
sample declared a metal is fitted with (``gonio fit --select --metal``, issue 29).

Why a separate scale and a conductor Fresnel. A MERL metal's table reflects 0.02–0.11 of the light in its specular
lobe, a dark dielectric's level, while a metal's normal-incidence reflectance is above 0.5 (Palik, *Handbook of Optical
Constants of Solids*, 1985). A model whose Fresnel factor is the lobe's whole amplitude then fits a metal with a
dielectric's f0 of 0.08 and its Fresnel rise towards grazing; the published ABC fits (Löw et al. 2012) keep the lobe's
amplitude A apart from the Fresnel factor instead, which then only shapes the θd dependence (their chrome: η ≈ 100,
F ≈ 0.96 at every angle). Here F is the exact Fresnel reflectance of a conductor (:func:`gonio.brdf.fresnel.conductor`;
Cook & Torrance 1982 appendix), so a metal gets a metal's Fresnel *shape* — flat until grazing, then towards 1 — at the
amplitude its table measures. What A means physically: A·albedo(B, C) (:func:`gonio.fit.kernels_abc.abc_smooth_albedo`,
the lobe's directional albedo at normal incidence with F = 1) is the fraction of the light the lobe would reflect from a
perfect mirror of the same roughness — the specular scale ks of ``dupuy2015-conductor``; below 1 it is what the surface
loses beyond the conductor's Fresnel (scattering outside the measured lobe, oxide or contamination layers) or the
table's absolute calibration. The fit's notes print it beside F(0).
"""

from __future__ import annotations

import numpy as np

from gonio._jit import jitable
from gonio.brdf.abc import ABCSmooth, abc_base, abc_smooth_x
from gonio.brdf.base import BRDF, Param
from gonio.brdf.fresnel import F0_MAX, METAL_F0_MIN, conductor_core, gulbrandsen_index
from gonio.brdf.pairs import Lobe, cos_d, split_value

__all__ = ["ABCSmoothConductor", "abc_smooth_conductor_spec", "abc_conductor_fresnel"]


@jitable
def abc_conductor_fresnel(p, eta, k):
    """The conductor's Fresnel reflectance at θd (:func:`gonio.brdf.fresnel.conductor_core`; Cook & Torrance 1982) of
    cos θd (:func:`~gonio.brdf.pairs.cos_d`) clamped to [0, 1]."""
    return conductor_core(np.minimum(np.maximum(cos_d(p), 0.0), 1.0), eta, k)


@jitable
def abc_smooth_conductor_spec(p, B, C, eta, k):
    """The lobe of :class:`ABCSmoothConductor` without its colour A: S(x)/A · F_conductor(θd; η, k) (Löw et al. 2012,
    §4, eq. 7, with a conductor's F in place of Q), x of :func:`gonio.brdf.abc.abc_smooth_x`."""
    return split_value(abc_base(abc_smooth_x(p), B), -C, abc_conductor_fresnel(p, eta, k))


class ABCSmoothConductor(BRDF):
    r"""Löw et al. 2012's smooth-surface ABC model with a conductor's Fresnel factor:

    f(wi, wo) = kd/π + A · F(θd; η + i k) · S(‖wi⊥ + wo⊥‖²),     S(x) = 1 / (1 + B x)^C,

    with F the exact unpolarized Fresnel reflectance of the complex index η + i k (:func:`gonio.brdf.fresnel.conductor`;
    Cook & Torrance 1982 appendix) and the rest as :class:`gonio.brdf.abc.ABCSmooth`. The index is parameterized by
    what it does (:func:`gulbrandsen_index`): ``f0`` = F(0), bounded to a metal's range [:data:`METAL_F0_MIN`,
    :data:`F0_MAX`], and ``edge``, how flat F stays towards grazing. A (per channel) carries the colour and the lobe's
    scale (module docstring: A·albedo(B, C) ≤ 1 is the specular scale), B and C the shape; one index for R, G, B (the
    colour is in A). Not normalized: fits check the albedo.

    Parameters
    ----------
    kd : float or 3 floats
        Diffuse albedo in [0, 1].
    A : float or 3 floats
        Lobe scale (≥ 0, 1/sr).
    B, C : float
        Lobe sharpness in [1e-2, 1e8] and fall-off exponent in [1e-3, 50].
    f0 : float
        The conductor's normal-incidence reflectance, in [0.5, 0.999].
    edge : float
        Gulbrandsen's edge tint g in [0, 1] (0: the dielectric of that F(0), k = 0, whose F dips before grazing;
        1: the lowest η, whose F rises soonest towards 1).
    """

    name = "abc-smooth-conductor"
    PARAMS = {
        "kd": ABCSmooth.PARAMS["kd"],
        "A": ABCSmooth.PARAMS["A"],
        "B": ABCSmooth.PARAMS["B"],
        "C": ABCSmooth.PARAMS["C"],
        "f0": Param("scalar", METAL_F0_MIN, F0_MAX, 0.8, doc="the conductor's normal-incidence reflectance F(0)"),
        "edge": Param("scalar", 0.0, 1.0, 0.5, doc="edge tint g of Gulbrandsen 2014 (the shape of F towards grazing)"),
    }
    energy_conserving = False

    def index(self) -> tuple[float, float]:
        """The complex index ``(eta, k)`` of the fitted conductor (:func:`gulbrandsen_index`)."""
        eta, k = gulbrandsen_index(self.f0, self.edge)
        return float(eta), float(k)

    def _lobes(self):
        eta, k = self.index()
        return self.kd / np.pi, [Lobe(abc_smooth_conductor_spec, (self.B, self.C, eta, k), self.A)]
