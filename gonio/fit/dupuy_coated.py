"""Fitting the coated-conductor variant of the data-driven microfacet model (:class:`gonio.brdf.coated.Dupuy2015Coated`):
D tabulated as in Dupuy et al. 2015, the Fresnel factor ks · F(θd) of a conductor under a thin dielectric coat
(:func:`gonio.brdf.coated.thin_coat_fresnel`; Weidlich & Wilkie 2007).

As :mod:`gonio.fit.dupuy_conductor`: the table fit of :mod:`gonio.fit.dupuy`, then rounds of the Fresnel step and the
D step. The Fresnel step: the coat's index n (one for R, G, B) by a scan of [:data:`~gonio.brdf.coated.COAT_N_MIN`,
:data:`~gonio.brdf.coated.COAT_N_MAX`] and a bounded scalar search (Brent) around its best point (a later round: around
the last round's n) of the summed per-channel optimum;
per channel, kd and ks in closed form (variable projection, Golub & Pereyra 1973, on per-θd-bin sums:
:class:`gonio.fit.dupuy_conductor._Channel`) for every (F(0), edge tint, t) of a scan over metals only
(Gulbrandsen 2014, :func:`gonio.brdf.fresnel.gulbrandsen_index`, F(0) ≥ 0.5, edge tint ≥
:data:`~gonio.brdf.coated.BASE_EDGE_MIN`: k > 0) and the layer's transmittance t ∈ [0, 1],
then, in the last round, a bounded polish (L-BFGS-B) of the three. Standard uncertainties s² (JᵀJ)⁻¹ of
(kd, ks, η, k, t) per channel and n jointly, at the solution and conditional on the fitted D (Press et al., *Numerical
Recipes*, 3rd ed., §15.5); a parameter on a bound has none. t and the metal's index trade off along t F_c(0), the light
the metal sends back through the coat at normal incidence, which the fit's note prints.
"""

from __future__ import annotations

import time

import numpy as np

from gonio.brdf.coated import BASE_EDGE_MIN, COAT_N_MAX, COAT_N_MIN, Dupuy2015Coated, thin_coat_fresnel
from gonio.brdf.dupuy import N_NDF, N_FRESNEL, ndf_nodes, normalization
from gonio.brdf.fresnel import F0_MAX, METAL_F0_MIN, conductor, gulbrandsen_index
from gonio.fit.data import FitData
from gonio.fit.dupuy import IMAGE_WEIGHT, ITERATIONS, _inverse, _ndf_step, _weights, table_fit, unmeasured_note
from gonio.fit.dupuy_conductor import (ROUNDS, _Channel, _edge_of, bounded_difference, check_size, index_bounds,
                                       mark_bound, ndf_sigma)
from gonio.fit.losses import Loss
from gonio.fit.result import FitResult

__all__ = ["fit_dupuy_coated"]

#: The per-channel scan: F(0) in air × edge tint × the layer's round-trip transmittance t.
_F0S = np.linspace(METAL_F0_MIN, F0_MAX, 8)
_EDGES = np.linspace(BASE_EDGE_MIN, 1.0, 7)
_TS = np.concatenate([[0.0], np.geomspace(0.01, 1.0, 8)])
#: Coat indices of the scan that starts the bounded search of n, and the search's tolerance in n.
_NS = np.linspace(COAT_N_MIN, COAT_N_MAX, 6)
N_TOL = 3e-3
_NAMES = ("kd", "ks", "eta", "k", "t")


def _scan(cos, n: float, extra) -> np.ndarray:
    """The Fresnel factors of the scan at the bins' cos θd and coat index n, (bins, G·T + E): every (F(0), edge) of
    :data:`_F0S` × :data:`_EDGES` with every t of :data:`_TS` (the conductor evaluated once per (F(0), edge)), then the
    E points (η, k, t) of ``extra`` (3, E)."""
    r, g = (a.ravel() for a in np.meshgrid(_F0S, _EDGES, indexing="ij"))
    eta, k = gulbrandsen_index(r, g)
    f = thin_coat_fresnel(cos, n, eta[:, None], k[:, None], _TS[None, :]).reshape(cos.size, -1)
    if extra.shape[1]:
        f = np.concatenate([f, thin_coat_fresnel(cos, n, extra[0], extra[1], extra[2])], axis=1)
    return f


def _scan_point(j: int) -> np.ndarray:
    """(F(0), edge, t) of column ``j`` of :func:`_scan` (below G·T)."""
    a, b = divmod(j, _TS.size)
    r, g = divmod(a, _EDGES.size)
    return np.array([_F0S[r], _EDGES[g], _TS[b]])


def _one(ch: _Channel, n: float, u) -> tuple[float, float, float, float, float]:
    """``(objective, kd, ks, η, k)`` of one channel at (F(0), edge, t) = ``u`` and coat index n."""
    eta, k = gulbrandsen_index(float(np.clip(u[0], METAL_F0_MIN, F0_MAX)), float(np.clip(u[1], BASE_EDGE_MIN, 1.0)))
    f = thin_coat_fresnel(ch.cos, n, np.array([float(eta)]), np.array([float(k)]), np.array([float(np.clip(u[2], 0, 1))]))
    obj, kd, ks = ch.solve_fresnel(f)
    return float(obj[0]), float(kd[0]), float(ks[0]), float(eta), float(k)


