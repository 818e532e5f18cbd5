"""Mitsuba 3's ``roughplastic`` plugin by its published formulas, for exporting a diffuse term under one
dielectric (f0 < 1) microfacet lobe (:mod:`gonio.io.mitsuba`).

Mitsuba 3 ``src/bsdfs/roughplastic.cpp`` (W. Jakob et al.; its BSDF ``eval`` divided by cos θo):

    f = ks · F(wi·h; η) D(h) G(wi, wo) / (4 cos θi cos θo)
        + ρ / (1 − R_int) · t(cos θi) t(cos θo) / (π η²)                          (nonlinear = false)

with the exact dielectric Fresnel reflectance F (:func:`gonio.brdf.fresnel.dielectric`), Walter et al.
2007's D and separable Smith G (gonio's microfacet lobe with F = 1: tests/brdf/test_reference.py checks it
against Mitsuba 3's values), t(μ) the transmittance of the rough interface tabulated at
μᵢ = max(10⁻⁶, i/63), i = 0..63, and linearly interpolated, and R_int = 2 · mean over the same μᵢ of
μᵢ R(μᵢ; 1/η) (the internal reflectance), R(μ; η) the directional albedo of the specular lobe alone (ks = 1).
t(μ) is the single-scattering transmittance of the rough dielectric (Mitsuba 3 ``eval_transmittance``,
``include/mitsuba/render/microfacet.h``, used by ``roughplastic.cpp`` since it replaced 1 − R(μ; η): the two
differ by the energy the single-scattering microfacet model loses, up to ~30 % of the diffuse term at grazing
angles for α ~ 0.3; found by QA against mitsuba 3.9.1), :func:`lobe_transmittance`. Mitsuba computes R and t
by its own quadratures (``eval_reflectance``, ``eval_transmittance``: visible-normal samples at Gauss–Legendre
nodes); here they are tensor Gauss–Legendre quadratures over the microfacet normal (:func:`lobe_albedo`,
:func:`lobe_transmittance`), which agree with fine Monte Carlo estimates to ~10⁻⁴ — far below the errors of
an approximate export, which are what this evaluation measures.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["lobe_albedo", "lobe_transmittance", "roughplastic_tables", "roughplastic_eval", "roughplastic_dict", "RES"]

#: Mitsuba's MI_ROUGH_TRANSMITTANCE_RES.
RES = 64


def _lobe(alpha: float, distribution: str):
    from gonio.brdf import make

    return make("microfacet", kd=0.0, ks=1.0, alpha=alpha, f0=1.0, distribution=distribution)


def lobe_albedo(mu: np.ndarray, eta: float, alpha: float, distribution: str = "ggx", n: int = 48) -> np.ndarray:
    """R(μ) = ∫ F(wi·h; η) D G / (4 cos θi cos θo) cos θo dωo for wi at cos θi = μ (φ = 0), by Gauss–Legendre
    quadrature over the half vector: dωo = 4 (wo·h) dωh, tan θh = α s with s = x/(1 − x), x ∈ (0, 1)
    (n nodes), and φh over [0, 2π) (2n nodes)."""
    from gonio.brdf.fresnel import dielectric

    mu = np.atleast_1d(np.asarray(mu, dtype=np.float64))
    h, W = _normals(alpha, n)
    lobe = _lobe(alpha, distribution)
    out = np.empty(mu.size)
    for j, m in enumerate(mu):
        wi = np.array([np.sqrt(max(1.0 - m * m, 0.0)), 0.0, m])
        c = h @ wi
        wo = 2.0 * c[:, None] * h - wi
        ok = (c > 0) & (wo[:, 2] > 0)
        f = lobe.eval(np.broadcast_to(wi, wo[ok].shape), wo[ok])[:, 0] * dielectric(c[ok], eta)
        out[j] = float(np.sum(f * wo[ok, 2] * 4.0 * c[ok] * W[ok]))
    return out


def _normals(alpha: float, n: int):
    """Microfacet normals ``m`` (N, 3) and quadrature weights of dω_m over the upper hemisphere: Gauss–Legendre in
    x ∈ (0, 1) with tan θm = α x/(1 − x) (n nodes) times the midpoint rule in φm (2n nodes)."""
    x, wx = np.polynomial.legendre.leggauss(n)
    x, wx = 0.5 * (x + 1.0), 0.5 * wx
    s = x / (1.0 - x)
    th = np.arctan(alpha * s)
    dth = alpha / (1.0 + (alpha * s) ** 2) / (1.0 - x) ** 2 * wx
    ph = (np.arange(2 * n) + 0.5) * (np.pi / n)
    TH, PH = np.meshgrid(th, ph, indexing="ij")
    W = (dth[:, None] * np.sin(TH)) * (np.pi / n)
    m = np.stack([np.sin(TH) * np.cos(PH), np.sin(TH) * np.sin(PH), np.cos(TH)], axis=-1).reshape(-1, 3)
    return m, W.reshape(-1)


def lobe_transmittance(mu: np.ndarray, eta: float, alpha: float, distribution: str = "ggx", n: int = 48) -> np.ndarray:
    """t(μ): the fraction of light arriving at cos θi = μ that a rough dielectric interface of relative index η
    transmits in single scattering (Mitsuba 3 ``eval_transmittance``, ``include/mitsuba/render/microfacet.h``; the
    expectation over visible normals of (1 − F(wi·m; η)) G1(wt, m), wt the direction refracted at m):

        t(μ) = ∫ (1 − F(wi·m; η)) G1(wt, m) G1(wi, m) max(0, wi·m) D(m) / μ dω_m

    with Walter et al. 2007's refraction wt = (η_ti (wi·m) − cos θt) m − η_ti wi, η_ti = 1/η,
    cos θt = √(1 − η_ti² (1 − (wi·m)²)) (eq. 40), D and the Smith G1 of :mod:`gonio.brdf.microfacet` (the same
    functions as Mitsuba's), F the exact dielectric Fresnel reflectance (1 under total internal reflection), by
    quadrature over the microfacet normal (:func:`_normals`)."""
    from gonio.brdf.fresnel import dielectric
    from gonio.brdf.microfacet import distribution_d, smith_g1

    mu = np.atleast_1d(np.asarray(mu, dtype=np.float64))
    m, W = _normals(alpha, n)
    D = distribution_d(distribution, m, alpha)
    out = np.empty(mu.size)
    for j, u in enumerate(mu):
        wi = np.broadcast_to([np.sqrt(max(1.0 - u * u, 0.0)), 0.0, u], m.shape)
        c = np.sum(wi * m, axis=-1)
        eta_ti = 1.0 / eta
        cos_t2 = 1.0 - eta_ti * eta_ti * (1.0 - c * c)
        ok = (c > 0) & (cos_t2 > 0)
        cos_t = np.sqrt(np.maximum(cos_t2, 0.0))
        wt = (eta_ti * c - cos_t)[:, None] * m - eta_ti * wi
        g = smith_g1(distribution, wt, m, alpha) * smith_g1(distribution, wi, m, alpha)
        f = (1.0 - dielectric(c, eta)) * g * np.maximum(c, 0.0) * D / u
        out[j] = float(np.sum(np.where(ok & (wt[:, 2] < 0), f, 0.0) * W))
    return out


@functools.lru_cache(maxsize=32)
def roughplastic_tables(eta: float, alpha: float, distribution: str = "ggx") -> tuple[np.ndarray, float]:
    """``(t (RES,), R_int)``: Mitsuba's external transmittance table and internal reflectance (module docstring)."""
    mu = np.maximum(1e-6, np.arange(RES) / (RES - 1))
    t = lobe_transmittance(mu, eta, alpha, distribution)
    r_int = 2.0 * float(np.mean(lobe_albedo(mu, 1.0 / eta, alpha, distribution) * mu))
    return t, r_int


def _lerp(table: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Mitsuba's ``lerp_gather``: linear interpolation in a table over [0, 1]."""
    x = np.asarray(x, dtype=np.float64) * (table.size - 1)
    i = np.minimum(np.maximum(x, 0).astype(int), table.size - 2)
    w1 = x - i
    return (1.0 - w1) * table[i] + w1 * table[i + 1]


def roughplastic_eval(d: dict, wi, wo) -> np.ndarray:
    """f (1/sr, RGB) of a ``roughplastic`` dictionary (module docstring), 0 below the horizon."""
    from gonio.brdf.fresnel import dielectric

    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    eta, alpha, dist = float(d["int_ior"]) / float(d.get("ext_ior", 1.0)), float(d["alpha"]), d["distribution"]
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    F = dielectric(np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0), eta)
    spec = _lobe(alpha, dist).eval(wi, wo) * F[..., None] * np.asarray(d["specular_reflectance"]["value"])
    t, r_int = roughplastic_tables(eta, alpha, dist)
    rho = np.asarray(d["diffuse_reflectance"]["value"])
    above = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    ti, to = _lerp(t, np.clip(wi[..., 2], 0, 1)), _lerp(t, np.clip(wo[..., 2], 0, 1))
    diff = (rho / (1.0 - r_int)) * ((ti * to) / (np.pi * eta * eta))[..., None]
    return np.where(above[..., None], spec + diff, 0.0)


def roughplastic_dict(albedo, ks, f0: float, alpha: float, distribution: str, wi, wo) -> tuple[dict, list[str]]:
    """The ``roughplastic`` closest to ``albedo/π + ks·lobe(f0)``: η from the normal reflectance
    (f0 = ((η − 1)/(η + 1))², so η = (1 + √f0)/(1 − √f0)), the same distribution, α and ks, and the diffuse
    reflectance ρ that matches albedo/π in least squares over the pairs ``wi``, ``wo`` (cosine-weighted),
    clipped to [0, 1]. Returns the dictionary and what it changes."""
    sq = np.sqrt(np.clip(f0, 1e-8, 1.0 - 1e-8))
    eta = float((1 + sq) / (1 - sq))
    t, r_int = roughplastic_tables(eta, float(alpha), distribution)
    g = _lerp(t, wi[:, 2]) * _lerp(t, wo[:, 2]) * wi[:, 2] / (eta * eta * (1.0 - r_int))  # diffuse shape × cos
    c = wi[:, 2]
    scale = float(np.sum(g * c) / np.sum(g * g))  # min Σ (albedo·cos − ρ·g)²
    rho = np.asarray(albedo, dtype=np.float64) * scale
    reasons = ["roughplastic: exact dielectric Fresnel in place of Schlick's; its diffuse term is dimmed "
               "towards grazing by the coating's transmittance (a Lambert term is not)"]
    if np.any(rho > 1):
        reasons.append("diffuse reflectance clipped to 1")
    d = {"type": "roughplastic", "distribution": distribution, "alpha": float(alpha), "int_ior": eta,
         "ext_ior": 1.0, "nonlinear": False,
         "diffuse_reflectance": {"type": "rgb", "value": [float(x) for x in np.clip(rho, 0, 1)]},
         "specular_reflectance": {"type": "rgb", "value": [float(x) for x in np.broadcast_to(ks, (3,))]}}
    return d, reasons
