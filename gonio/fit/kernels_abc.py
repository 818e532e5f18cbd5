"""Precomputed-geometry kernels of the models for real measurements (:mod:`gonio.brdf.abc`), registered in
:data:`gonio.fit.kernels.KERNELS` (same contract: the colour basis of the model from geometry cached on the
data; equality with the model's ``eval`` is a test, tests/fit/test_real_data.py)."""

from __future__ import annotations

import numpy as np

from gonio.brdf.abc import abc_fresnel, abc_s_core, abc_smooth_x


def _projected_x(data) -> np.ndarray:
    """‖wi⊥ + wo⊥‖² (:func:`gonio.brdf.abc.abc_smooth_x` of the data's pair geometry), cached per dataset."""
    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "abc_x" not in cache:
        cache["abc_x"] = abc_smooth_x(data.pair)
    return cache["abc_x"]


def _fresnel(data, eta: float) -> np.ndarray:
    """Exact dielectric Fresnel reflectance at θd (:func:`gonio.brdf.abc.abc_fresnel`), kept for the last η."""
    cache = data.__dict__.setdefault("_kernel_cache", {})
    hit = cache.get("abc_fresnel")
    if hit is None or hit[0] != eta:
        hit = cache["abc_fresnel"] = (eta, abc_fresnel(data.pair, eta))
    return hit[1]


def abc_smooth(data, layout, shape):
    """Löw et al. 2012's smooth-surface ABC model (:class:`gonio.brdf.abc.ABCSmooth`): bases kd → 1/π,
    A → S(‖wi⊥ + wo⊥‖²; B, C) · F(θd; η) with S(x) = 1/(1 + B x)^C (their §4, eq. 7): the factors of the
    model's lobe :func:`gonio.brdf.abc.abc_smooth_spec`, F kept for the last η."""
    p = {**layout.fixed, **shape}
    s = abc_s_core(_projected_x(data), float(p["B"]), float(p["C"])) * _fresnel(data, float(p["eta"]))
    basis = {"kd": np.full(len(data), 1.0 / np.pi), "A": s}
    offset = None
    for k in ("kd", "A"):
        if k in layout.fixed and np.any(np.asarray(layout.fixed[k]) != 0):
            b = basis[k][:, None]
            offset = (0.0 if offset is None else offset) + np.asarray(layout.fixed[k]) * b
    return offset, [basis[k] for k in layout.colour]


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
KERNELS_ABC = {"abc-smooth": abc_smooth}