def _channels_at(chans, n: float, x_prev, polish: bool) -> tuple[float, np.ndarray]:
    """``(summed objective, x (5, 3))`` at coat index n: per channel the best point of the scan (a previous solution
    ``x_prev`` joins it, when its F(0) is a metal's), and with ``polish`` the bounded L-BFGS-B refinement in
    (F(0), edge, t)."""
    extra = []
    if x_prev is not None:
        for c in range(3):
            r0 = float(conductor(np.ones(1), x_prev[2, c], x_prev[3, c])[0])
            if METAL_F0_MIN <= r0 <= F0_MAX:
                extra.append((c, np.array([r0, max(_edge_of(r0, x_prev[2, c]), BASE_EDGE_MIN), x_prev[4, c]]),
                              x_prev[2:5, c]))
    f = _scan(chans[0].cos, n, np.array([e[2] for e in extra]).T.reshape(3, -1))
    g = f.shape[1] - len(extra)
    total, x = 0.0, np.zeros((5, 3))
    for c, ch in enumerate(chans):
        mine = [i for i, e in enumerate(extra) if e[0] == c]
        cols = np.r_[np.arange(g), g + np.array(mine, dtype=int)]
        obj = ch.solve_fresnel(f[:, cols])[0]
        j = int(np.argmin(obj))
        u = _scan_point(j) if j < g else extra[mine[j - g]][1]
        if polish:
            from scipy.optimize import minimize

            bounds = [(METAL_F0_MIN, F0_MAX), (BASE_EDGE_MIN, 1.0), (0.0, 1.0)]
            res = minimize(lambda v: _one(ch, n, v)[0], u, method="L-BFGS-B", bounds=bounds, options={"maxiter": 40})
            if res.fun <= obj[j]:
                u = np.clip(res.x, [b[0] for b in bounds], [b[1] for b in bounds])
        val, kd, ks, e, kk = _one(ch, n, u)
        total += val
        x[:, c] = (kd, ks, e, kk, u[2])
    return total, x


def _fresnel_step(chans, x_prev, n_prev, polish: bool):
    """The coat index and the per-channel (kd, ks, η, k, t) (module docstring; the L-BFGS-B polish with ``polish``):
    ``(n, x (5, 3))``."""
    from scipy.optimize import minimize_scalar

    def total(n):
        return _channels_at(chans, float(n), x_prev, False)[0]

    ns = _NS if n_prev is None else np.array([n_prev])  # a later round searches near the last round's n
    vals = [total(n) for n in ns]
    j = int(np.argmin(vals))
    step = (_NS[1] - _NS[0]) * (1.0 if n_prev is None else 0.5)
    lo, hi = max(ns[j] - step, COAT_N_MIN), min(ns[j] + step, COAT_N_MAX)
    res = minimize_scalar(total, bounds=(lo, hi), method="bounded", options={"xatol": N_TOL})
    n = float(res.x) if res.fun <= vals[j] else float(ns[j])
    return n, _channels_at(chans, n, x_prev, polish)[1]


def _jacobian(cos_d, spec, w, x, n) -> np.ndarray:
    """∂(√w · model)/∂(kd, ks, η, k, t of each channel, n) stacked over the three channels: (3N, 16) (analytic in
    kd, ks; central differences in the rest, within their bounds)."""
    from gonio.brdf.dupuy import ETA_MAX, ETA_MIN, K_MAX

    N = len(cos_d)
    jac = np.zeros((3 * N, 16))
    bounds = ((ETA_MIN, ETA_MAX), (0.0, K_MAX), (0.0, 1.0))
    for c in range(3):
        sw = np.sqrt(w[:, c])
        rows = slice(c * N, (c + 1) * N)

        def fres(xc, nn):
            return thin_coat_fresnel(cos_d, nn, xc[2], xc[3], xc[4])

        f = fres(x[:, c], n)
        jac[rows, 5 * c] = sw / np.pi
        jac[rows, 5 * c + 1] = sw * f * spec
        scale = sw * x[1, c] * spec
        for i, (lo, hi) in zip((2, 3, 4), bounds):
            jac[rows, 5 * c + i] = bounded_difference(lambda v: fres(v, n), x[:, c], i, lo, hi,
                                                      1e-5 * max(abs(x[i, c]), 1.0), scale)
        jac[rows, 15] = bounded_difference(lambda v: fres(x[:, c], v[0]), np.array([n]), 0, COAT_N_MIN, COAT_N_MAX,
                                           1e-5, scale)
    return jac


