"""Fitting the conductor variant of the data-driven microfacet model (:class:`gonio.brdf.dupuy.Dupuy2015Conductor`):
D tabulated as in Dupuy et al. 2015, the Fresnel factor ks · F(θd; η + ik) of a complex index per RGB channel.

1. The table fit of :mod:`gonio.fit.dupuy` (power iteration, alternating linear least squares, the image term).
2. Rounds of: per channel, (kd, ks, η, k) minimizing the same weighted squares with D and G fixed — kd and
   ks in closed form for each (η, k) (variable projection, Golub & Pereyra 1973), (η, k) over metals only
   (F(0) ≥ 0.5: a scan of Gulbrandsen 2014's (F(0), edge tint), :func:`gonio.brdf.fresnel.gulbrandsen_index`, and a
   bounded polish, L-BFGS-B, in those two), on per-θd-bin sums (:class:`_Channel`); then D by the
   linear step of :mod:`gonio.fit.dupuy` with this Fresnel, normalized, and G1 recomputed from it. The round
   with the lowest objective is kept.

The conductor Fresnel equations: :func:`gonio.brdf.fresnel.conductor` (Born & Wolf §14.2; pbrt-v4 §9.3
``FrComplex``). Standard uncertainties of (kd, ks, η, k) are s² (JᵀJ)⁻¹ per channel at the solution (Press et
al., *Numerical Recipes*, 3rd ed., §15.5), those of D as for the table model; a parameter on a bound has none.
"""

from __future__ import annotations

import time

import numpy as np

from gonio.brdf.dupuy import (ETA_MAX, ETA_MIN, K_MAX, N_FRESNEL, N_NDF, Dupuy2015Conductor, ndf_nodes,
                              normalization)
from gonio.brdf.fresnel import F0_MAX, METAL_F0_MIN, conductor, gulbrandsen_index
from gonio.errors import DataError
from gonio.fit.data import FitData
from gonio.fit.dupuy import (IMAGE_WEIGHT, ITERATIONS, _inverse, _ndf_step, _weights, table_fit,
                              unmeasured_note)
from gonio.fit.losses import Loss
from gonio.fit.result import FitResult

__all__ = ["fit_dupuy_conductor", "ROUNDS"]

#: Rounds of step 2.
ROUNDS = 2
#: The scan of step 2, over metals only: F(0) from :data:`~gonio.brdf.fresnel.METAL_F0_MIN` to
#: :data:`~gonio.brdf.fresnel.F0_MAX` × Gulbrandsen's edge tint over [0, 1] (:func:`gonio.brdf.fresnel.gulbrandsen_index`).
_F0S = np.linspace(METAL_F0_MIN, F0_MAX, 32)
_EDGES = np.linspace(0.0, 1.0, 33)


#: θd bins of the sufficient statistics of step 3 (F is taken constant within a bin of 0.35°).
_BINS = 256


