"""Precomputed-geometry kernels of the models for real measurements (:mod:`gonio.brdf.abc`), registered in
:data:`gonio.fit.kernels.KERNELS` (same contract: the colour basis of the model from geometry cached on the
data; equality with the model's ``eval`` is a test, tests/fit/test_real_data.py)."""

from __future__ import annotations

import numpy as np

from gonio.brdf.abc import abc_fresnel, abc_s_core, abc_smooth_x
from gonio.brdf.abc_conductor import abc_conductor_fresnel, gulbrandsen_index


def _projected_x(data) -> np.ndarray:
    """‖wi⊥ + wo⊥‖² (:func:`gonio.brdf.abc.abc_smooth_x` of the data's pair geometry), cached per dataset."""
    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "abc_x" not in cache:
        cache["abc_x"] = abc_smooth_x(data.pair)
    return cache["abc_x"]


def _fresnel(data, eta: float, k: float | None = None) -> np.ndarray:
    """Fresnel reflectance at θd, kept for the last index: the exact dielectric one of η
    (:func:`gonio.brdf.abc.abc_fresnel`), or with ``k`` the conductor's of η + i k
    (:func:`gonio.brdf.abc_conductor.abc_conductor_fresnel`)."""
    cache = data.__dict__.setdefault("_kernel_cache", {})
    key = (eta, k)
    hit = cache.get("abc_fresnel")
    if hit is None or hit[0] != key:
        f = abc_fresnel(data.pair, eta) if k is None else abc_conductor_fresnel(data.pair, eta, k)
        hit = cache["abc_fresnel"] = (key, f)
    return hit[1]


def abc_smooth(data, layout, shape):
    """Löw et al. 2012's smooth-surface ABC model (:class:`gonio.brdf.abc.ABCSmooth`): bases kd → 1/π,
    A → S(‖wi⊥ + wo⊥‖²; B, C) · F(θd; η) with S(x) = 1/(1 + B x)^C (their §4, eq. 7): the factors of the
    model's lobe :func:`gonio.brdf.abc.abc_smooth_spec`, F kept for the last η. With ``f0`` and ``edge``
    (:class:`gonio.brdf.abc_conductor.ABCSmoothConductor`) F is the conductor's of their index η + i k."""
    p = {**layout.fixed, **shape}
    if "edge" in p:  # the conductor's index from (f0, edge) (gonio.brdf.abc_conductor.gulbrandsen_index)
        eta, k = (float(v) for v in gulbrandsen_index(float(p["f0"]), float(p["edge"])))
    else:
        eta, k = float(p["eta"]), None
    s = abc_s_core(_projected_x(data), float(p["B"]), float(p["C"])) * _fresnel(data, eta, k)
    basis = {"kd": np.full(len(data), 1.0 / np.pi), "A": s}
    offset = None
    for name in ("kd", "A"):
        if name in layout.fixed and np.any(np.asarray(layout.fixed[name]) != 0):
            b = basis[name][:, None]
            offset = (0.0 if offset is None else offset) + np.asarray(layout.fixed[name]) * b
    return offset, [basis[name] for name in layout.colour]


def abc_smooth_albedo(B: float, C: float) -> float:
    """Directional albedo at normal incidence of the lobe S(x) = 1/(1 + B x)^C of :class:`gonio.brdf.abc.ABCSmooth`
    with F = 1 (a perfect reflector): at θi = 0, x = sin²θo, and with u = sin²θo (du = 2 sinθo cosθo dθo)
    ∫ S cos θo dω = π ∫₀¹ (1 + B u)^−C du = π (1 − (1 + B)^(1−C)) / (B (C − 1)) (π ln(1 + B)/B at C = 1)."""
    if abs(C - 1.0) < 1e-9:
        return float(np.pi * np.log1p(B) / B)
    return float(np.pi * -np.expm1((1.0 - C) * np.log1p(B)) / (B * (C - 1.0)))


def _abc_smooth_hi(layout, shape) -> np.ndarray | None:
    """Upper bound of the colours of :func:`abc_smooth`: A ≤ 1/albedo(B, C) (:func:`abc_smooth_albedo`), so the
    lobe reflects at most all the light before Fresnel's F ≤ 1 (energy conservation of the lobe; without it the
    unnormalized A lets a dielectric F of 0.04 stand in for a metal's reflectance, issue 29); kd ≤ 1 as declared."""
    if "A" not in layout.colour:
        return None
    p = {**layout.fixed, **shape}
    hi = np.array(layout.colour_hi, dtype=np.float64)
    hi[layout.colour.index("A")] = 1.0 / abc_smooth_albedo(float(p["B"]), float(p["C"]))
    return hi


abc_smooth.supports = lambda L: set(L.colour) <= {"kd", "A"}
abc_smooth.colour_hi = _abc_smooth_hi
abc_smooth.colour_hi_reason = "the lobe's albedo 1"
KERNELS_ABC = {"abc-smooth": abc_smooth, "abc-smooth-conductor": abc_smooth}


def conductor_note(params: dict) -> str:
    """What a fitted :class:`gonio.brdf.abc_conductor.ABCSmoothConductor` means physically (its module docstring): the
    conductor's index and F(0), and the specular scale A·albedo(B, C) — the fraction of the light the lobe would
    reflect from a perfect mirror of the same roughness, below 1 by what the surface loses beyond the conductor's
    Fresnel (or the table's absolute calibration)."""
    eta, k = (float(v) for v in gulbrandsen_index(float(params["f0"]), float(params["edge"])))
    scale = np.asarray(params["A"], dtype=np.float64) * abc_smooth_albedo(float(params["B"]), float(params["C"]))
    return (f"a conductor's Fresnel: index {eta:.3g} + {k:.3g}i (Gulbrandsen 2014 from F(0) {float(params['f0']):.3g}, "
            f"edge tint {float(params['edge']):.3g}); specular scale A x the lobe's albedo "
            f"{'/'.join(f'{v:.3g}' for v in scale)} (1: every bit of light a mirror of this roughness would reflect; "
            f"the lobe reflects that times F)")


#: A note every fit of these models carries (:func:`gonio.fit.fit.fit`), by model name.
FIT_NOTES = {"abc-smooth-conductor": conductor_note}