def fit_dupuy_coated(d: FitData, loss: Loss, *, n_ndf: int = N_NDF, image: float = IMAGE_WEIGHT,
                     rounds: int = ROUNDS) -> FitResult:
    """Fit :class:`gonio.brdf.coated.Dupuy2015Coated` to prepared samples ``d`` under ``loss`` (module docstring)."""
    t0 = time.perf_counter()
    k_par = n_ndf + 16
    check_size(d, n_ndf, Dupuy2015Coated.name)
    table, _, _, geo, w, n_pix = table_fit(d, loss, n_ndf, N_FRESNEL, ITERATIONS, image)
    y = np.asarray(d.y, dtype=np.float64)
    ndf = np.asarray(table._ndf)
    cos_d = np.clip(d.cos_d, 0.0, 1.0)
    x, n, best = None, None, None
    for it in range(rounds):
        g2 = geo.g2(ndf)
        spec = geo.ndf_at(ndf) * g2 / geo.den
        n, x = _fresnel_step([_Channel(geo.theta_d, spec, y[:, c], w[:, c]) for c in range(3)], x, n, it == rounds - 1)
        model = Dupuy2015Coated(kd=x[0], ndf=ndf, ks=x[1], eta=x[2], k=x[3], t=x[4], n=n)
        objective = float(np.sum(w * (model.eval(d.wi, d.wo) - y) ** 2))
        if best is None or objective < best[0]:
            best = (objective, model, spec, x.copy(), n, it)
        raw, _, _ = _ndf_step(geo, x[0], model.fresnel_at(cos_d), g2, y, w)
        norm = normalization(raw)
        if not norm > 0:
            break
        ndf = raw / norm
    _, model, spec, x, n, it_best = best
    cost = 0.5 * float(np.sum(loss.residual(model.eval(d.wi, d.wo), y, d.cos_i, d.sigma) ** 2))
    s2 = 1.0 if loss.name == "chi2" else 2.0 * cost / max(3 * len(d) - k_par, 1)
    wscale = max(float(np.sum(_weights(loss, d) * y * y)), 1e-300)  # the objective's weights were normalized
    jac = _jacobian(cos_d, spec, w, x, n)
    sd = np.sqrt(np.maximum(np.diag(_inverse(jac.T @ jac * wscale)), 0.0) * s2)
    se = sd[:15].reshape(3, 5).T.copy()  # (5 names, 3 channels)
    n_se = np.array([[sd[15]] * 3])
    at_bound: dict = {}
    ndf_bound: dict = {}  # listed last
    ndf_se, nempty = ndf_sigma(geo, model, cos_d, y, w, wscale, s2, ndf_bound)
    for i, name in ((0, "kd"), (1, "ks"), (4, "t")):  # in [0, 1]
        mark_bound(at_bound, se, i, name, x[i], 0.0, 1.0)
    f0 = index_bounds(at_bound, se, slice(2, 4), x[2], x[3], BASE_EDGE_MIN)
    mark_bound(at_bound, n_se, 0, "n", np.full(3, n), COAT_N_MIN, COAT_N_MAX)
    if "n" in at_bound:  # one value for R, G, B
        at_bound["n"] = {"value": at_bound["n"]["r"]}
    n_se = float(n_se[0, 0])
    at_bound.update(ndf_bound)
    coat0 = ((n - 1.0) / (n + 1.0)) ** 2
    back = x[4] * conductor(np.ones(1), x[2] / n, x[3] / n)[0]  # t F_c(0) against the coat
    notes = [f"Dupuy et al. 2015's tabulated D with a conductor under a thin dielectric coat (Weidlich & Wilkie 2007): "
             f"coat index {n:.3g} (its own reflectance {coat0:.3g} at normal incidence), the metal's normal-incidence "
             f"reflectance in air {'/'.join(f'{v:.3g}' for v in f0)}, the layer's round-trip transmittance "
             f"{'/'.join(f'{v:.3g}' for v in x[4])}, all times ks; round {it_best + 1} of {rounds} kept"
             + (f"; the objective includes {image:g} x the image error" if n_pix else ""),
             f"the layer's transmittance t and the metal's index trade off: what the data determine is the light the "
             f"metal sends back through the coat at normal incidence, t F_c(0) = {'/'.join(f'{v:.3g}' for v in back)} "
             f"(their sigmas are conditional on the fitted D)"]
    if nempty.any():
        notes.append(unmeasured_note("D", "theta_h", nempty, ndf_nodes(n_ndf)))
    rms_rel, chi2_red = d.fit_quality(model.eval(d.wi, d.wo), k_par)
    unc = {name: se[i].tolist() for i, name in enumerate(_NAMES)}
    unc["n"] = n_se
    unc["ndf"] = ndf_se.tolist()
    return FitResult(model_name=Dupuy2015Coated.name, params=model.params, uncertainty=unc, loss=loss.name,
                     cost=cost, rms_rel=rms_rel, n_used=len(d), n_params=k_par, chi2_red=chi2_red,
                     method="power iteration + alternating least squares (coated conductor Fresnel)",
                     n_evals=it_best + 1, seconds=time.perf_counter() - t0, notes=notes, dropped=dict(d.dropped),
                     at_bound=at_bound)