class _Channel:
    """Σ w (kd/π + ks F(θd; η, k) S − y)² of one channel, from per-θd-bin sums (F is constant within a bin),
    so that (η, k) are searched on :data:`_BINS` numbers and kd, ks solved in closed form (variable
    projection, Golub & Pereyra 1973)."""

    def __init__(self, theta_d, spec, y, w):
        b = np.minimum((theta_d / (0.5 * np.pi) * _BINS).astype(np.intp), _BINS - 1)
        self.cos = np.cos((np.arange(_BINS) + 0.5) / _BINS * 0.5 * np.pi)
        sums = [np.bincount(b, v, _BINS) for v in (w, w * spec, w * spec * spec, w * y, w * spec * y)]
        self.w, self.ws, self.wss, self.wy, self.wsy = sums
        self.wyy = float(np.sum(w * y * y))

    def solve(self, eta: float, k: float) -> tuple[float, float, float]:
        """(objective, kd, ks) at (η, k): the bounded 2×2 least squares in (kd, ks) ∈ [0, 1]²."""
        obj, kd, ks = self.solve_many(np.array([eta], dtype=np.float64), np.array([k], dtype=np.float64))
        return float(obj[0]), float(kd[0]), float(ks[0])

    def solve_many(self, eta: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`solve` at M points (η, k) at once (arrays (M,)): the Fresnel factors of every bin and point are one
        (bins, M) array, the normal equations M 2×2 systems; the minimum over the interior solution and the four
        edges of the box (one of kd, ks at 0 or 1, the other solved, each clipped to [0, 1])."""
        return self.solve_fresnel(conductor(self.cos, eta, k).reshape(self.cos.size, -1))

    def solve_fresnel(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`solve_many` for M Fresnel factors given at the bins' θd (an array (bins, M)): any F(θd), e.g. a
        coated conductor's (:mod:`gonio.fit.dupuy_coated`)."""
        a11 = float(np.sum(self.w)) / np.pi ** 2
        a12 = (self.ws @ f) / np.pi
        a22 = self.wss @ (f * f)
        b1, b2 = float(np.sum(self.wy)) / np.pi, self.wsy @ f
        det = a11 * a22 - a12 * a12
        safe = np.where(det > 0, det, 1.0)
        pos22 = np.where(a22 > 0, a22, 1.0)
        cands = [(0.0 * a12, np.where(a22 > 0, b2 / pos22, 0.0)), (1.0 + 0.0 * a12, np.where(a22 > 0, (b2 - a12) / pos22, 0.0)),
                 ((b1 - 0.0 * a12) / a11 if a11 > 0 else 0.0 * a12, 0.0 * a12),
                 ((b1 - a12) / a11 if a11 > 0 else 0.0 * a12, 1.0 + 0.0 * a12)]
        interior = det > 0
        cands.insert(0, (np.where(interior, (a22 * b1 - a12 * b2) / safe, np.nan),
                         np.where(interior, (a11 * b2 - a12 * b1) / safe, np.nan)))
        best_obj = np.full(a12.shape, np.inf)
        best_kd, best_ks = np.zeros(a12.shape), np.zeros(a12.shape)
        for kd, ks in cands:
            kd, ks = np.clip(kd, 0.0, 1.0), np.clip(ks, 0.0, 1.0)
            obj = a11 * kd * kd + 2 * a12 * kd * ks + a22 * ks * ks - 2 * (b1 * kd + b2 * ks) + self.wyy
            better = obj < best_obj  # nan (no interior solution) is never better
            best_obj, best_kd, best_ks = (np.where(better, obj, best_obj), np.where(better, kd, best_kd),
                                          np.where(better, ks, best_ks))
        return best_obj, best_kd, best_ks


def _channel(ch: _Channel, x0) -> np.ndarray:
    """(kd, ks, η, k) of one channel, over metals only (F(0) ≥ :data:`~gonio.brdf.fresnel.METAL_F0_MIN`, issue 29): a
    scan of Gulbrandsen's (F(0), edge tint) (:func:`gonio.brdf.fresnel.gulbrandsen_index`), then a bounded polish
    (L-BFGS-B) of the profiled objective :meth:`_Channel.solve` in the same two numbers; ``x0`` (a previous round's
    index, kept when it is a metal's) joins the scan."""
    from scipy.optimize import minimize

    r_grid, g_grid = (a.ravel() for a in np.meshgrid(_F0S, _EDGES, indexing="ij"))
    e_grid, k_grid = gulbrandsen_index(r_grid, g_grid)
    if x0 is not None:
        r0 = float(conductor(np.ones(1), x0[2], x0[3])[0])
        if METAL_F0_MIN <= r0 <= F0_MAX:
            e_grid, k_grid = np.append(e_grid, x0[2]), np.append(k_grid, x0[3])
            r_grid, g_grid = np.append(r_grid, r0), np.append(g_grid, _edge_of(r0, x0[2]))
    j = int(np.argmin(ch.solve_many(e_grid, k_grid)[0]))

    def objective(u):
        eta, k = gulbrandsen_index(float(np.clip(u[0], METAL_F0_MIN, F0_MAX)), float(np.clip(u[1], 0.0, 1.0)))
        return ch.solve(float(eta), float(k))[0]

    res = minimize(objective, [r_grid[j], g_grid[j]], method="L-BFGS-B", bounds=[(METAL_F0_MIN, F0_MAX), (0.0, 1.0)])
    eta, k = gulbrandsen_index(float(np.clip(res.x[0], METAL_F0_MIN, F0_MAX)), float(np.clip(res.x[1], 0.0, 1.0)))
    _, kd, ks = ch.solve(float(eta), float(k))
    return np.array([kd, ks, float(eta), float(k)])


def _edge_of(r: float, eta: float) -> float:
    """Gulbrandsen's edge tint g of the index whose F(0) is ``r`` and real part ``eta`` (the first of his eqs. 3–4
    solved for g), clipped to [0, 1]."""
    sr = np.sqrt(r)
    n_min, n_max = (1.0 - r) / (1.0 + r), (1.0 + sr) / (1.0 - sr)
    return float(np.clip((n_max - eta) / max(n_max - n_min, 1e-300), 0.0, 1.0))


def bounded_difference(f, x: np.ndarray, i: int, lo: float, hi: float, h: float, scale) -> np.ndarray:
    """``scale · ∂f/∂x[i]`` by a central difference kept within the parameter's range [lo, hi] (one-sided at a
    bound): ``scale · (f(x with x[i] = b) − f(x with x[i] = a)) / (b − a)``, a, b = x[i] ∓ h clipped to the range."""
    a, b = max(x[i] - h, lo), min(x[i] + h, hi)
    xa, xb = x.copy(), x.copy()
    xa[i], xb[i] = a, b
    return scale * (f(xb) - f(xa)) / max(b - a, 1e-300)


def _jacobian(cos_d, spec, w, x) -> np.ndarray:
    """∂(√w · model)/∂(kd, ks, η, k) of one channel at ``x`` (analytic in kd, ks; central differences in η, k)."""
    sw = np.sqrt(w)
    f = conductor(cos_d, x[2], x[3])
    cols = [sw / np.pi, sw * f * spec]
    for i, (lo, hi) in ((2, (ETA_MIN, ETA_MAX)), (3, (0.0, K_MAX))):
        cols.append(bounded_difference(lambda v: conductor(cos_d, v[2], v[3]), x, i, lo, hi,
                                       1e-5 * max(abs(x[i]), 1.0), sw * x[1] * spec))
    return np.stack(cols, axis=1)


def check_size(d: FitData, n_ndf: int, name: str) -> None:
    """DataError (one line) when ``d`` has too few values to determine the tables of ``name``."""
    if 3 * len(d) <= n_ndf + 3 * N_FRESNEL + 3:
        raise DataError(f"{d.source}: {len(d)} usable samples ({3 * len(d)} values) cannot determine the "
                        f"tables of {name}; need at least {(n_ndf + 3 * N_FRESNEL + 3) // 3 + 1} samples")


def mark_bound(at_bound: dict, se: np.ndarray, rows, name: str, v, lo: float, hi: float) -> None:
    """Name every channel of parameter ``name`` (values ``v`` (3,)) within 10⁻⁶ of its range's width from a bound in
    ``at_bound`` and take the σ of rows ``rows`` of ``se`` (params × channels) of that channel."""
    for c, ch in enumerate("rgb"):
        if v[c] - lo <= 1e-6 * (hi - lo) or hi - v[c] <= 1e-6 * (hi - lo):
            at_bound.setdefault(name, {})[ch] = f"lower {lo:g}" if v[c] - lo <= 1e-6 * (hi - lo) else f"upper {hi:g}"
            se[rows, c] = np.nan


def index_bounds(at_bound: dict, se: np.ndarray, rows, eta, k, edge_min: float = 0.0) -> np.ndarray:
    """The conductors' F(0) per channel; an F(0) or edge tint on a bound (the edge tint's lower one ``edge_min``) is
    named (:func:`mark_bound`): the index is searched in Gulbrandsen's (F(0), edge tint), whose bounds are its own (η
    and k, rows ``rows``, lose their σ)."""
    f0 = conductor(np.ones(1), np.asarray(eta), np.asarray(k))[0]
    edge = np.array([_edge_of(float(f0[c]), float(np.asarray(eta)[c])) for c in range(3)])
    mark_bound(at_bound, se, rows, "f0", f0, METAL_F0_MIN, F0_MAX)
    mark_bound(at_bound, se, rows, "edge", edge, edge_min, 1.0)
    return f0


def ndf_sigma(geo, model, cos_d, y, w, wscale: float, s2: float, at_bound: dict) -> tuple[np.ndarray, np.ndarray]:
    """``(σ of D's nodes, nodes no sample constrains)`` from the D step's normal matrix at ``model`` (as
    :mod:`gonio.fit.dupuy`); nodes at 0 are named in ``at_bound`` and lose their σ."""
    _, nmat, nempty = _ndf_step(geo, np.asarray(model.kd), model.fresnel_at(cos_d), geo.g2(model._ndf), y, w)
    ndf_se = np.sqrt(np.maximum(np.diag(_inverse(nmat * wscale + np.diag(np.where(nempty[1:], 1.0, 0.0)))), 0.0) * s2)
    ndf_se = np.concatenate([ndf_se[:1], ndf_se]) / normalization(model.ndf)
    ndf_se[nempty] = np.nan
    if (np.asarray(model.ndf) <= 0).any():
        at_bound["ndf"] = {"value": "lower 0 at some theta_h nodes"}
        ndf_se[np.asarray(model.ndf) <= 0] = np.nan
    return ndf_se, nempty


def fit_dupuy_conductor(d: FitData, loss: Loss, *, n_ndf: int = N_NDF, image: float = IMAGE_WEIGHT,
                        rounds: int = ROUNDS) -> FitResult:
    """Fit :class:`gonio.brdf.dupuy.Dupuy2015Conductor` to prepared samples ``d`` under ``loss`` (module docstring)."""
    t0 = time.perf_counter()
    k_par = n_ndf + 12
    check_size(d, n_ndf, "dupuy2015-conductor")
    table, _, _, geo, w, n_pix = table_fit(d, loss, n_ndf, N_FRESNEL, ITERATIONS, image)
    y = np.asarray(d.y, dtype=np.float64)
    ndf = np.asarray(table._ndf)
    x = np.zeros((4, 3))
    cos_d = np.clip(d.cos_d, 0.0, 1.0)
    best = None
    for it in range(rounds):
        g2 = geo.g2(ndf)
        spec = geo.ndf_at(ndf) * g2 / geo.den
        for c in range(3):
            x[:, c] = _channel(_Channel(geo.theta_d, spec, y[:, c], w[:, c]), x[:, c] if it else None)
        model = Dupuy2015Conductor(kd=x[0], ndf=ndf, ks=x[1], eta=x[2], k=x[3])
        objective = float(np.sum(w * (model.eval(d.wi, d.wo) - y) ** 2))
        if best is None or objective < best[0]:
            best = (objective, model, [_jacobian(cos_d, spec, w[:, c], x[:, c]) for c in range(3)], it)
        raw, _, _ = _ndf_step(geo, x[0], model.fresnel_at(cos_d), g2, y, w)
        norm = normalization(raw)
        if not norm > 0:
            break
        ndf = raw / norm
    _, model, jacs, it_best = best
    cost = 0.5 * float(np.sum(loss.residual(model.eval(d.wi, d.wo), y, d.cos_i, d.sigma) ** 2))
    s2 = 1.0 if loss.name == "chi2" else 2.0 * cost / max(3 * len(d) - k_par, 1)
    wscale = max(float(np.sum(_weights(loss, d) * y * y)), 1e-300)  # the objective's weights were normalized
    names = ("kd", "ks", "eta", "k")
    se = np.zeros((4, 3))
    for c, jac in enumerate(jacs):
        se[:, c] = np.sqrt(np.maximum(np.diag(_inverse(jac.T @ jac * wscale)), 0.0) * s2)
    at_bound: dict = {}
    ndf_bound: dict = {}  # listed last
    ndf_se, nempty = ndf_sigma(geo, model, cos_d, y, w, wscale, s2, ndf_bound)
    for i, name in enumerate(names[:2]):  # kd, ks in [0, 1]
        mark_bound(at_bound, se, i, name, np.asarray(model.params[name], dtype=np.float64), 0.0, 1.0)
    f0 = index_bounds(at_bound, se, slice(2, 4), model.eta, model.k)
    at_bound.update(ndf_bound)
    notes = [f"Dupuy et al. 2015's tabulated D with a conductor's Fresnel (complex index per channel): "
             f"normal-incidence reflectance {'/'.join(f'{v:.3g}' for v in f0)} times ks; round {it_best + 1} of "
             f"{rounds} kept" + (f"; the objective includes {image:g} x the image error" if n_pix else "")]
    if nempty.any():
        notes.append(unmeasured_note("D", "theta_h", nempty, ndf_nodes(n_ndf)))
    rms_rel, chi2_red = d.fit_quality(model.eval(d.wi, d.wo), k_par)
    unc = {name: se[i].tolist() for i, name in enumerate(names)}
    unc["ndf"] = ndf_se.tolist()
    return FitResult(model_name=Dupuy2015Conductor.name, params=model.params, uncertainty=unc, loss=loss.name,
                     cost=cost, rms_rel=rms_rel, n_used=len(d), n_params=k_par, chi2_red=chi2_red,
                     method="power iteration + alternating least squares (conductor Fresnel)", n_evals=it_best + 1,
                     seconds=time.perf_counter() - t0, notes=notes, dropped=dict(d.dropped), at_bound=at_bound)
