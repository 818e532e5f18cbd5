"""pbrt-v4's ``coateddiffuse`` material evaluated by its own formulas, for exporting plastics: the expected
value of its stochastic BSDF, and the parameters that bring it closest to a model.

pbrt-v4 (Pharr, Jakob, Humphreys, *Physically Based Rendering*, 4th ed., §14.3; ``src/pbrt/bxdfs.h``
``LayeredBxDF<DielectricBxDF, DiffuseBxDF, true>``, ``bxdfs.cpp`` ``DielectricBxDF``, ``util/scattering.h``
``TrowbridgeReitzDistribution``, ``materials.cpp`` ``CoatedDiffuseMaterial``) renders a rough dielectric
interface (index η, Trowbridge-Reitz α) over a Lambertian base of reflectance R, a slab of ``thickness`` t
between them that attenuates by Tr(w) = exp(−t/|cos θ_w|) per crossing (``albedo`` 0: no medium scattering),
and estimates ``f(wo, wi)`` by one random walk (``nsamples`` 1) of at most ``maxdepth`` = 10 events. With a
Lambertian base the walk's expected value has a closed form (every path leaves the base cosine-distributed):

    f = f_R(wo, wi) + R/π · E_in(wo) · Σ_{k=0}^{K−1} (R r)^k · E_out(wi),        K = 5 base hits in 10 events

* f_R = D(h) G(wo, wi) F(wo·h; η) / (4 cos θi cos θo): the interface's reflection (``DielectricBxDF::f``), with
  pbrt's D, height-correlated G = 1/(1 + Λ(wo) + Λ(wi)), Λ(w) = (√(1 + α² tan²θ) − 1)/2 and the exact
  dielectric Fresnel reflectance (``FrDielectric``);
* E_in(wo) = E_{m∼D_wo}[(1 − F) G(wo, wt)/G1(wo) · Tr(wt)] / η²: the transmission into the slab as
  ``Sample_f(wo, Transmission)`` estimates it (visible normals m, wt refracted at m; radiance mode: /η²);
* r = E_{u∼cos}[Tr(u) E_{m∼D_u}[F G(−u, w')/G1(u) Tr(w')]]: what a cosine-distributed flux from the base
  brings back to it after reflecting inside the interface (total internal reflection included);
* E_out(wi) = E_{m∼D_wi}[(1 − F) G/G1 · Tr(d) · (w_A(d) + P(wi) w_B(d))]: the way out as the walk's two
  next-event estimates weight it: w_A, w_B its power-heuristic weights (strategy A: the direction d sampled
  from wi, once per walk; B: the base's cosine sample evaluated through the interface, weighted with
  ``exitInterface.PDF(-w, wi)``, the density of sampling wi from d — not of d from wi, so w_A + w_B is not 1:
  this is pbrt's estimator's expectation, not the layered BSDF's exact value), P(wi) the probability that the
  walk's sample from wi is valid (refracted into the slab; the walk is dropped otherwise).

Each expectation is a quadrature over the microfacet normal (Gauss–Legendre in tan θm/α, midpoint in φm) at
:data:`N_MU` cosines, interpolated linearly. ``tests/io/test_pbrt_coateddiffuse.py`` runs a port of pbrt-v4's
walk (``LayeredBxDF::f``, Monte Carlo, fixed seed) and checks this expectation against it.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["coated_eval", "coated_tables", "fit_coated", "fr_dielectric", "MAX_DEPTH", "N_MU", "coated_text"]

#: pbrt-v4's default ``maxdepth`` of ``coateddiffuse`` (written into the file, so the evaluation holds).
MAX_DEPTH = 10
#: Cosines at which the walk's expectations are tabulated (denser towards grazing), and the Gauss–Legendre
#: order of the microfacet-normal quadrature: those of a reported error (the fit uses :data:`COARSE`; the two
#: differ by ~6e-4 relative, the finer from one twice as fine by ~2e-4).
N_MU, N_NORMALS = 48, 24
COARSE = (24, 12)


def _mu_nodes(n_mu: int) -> np.ndarray:
    return np.sin(0.5 * np.pi * (np.arange(n_mu) + 0.5) / n_mu) ** 1.5


def fr_dielectric(cos_i, eta: float) -> np.ndarray:
    """pbrt-v4's ``FrDielectric``: unpolarized Fresnel reflectance of a dielectric interface of relative index
    ``eta``; a negative cosine is the inside (η → 1/η); 1 under total internal reflection."""
    c = np.clip(np.asarray(cos_i, dtype=np.float64), -1.0, 1.0)
    e = np.where(c < 0, 1.0 / eta, eta)
    c = np.abs(c)
    sin2_t = (1.0 - c * c) / (e * e)
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    r_parl = (e * c - cos_t) / (e * c + cos_t)
    r_perp = (c - e * cos_t) / (c + e * cos_t)
    return np.where(sin2_t >= 1.0, 1.0, (r_parl ** 2 + r_perp ** 2) / 2.0)


def _lam(w, alpha: float) -> np.ndarray:
    """Λ(w) of the isotropic Trowbridge-Reitz distribution (``TrowbridgeReitzDistribution::Lambda``)."""
    c2 = w[..., 2] ** 2
    t2 = (1.0 - c2) / np.maximum(c2, 1e-300)
    return (np.sqrt(1.0 + alpha * alpha * t2) - 1.0) / 2.0


def _d(m, alpha: float) -> np.ndarray:
    """D(m) (``TrowbridgeReitzDistribution::D``)."""
    c2 = m[..., 2] ** 2
    t2 = (1.0 - c2) / np.maximum(c2, 1e-300)
    return 1.0 / (np.pi * alpha * alpha * c2 * c2 * (1.0 + t2 / (alpha * alpha)) ** 2)


def _normals(alpha: float, n: int):
    from gonio.io.mitsuba_plastic import _normals as quadrature

    return quadrature(alpha, n)


def _refract(w, m, eta: float):
    """pbrt-v4's ``Refract(w, m, eta)``: the refracted direction and whether it exists (no total internal
    reflection); ``w`` on either side of ``m``."""
    c = np.sum(w * m, axis=-1)
    inside = c < 0
    e = np.where(inside, 1.0 / eta, eta)[..., None]
    n = np.where(inside[..., None], -m, m)
    c = np.abs(c)[..., None]
    sin2_t = (1.0 - c * c) / (e * e)
    ok = sin2_t[..., 0] < 1.0
    cos_t = np.sqrt(np.maximum(1.0 - sin2_t, 0.0))
    return -w / e + (c / e - cos_t) * n, ok


def _pdf_t(wo, wi, m, alpha: float, eta: float) -> np.ndarray:
    """``DielectricBxDF::PDF(wo, wi, Transmission)``: the density of sampling ``wi`` (other side) from ``wo``
    through the normal ``m`` (visible normals of wo times dm/dwi)."""
    etap = np.where(wo[..., 2] > 0, eta, 1.0 / eta)
    wo_m, wi_m = np.sum(wo * m, axis=-1), np.sum(wi * m, axis=-1)
    g1 = 1.0 / (1.0 + _lam(wo, alpha))
    vis = g1 / np.abs(wo[..., 2]) * _d(m, alpha) * np.abs(wo_m)
    return vis * np.abs(wi_m) / (wi_m + wo_m / etap) ** 2


def _power(f, g):
    return f * f / np.maximum(f * f + g * g, 1e-300)


@functools.lru_cache(maxsize=64)
def coated_tables(alpha: float, eta: float, thickness: float, n_mu: int = N_MU,
                  n_normals: int = N_NORMALS) -> tuple[np.ndarray, np.ndarray, float]:
    """``(E_in, E_out)`` at ``n_mu`` cosines (:func:`_mu_nodes`) and ``r`` (module docstring), for one
    interface and slab."""
    m, W = _normals(alpha, n_normals)
    D = _d(m, alpha)
    nodes = _mu_nodes(n_mu)
    mu = nodes[:, None]
    w = np.broadcast_to(np.stack([np.sqrt(1.0 - nodes ** 2), 0.0 * nodes, nodes], axis=-1)[:, None, :],
                        (n_mu, len(m), 3))
    cos_wm = np.sum(w * m, axis=-1)
    g1 = 1.0 / (1.0 + _lam(w, alpha))
    dens = np.where(cos_wm > 0, g1 / mu * D * cos_wm, 0.0) * W  # visible normals of w, as quadrature weights

    def tr(v):
        return np.exp(-thickness / np.maximum(np.abs(v[..., 2]), 1e-300))

    # the way in and out: refraction at m, valid when the refracted direction is below
    d, ok = _refract(w, m, eta)
    valid = ok & (d[..., 2] < 0) & (cos_wm > 0)
    T = 1.0 - fr_dielectric(cos_wm, eta)
    gg = 1.0 / (1.0 + _lam(w, alpha) + _lam(d, alpha))
    through = np.where(valid, T * gg / g1 * tr(d), 0.0)
    e_in = np.sum(dens * through, axis=1) / (eta * eta)
    with np.errstate(divide="ignore", invalid="ignore"):
        p_a = _pdf_t(w, d, m, alpha, eta)  # strategy A: d sampled from wi
        p_e = _pdf_t(d, w, m, alpha, eta)  # pbrt's weight for B: wi sampled from d
    p_d = np.abs(d[..., 2]) / np.pi  # the base's cosine density of the same direction
    p_valid = np.sum(dens * valid, axis=1)
    weight = _power(p_a, p_d) + p_valid[:, None] * _power(p_d, p_e)
    e_out = np.sum(dens * np.where(valid, through * np.nan_to_num(weight), 0.0), axis=1)
    # back to the base: a cosine-distributed u reflected inside the interface (wo = -u below it)
    wr = 2.0 * cos_wm[..., None] * m - w  # reflection of u about m (mirror symmetric to -u's)
    back = (cos_wm > 0) & (wr[..., 2] > 0)
    F_in = fr_dielectric(-cos_wm, eta)  # seen from inside: 1/η, total internal reflection
    g_r = 1.0 / (1.0 + _lam(w, alpha) + _lam(wr, alpha))
    rho_in = np.sum(dens * np.where(back, F_in * g_r / g1 * tr(wr), 0.0), axis=1)
    # r = ∫ Tr(u) ρ_in(u) cos θu/π dω = 2 ∫_0^1 Tr(μ) ρ_in(μ) μ dμ, on the same nodes (trapezoid in μ)
    f = np.exp(-thickness / nodes) * rho_in * nodes
    xs = np.concatenate([[0.0], nodes, [1.0]])
    fs = np.concatenate([[0.0], f, [f[-1]]])
    r = float(2.0 * np.trapezoid(fs, xs))
    return e_in, e_out, r


def _series(R, r: float, depth: int = MAX_DEPTH) -> np.ndarray:
    """Σ_{k<K} (R r)^k with K = ⌈depth/2⌉ base hits in ``depth`` events."""
    x = np.asarray(R, dtype=np.float64) * r
    return sum(x ** k for k in range((depth + 1) // 2))


def coated_eval(p: dict, wi, wo) -> np.ndarray:
    """The expected f (1/sr, RGB) of ``coateddiffuse`` with ``p = {"reflectance", "roughness", "eta",
    "thickness"}`` (albedo 0, g 0, maxdepth :data:`MAX_DEPTH`, nsamples 1), ``wi`` the light's direction and
    ``wo`` the camera's (pbrt's ``f(wo, wi)``), 0 below the horizon (module docstring)."""
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    alpha, eta = float(p["roughness"]), float(p["eta"])
    if alpha < 1e-3:  # EffectivelySmooth: pbrt's interface is a perfect mirror, f_R and this walk do not apply
        raise ValueError(f"roughness {alpha:g} < 1e-3: pbrt-v4 renders a smooth (specular) coating")
    spec, shape = _specular(wi, wo, alpha, eta), _diffuse_shape(wi, wo, alpha, eta, float(p["thickness"]))
    R = np.clip(np.asarray(p["reflectance"], dtype=np.float64), 0.0, 1.0)
    r = coated_tables(alpha, eta, float(p["thickness"]))[2]
    f = spec[..., None] + (R * _series(R, r) / np.pi) * shape[..., None]
    above = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    return np.where(above[..., None], np.nan_to_num(f), 0.0)


def _specular(wi, wo, alpha: float, eta: float) -> np.ndarray:
    """f_R (module docstring): ``DielectricBxDF::f`` for a reflected pair."""
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = 1.0 / (1.0 + _lam(wo, alpha) + _lam(wi, alpha))
        return _d(h, alpha) * g * fr_dielectric(np.sum(wo * h, axis=-1), eta) / np.abs(4.0 * wi[..., 2] * wo[..., 2])


def _diffuse_shape(wi, wo, alpha: float, eta: float, thickness: float, res=(N_MU, N_NORMALS)) -> np.ndarray:
    """E_in(wo) E_out(wi) (module docstring), interpolated in the tables."""
    e_in, e_out, _ = coated_tables(alpha, eta, thickness, *res)
    xs = np.concatenate([[0.0], _mu_nodes(res[0]), [1.0]])

    def at(table, mu):
        return np.interp(np.clip(mu, 0.0, 1.0), xs, np.concatenate([[0.0], table, [table[-1]]]))

    return at(e_in, wo[..., 2]) * at(e_out, wi[..., 2])


def _reflectance_for(c: np.ndarray, r: float) -> np.ndarray:
    """The R in [0, 1] with R Σ_k (R r)^k = c (increasing in R), by bisection; c beyond R = 1 gives 1."""
    lo, hi = np.zeros_like(c), np.ones_like(c)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        low = mid * _series(mid, r) < c
        lo, hi = np.where(low, mid, lo), np.where(low, hi, mid)
    return 0.5 * (lo + hi)


def fit_coated(model, alpha0: float, eta0: float, n: int = 2048, seed: int = 271828):
    """The ``coateddiffuse`` parameters closest to ``model``: the cosine-weighted relative RMS difference over
    ``n`` cosine-distributed pairs (:func:`gonio.io.approx.direction_pairs`, a seed apart from the pairs the
    error is reported on) minimised over roughness α and η (Nelder–Mead from the model's own α and the η of its
    f0), the reflectance solved per channel for each (linear least squares in R Σ (R r)^k, then inverted).

    ``thickness`` is 0 (pbrt: no absorption, Tr = 1) and ``albedo`` 0: with albedo 0 the slab only absorbs,
    which dims the base towards grazing, where pbrt's coating already dims it more than a Lambert term is
    (fitted as a third parameter it went to 0 for every plastic tried); a scattering slab (albedo > 0) has no
    closed form here. Returns ``(params, notes)``: notes say a value on its bound."""
    from scipy.optimize import minimize

    from gonio.io.approx import direction_pairs

    wi, wo = direction_pairs(n, seed)
    want = model.eval(wi, wo)

    def solve(x):
        alpha = float(np.clip(np.exp(x[0]), 1e-3, 1.0))
        eta = float(np.clip(1.0 + np.exp(x[1]), 1.0 + 1e-3, 4.0))
        spec, shape = _specular(wi, wo, alpha, eta), _diffuse_shape(wi, wo, alpha, eta, 0.0, COARSE)
        spec, shape = np.nan_to_num(spec), np.nan_to_num(shape)
        rest = want - spec[:, None]
        c = np.maximum(np.sum(rest * shape[:, None], axis=0) / max(float(np.sum(shape * shape)), 1e-300), 0.0)
        r = coated_tables(alpha, eta, 0.0, *COARSE)[2]
        R = _reflectance_for(c * np.pi, r)  # diffuse = (R Σ (R r)^k / π) · shape
        f = spec[:, None] + (R * _series(R, r) / np.pi) * shape[:, None]
        err = float(np.sqrt(np.sum((f - want) ** 2)) / max(np.sqrt(np.sum(want ** 2)), 1e-300))
        return err, {"reflectance": R, "roughness": alpha, "eta": eta, "thickness": 0.0}

    x0 = [np.log(max(alpha0, 1e-3)), np.log(max(eta0 - 1.0, 1e-3))]
    best = minimize(lambda x: solve(x)[0], x0, method="Nelder-Mead",
                    options={"xatol": 1e-3, "fatol": 1e-6, "maxfev": 120})
    _, params = solve(best.x)
    notes = []
    if params["roughness"] <= 1e-3 or params["roughness"] >= 1.0:
        notes.append(f"coateddiffuse roughness {params['roughness']:.3g} on its bound (1e-3 .. 1)")
    if np.any(params["reflectance"] >= 1.0 - 1e-6):
        notes.append("coateddiffuse reflectance clipped to 1")
    if params["eta"] <= 1.0 + 1e-3 or params["eta"] >= 4.0:
        notes.append(f"coateddiffuse eta {params['eta']:.4g} on its bound (1.001 .. 4)")
    return params, notes


def coated_text(p: dict, name: str) -> str:
    """The ``MakeNamedMaterial`` line of ``coateddiffuse`` with every parameter the evaluation assumes spelled
    out (pbrt-v4 ``CoatedDiffuseMaterial::Create``: ``roughness`` as α with ``remaproughness`` false, ``float
    eta``, ``thickness``, ``albedo`` 0, ``g`` 0, ``maxdepth``, ``nsamples``)."""
    rgb = " ".join(f"{float(x):.9g}" for x in np.broadcast_to(p["reflectance"], (3,)))
    return (f'MakeNamedMaterial "{name}" "string type" "coateddiffuse" "rgb reflectance" [ {rgb} ]'
            f' "float roughness" {p["roughness"]:.9g} "bool remaproughness" false "float eta" {p["eta"]:.9g}'
            f' "float thickness" {p["thickness"]:.9g} "rgb albedo" [ 0 0 0 ] "float g" 0'
            f' "integer maxdepth" {MAX_DEPTH} "integer nsamples" 1')
