"""Fitting the data-driven microfacet model of Dupuy et al. 2015 (:mod:`gonio.brdf.dupuy`) to samples.

J. Dupuy, E. Heitz, J.-C. Iehl, P. Poulin, V. Ostromoukhov, "Extracting Microfacet-based BRDF Parameters
from Arbitrary Materials with Power Iterations", Computer Graphics Forum 34(4) (EGSR 2015).

1. **Power iteration** (Dupuy et al. 2015 §4). In the back-scattering configuration wi = wo = k the
   microfacets that are visible are also lit, G2(k, k) = G1(k) = cos θk / ∫ max(0, k·m) D(m) dm, so
   f(k, k) = F(0) D(k) G1(k) / (4 cos²θk) gives D(k) ∝ f(k, k) cos θk ∫ max(0, k·m) D(m) dm: D is the
   eigenvector of the positive linear operator K[D](k) = f(k, k) cos θk ∫ max(0, k·m) D(m) dm with the
   largest eigenvalue (Perron–Frobenius), found by iterating D ← K[D] / ‖K[D]‖. The back-scattering
   profile f(k, k) is the hat-weighted mean over θh of the samples nearest the back-scattering
   configuration (θd below :data:`RETRO_DEG`, or the tenth of the samples with the smallest θd where that
   is empty: a gonioreflectometer cannot put its camera on its light), minus a diffuse floor.
2. **Alternating linear least squares** in the fitting loss (this implementation's refinement; the
   paper fits the Fresnel term to the data once D is known): the model is linear in (kd, F) for a given D
   and G, and linear in D for given (kd, F) and G, so each step is a bounded linear least-squares problem
   (kd, F in [0, 1], D ≥ 0) on the normal equations; G1 is recomputed from each new D (normalized, Dupuy et
   al. 2015 eq. 2 and 4) — the fixed point of the power iteration with the model's own G2 at every
   configuration. A non-linear loss (log, cube root) is minimized linearized at the data
   (``w = (∂r/∂m)²`` at m = y). The iteration that leaves the lowest objective is kept.
3. **The image error in the objective** (issue 29: fit in the error a rendering sees): the loss's squares,
   normalized by their value at f_m = 0, plus :data:`IMAGE_WEIGHT` times a re-weighted cosine L2 that
   approximates the squared relative image error of :func:`gonio.fit.metrics.image_error` (:func:`_with_image`);
   ``image=0`` (``gonio fit --image-weight 0``) fits the loss alone. Both terms are linear in the tables, so the
   steps above stay linear least squares.

Standard uncertainties are those of the last linear steps, s² (XᵀWX)⁻¹ (Press et al., *Numerical Recipes*,
3rd ed., §15.4), with s² = 2·cost/(m − k) unless the loss is χ² with known σ; an entry on a bound has none
(NaN) and is named in ``at_bound``; a table node no sample constrains (a sparse measurement, a cross-validation
fold) is interpolated from the nearest nodes with samples and held beyond them (:func:`fill_empty`: whole empty
ranges of θh or θd included), has none either, and is named in the notes as not measured (:func:`unmeasured_note`).
"""

from __future__ import annotations

import time
from functools import lru_cache

import numpy as np

from gonio.brdf.dupuy import (G1_NODES, N_FRESNEL, N_NDF, Dupuy2015, fresnel_nodes, hat_weights, interp_g1,
                              ndf_nodes, ndf_position, normalization, projected_area, smith_g1_table)
from gonio.errors import DataError
from gonio.fit.data import FitData
from gonio.fit.losses import ROBUST_EPS, Loss
from gonio.fit.result import FitResult

__all__ = ["fit_dupuy", "power_iteration", "RETRO_DEG", "ITERATIONS"]

#: Largest θd (degrees) of the samples taken as back-scattering for the power iteration.
RETRO_DEG = 3.0
#: Power iterations on the back-scattering operator.
POWER_STEPS = 40
#: Rounds of the alternating least squares.
ITERATIONS = 8
#: Weight of the squared relative image error beside the loss's (normalized) in what the fit minimizes: chosen on
#: ``python -m benchmarks realdata``'s materials (4 left a near-Lambertian paint's image error above the published
#: fit's, 16 its cube-root error).
IMAGE_WEIGHT = 10.0
#: Relative weight of the second-difference penalty that fills table nodes without samples.
SMOOTH = 1e-9


def _weights(loss: Loss, d: FitData) -> np.ndarray:
    """Least-squares weights (N, 3) of ``loss`` (its own for a linear loss, else (∂r/∂m)² at m = y)."""
    if loss.weight is not None:
        return np.asarray(np.broadcast_to(loss.weight(d.y, d.cos_i, d.sigma), d.y.shape), dtype=np.float64)
    c = d.cos_i[:, None]
    if loss.name == "log":  # r = ln(1 + m c): ∂r/∂m = c / (1 + y c)
        return (c / (1.0 + np.maximum(d.y, 0.0) * c)) ** 2
    # cube root: ∂r/∂m = c / (3 (y c)^(2/3)), floored as the robust loss (gonio.fit.losses)
    return (c * c) / (9.0 * np.cbrt(np.maximum(d.y, 0.0) * c + ROBUST_EPS) ** 4)


def _retro_profile(theta_h, theta_d, y, n: int) -> np.ndarray:
    """f(k, k) (mean over channels) at D's ``n`` nodes from the samples nearest back-scattering (module
    docstring); nodes without such samples interpolated from the others."""
    cut = max(np.radians(RETRO_DEG), float(np.quantile(theta_d, 0.1)))
    near = theta_d <= cut
    j, t = hat_weights(ndf_position(theta_h[near], n), n)
    v = y[near].mean(axis=1)
    wsum = np.bincount(j, 1 - t, n) + np.bincount(j + 1, t, n)
    vsum = np.bincount(j, (1 - t) * v, n) + np.bincount(j + 1, t * v, n)
    have = wsum > 1e-12
    if not have.any():
        return np.ones(n)
    nodes = np.arange(n)
    return np.interp(nodes, nodes[have], vsum[have] / wsum[have])


def power_iteration(retro: np.ndarray, steps: int = POWER_STEPS) -> np.ndarray:
    """D (normalized, Dupuy et al. 2015 eq. 2) from a back-scattering profile f(k, k) tabulated at D's nodes:
    the dominant eigenvector of K[D](k) = f(k, k) cos θk ∫ max(0, k·m) D(m) dm (module docstring, step 1)."""
    retro = np.maximum(np.asarray(retro, dtype=np.float64), 0.0)
    n = retro.shape[0]
    theta = ndf_nodes(n)
    tk = np.linspace(0.0, 0.5 * np.pi, G1_NODES)
    ndf = np.ones(n) / normalization(np.ones(n))
    for _ in range(steps):
        area = np.interp(theta, tk, projected_area(ndf))
        new = retro * np.cos(theta) * area
        norm = normalization(new)
        if not norm > 0:
            break
        ndf = new / norm
    return ndf


@lru_cache(maxsize=4)
def _second_difference(n: int) -> np.ndarray:
    """Dᵀ D of the second-difference matrix D ((n − 2) × n) (read-only, cached)."""
    m = np.zeros((n - 2, n))
    i = np.arange(n - 2)
    m[i, i], m[i, i + 1], m[i, i + 2] = 1.0, -2.0, 1.0
    out = m.T @ m
    out.setflags(write=False)
    return out


def _bounded_normal(ata: np.ndarray, atb: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """argmin ‖A x − b‖² with lo ≤ x ≤ hi from the normal equations (AᵀA, Aᵀb): the same minimizer as on
    A itself, solved on its Cholesky factor R (RᵀR = AᵀA, ‖A x − b‖² = ‖R x − R⁻ᵀAᵀb‖² + const)."""
    from scipy.linalg import cho_factor, solve_triangular
    from scipy.optimize import lsq_linear

    k = ata.shape[0]
    scale = np.sqrt(np.maximum(np.diag(ata), 1e-300))
    a = ata / np.outer(scale, scale) + 1e-12 * np.eye(k)
    try:
        r = np.triu(cho_factor(a, lower=False)[0])
        q = solve_triangular(r, atb / scale, trans="T")
    except np.linalg.LinAlgError:  # not positive definite in rounding: the symmetric factor R = Λ^½ Vᵀ instead
        ev, vec = np.linalg.eigh(a)
        root = np.sqrt(np.maximum(ev, 1e-12))
        r = root[:, None] * vec.T
        q = (vec.T @ (atb / scale)) / root
    res = lsq_linear(r, q, bounds=(lo * scale, hi * scale), method="bvls")
    x = res.x / scale
    if not np.all(np.isfinite(x)):
        raise DataError("dupuy2015: a table's least-squares step has no finite solution on these samples")
    # BVLS holds x·scale on the bound; dividing by the scale can round it just past (−5e-29 for 0): clipped back
    return np.clip(x, lo, hi)


class _Geometry:
    """Per-sample interpolation weights and cosines shared by every step."""

    def __init__(self, d: FitData, n: int, m: int):
        self.ci, self.co = d.cos_i, d.cos_o
        self.theta_h = np.arccos(np.clip(d.cos_h, -1.0, 1.0))
        self.theta_d = np.arccos(np.clip(d.cos_d, 0.0, 1.0))
        self.jh, self.th = hat_weights(ndf_position(self.theta_h, n), n)
        self.jd, self.td = hat_weights(self.theta_d / (0.5 * np.pi) * (m - 1), m)
        self.den = 4.0 * np.maximum(self.ci * self.co, 1e-300)
        self.n, self.m = n, m
        # D's nodes no sample's interpolation weight reaches (the normal node tied to the next, as in _ndf_step)
        reach = np.bincount(self.jh, 1.0 - self.th, n) + np.bincount(self.jh + 1, self.th, n)
        reach[:2] = reach[0] + reach[1]
        self.ndf_empty = reach <= 1e-12 * max(float(reach.max()), 1e-300)

    def ndf_at(self, ndf):
        return (1.0 - self.th) * ndf[self.jh] + self.th * ndf[self.jh + 1]

    def g2(self, ndf):
        g1 = smith_g1_table(ndf)
        return interp_g1(g1, self.ci) * interp_g1(g1, self.co)


def _fresnel_step(geo: _Geometry, spec: np.ndarray, y, w):
    """(kd (3,), F (m, 3), normal matrices per channel) minimizing the weighted squares for a fixed specular
    shape ``spec`` = D G2 / (4 cos cos) (N,)."""
    m = geo.m
    x = np.zeros((len(y), m + 1))
    x[:, 0] = 1.0 / np.pi
    rows = np.arange(len(y))
    x[rows, 1 + geo.jd] += (1.0 - geo.td) * spec
    x[rows, 2 + geo.jd] += geo.td * spec
    kd, fr, mats = np.zeros(3), np.zeros((m, 3)), []
    for c in range(3):
        xw = x * w[:, c:c + 1]
        ata, atb = x.T @ xw, xw.T @ y[:, c]
        empty = np.diag(ata) <= 1e-12 * max(float(np.max(np.diag(ata))), 1e-300)
        ata = ata + np.diag(np.where(empty, 1.0, 0.0))  # a node without samples: held by the fill below
        sol = _bounded_normal(ata, atb, 0.0, 1.0)
        sol[1:] = fill_empty(sol[1:], empty[1:], fresnel_nodes(m))  # θd nodes without samples
        kd[c], fr[:, c] = sol[0], sol[1:]
        mats.append((ata, empty))
    return kd, fr, mats


def _table_at(geo: _Geometry, fr: np.ndarray) -> np.ndarray:
    """The Fresnel table ``fr`` (m, 3) at the samples' θd (N, 3)."""
    return (1.0 - geo.td)[:, None] * fr[geo.jd] + geo.td[:, None] * fr[geo.jd + 1]


def _ndf_step(geo: _Geometry, kd, f_at, g2, y, w):
    """D ≥ 0 (unnormalized) minimizing the weighted squares for fixed kd, F (at the samples, (N, 3)) and G2,
    and its normal matrix."""
    n = geo.n
    a = f_at * (g2 / geo.den)[:, None]  # (N, 3): y − kd/π = a · D(θh)
    r = y - kd[None, :] / np.pi
    wa2 = np.sum(w * a * a, axis=1)
    war = np.sum(w * a * r, axis=1)
    u, v = 1.0 - geo.th, geo.th
    ata = np.zeros((n, n))
    ata[np.diag_indices(n)] = np.bincount(geo.jh, wa2 * u * u, n) + np.bincount(geo.jh + 1, wa2 * v * v, n)
    off = np.bincount(geo.jh, wa2 * u * v, n)[: n - 1]
    ata[np.arange(n - 1), np.arange(1, n)] += off
    ata[np.arange(1, n), np.arange(n - 1)] += off
    atb = np.bincount(geo.jh, war * u, n) + np.bincount(geo.jh + 1, war * v, n)
    # D(θh) is even in θh, so flat at the normal: D(θ₀ = 0) = D(θ₁) (θ₁ = (π/2)/(n − 1)², where an isotropic D
    # has not moved by (θ₁/α)² ~ 10⁻⁴ even for α = 0.01); the normal node alone is barely sampled
    tie = np.eye(n)[:, 1:]
    tie[0, 0] = 1.0
    ata_t, atb_t = tie.T @ ata @ tie, tie.T @ atb
    diag = np.diag(ata_t).copy()
    empty = diag <= 1e-12 * max(float(diag.max()), 1e-300)
    reg = SMOOTH * max(float(diag.max()), 1e-300) * _second_difference(n - 1)
    sol = _bounded_normal(ata_t + reg + np.diag(np.where(empty, 1e-6 * float(diag.max() or 1.0), 0.0)), atb_t,
                          0.0, np.inf)
    full_empty = np.concatenate([[empty[0]], empty])
    return fill_empty(tie @ sol, full_empty, ndf_nodes(n)), ata_t, full_empty


def fill_empty(values: np.ndarray, empty: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """A table's ``values`` at the nodes no sample constrains (``empty``) replaced by linear interpolation in
    the node coordinate ``nodes`` between the nearest nodes with samples, and held at the nearest one beyond
    them (``numpy.interp``): a whole empty range — a fold with nothing near grazing or at the peak — gets its
    neighbours' values, not the ridge's zero; all zero when no node has samples. Not measured: the fits give
    these nodes no uncertainty and name them (:func:`unmeasured_note`)."""
    out = np.array(values, dtype=np.float64)
    have = ~np.asarray(empty, dtype=bool)
    if not have.all():
        out[~have] = np.interp(nodes[~have], nodes[have], out[have]) if have.any() else 0.0
    return out


def unmeasured_note(table: str, axis: str, empty: np.ndarray, nodes: np.ndarray) -> str:
    """One note naming the nodes of ``table`` no sample constrains, as ranges of ``axis`` in degrees."""
    idx = np.flatnonzero(empty)
    deg = np.degrees(nodes)
    spans = _nodes(idx, lambda j: f"{deg[j]:.3g}")
    return (f"not measured: {len(idx)} of {len(nodes)} nodes of {table} ({axis} {spans} deg) have no "
            f"sample; interpolated from the nearest measured nodes (held beyond them), not identified (no "
            f"uncertainty)")


def _with_image(d: FitData, w: np.ndarray, image: float) -> tuple[np.ndarray, int]:
    """Weights (N, 3) of what the alternating least squares minimize: the loss's, normalized by its value at
    f_m = 0, plus, with ``image`` > 0, ``image`` times a re-weighted cosine L2 that approximates the squared
    relative image error of :func:`gonio.fit.metrics.image_error`: that error sums c²(f(pixel) − f(sample))²
    over the sphere pixels, each with its nearest measured sample (:func:`gonio.fit.metrics.sphere_targets`);
    here every sample carries the c² = cos²θi of the pixels it is nearest to, and the model is compared with
    it at its own geometry (a pixel's geometry differs from its sample's by up to
    :data:`gonio.fit.metrics.IMAGE_MAX_GAP`: chasing that difference would move a razor-thin peak).
    ``(weights, number of samples the spheres see)``."""
    y = np.asarray(d.y, dtype=np.float64)
    wd = w / max(float(np.sum(w * y * y)), 1e-300)
    if not image > 0:
        return wd, 0
    from gonio.fit.metrics import sphere_cover

    cover = sphere_cover(d)
    if not cover.any():
        return wd, 0
    wp = cover[:, None] * np.ones((1, 3))
    wp = image * wp / max(float(np.sum(wp * y * y)), 1e-300)
    return wd + wp, int(np.count_nonzero(cover))


def table_fit(d: FitData, loss: Loss, n_ndf: int, n_fresnel: int, iterations: int, image: float):
    """Steps 1–3 of the module docstring: ``(model, the F steps' normal matrices, the round kept, geometry,
    weights, samples the spheres see)``. Kept on the data set for its arguments (the conductor and coated variants,
    :mod:`gonio.fit.dupuy_conductor`, :mod:`gonio.fit.dupuy_coated`, start from the same table fit: a metal's selection
    fits all three on one subset); what it returns is read, never written."""
    cache = d.__dict__.setdefault("_kernel_cache", {})
    key = ("dupuy_table", loss.name, n_ndf, n_fresnel, iterations, float(image))
    hit = cache.get(key)
    if hit is None:
        hit = cache[key] = _table_fit(d, loss, n_ndf, n_fresnel, iterations, image)
    return hit


def _table_fit(d: FitData, loss: Loss, n_ndf: int, n_fresnel: int, iterations: int, image: float):
    """:func:`table_fit`, computed."""
    geo = _Geometry(d, n_ndf, n_fresnel)
    floor = np.percentile(d.y, 5, axis=0)
    ndf = power_iteration(_retro_profile(geo.theta_h, geo.theta_d, d.y - floor[None, :], n_ndf))
    ndf = fill_empty(ndf, geo.ndf_empty, ndf_nodes(n_ndf))  # as every later D step fills them
    ndf = ndf / normalization(ndf)
    w, n_pix = _with_image(d, _weights(loss, d), image)
    y = np.asarray(d.y, dtype=np.float64)
    best = None
    for it in range(iterations + 1):
        g2 = geo.g2(ndf)
        kd, fr, fmats = _fresnel_step(geo, geo.ndf_at(ndf) * g2 / geo.den, y, w)
        model = Dupuy2015(kd=kd, ndf=ndf, fresnel=fr)
        objective = float(np.sum(w * (model.eval(d.wi, d.wo) - y) ** 2))
        if best is None or objective < best[0]:
            best = (objective, model, fmats, it)
        if it == iterations:
            break
        raw, _, _ = _ndf_step(geo, kd, _table_at(geo, fr), g2, y, w)
        norm = normalization(raw)
        if not norm > 0:
            break
        ndf = raw / norm
    return best[1], best[2], best[3], geo, w, n_pix


def fit_dupuy(d: FitData, loss: Loss, *, n_ndf: int = N_NDF, n_fresnel: int = N_FRESNEL,
              iterations: int = ITERATIONS, image: float = IMAGE_WEIGHT) -> FitResult:
    """Fit :class:`gonio.brdf.dupuy.Dupuy2015` to prepared samples ``d`` under ``loss`` (module docstring);
    ``image`` > 0 adds the image error to what is minimized, with that weight (:func:`_with_image`)."""
    t0 = time.perf_counter()
    k = n_ndf + 3 * n_fresnel + 3
    if 3 * len(d) <= k:
        raise DataError(f"{d.source}: {len(d)} usable samples ({3 * len(d)} values) cannot determine the {k} "
                        f"parameters of dupuy2015 (tabulated D and F); need at least {k // 3 + 1} samples")
    model, fmats, it_best, geo, w, n_pix = table_fit(d, loss, n_ndf, n_fresnel, iterations, image)
    y = np.asarray(d.y, dtype=np.float64)
    cost = 0.5 * float(np.sum(loss.residual(model.eval(d.wi, d.wo), d.y, d.cos_i, d.sigma) ** 2))
    # the D step's normal matrix at the kept solution (for its uncertainties)
    _, nmat, nempty = _ndf_step(geo, np.asarray(model.kd), model.parts(d.cos_i, d.cos_o, d.cos_h, d.cos_d)[1],
                                geo.g2(model._ndf), y, w)
    # the weights were normalized: back to the loss's scale for s² (AᵀWA scales as W)
    wscale = max(float(np.sum(_weights(loss, d) * d.y * d.y)), 1e-300)
    nmat = nmat * wscale
    fmats = [(a * wscale, e) for a, e in fmats]
    notes = [f"Dupuy et al. 2015: D from the power iteration on the back-scattering samples, then {it_best} of "
             f"{iterations} rounds of alternating linear least squares in the {loss.name} loss"
             + (f" plus {image:g} x the image error (re-weighted on the {n_pix} samples its spheres show)" if n_pix else "")]
    s2 = 1.0 if loss.name == "chi2" else 2.0 * cost / max(3 * len(d) - k, 1)
    kd_se, fr_se = np.zeros(3), np.zeros((n_fresnel, 3))
    for c, (ata, empty) in enumerate(fmats):
        cov = _inverse(ata) * s2
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
        se[empty] = np.nan
        kd_se[c], fr_se[:, c] = se[0], se[1:]
    ndf_se = np.sqrt(np.maximum(np.diag(_inverse(nmat + np.diag(np.where(nempty[1:], 1.0, 0.0)))), 0.0) * s2)
    ndf_se = np.concatenate([ndf_se[:1], ndf_se])  # the normal node is tied to the next (_ndf_step)
    ndf_se = ndf_se / normalization(model.ndf)  # in the units of the normalized table
    ndf_se[nempty] = np.nan
    at_bound: dict = {}
    for c, ch in enumerate("rgb"):
        if model.kd[c] <= 1e-9:
            at_bound.setdefault("kd", {})[ch] = "lower 0"
            kd_se[c] = np.nan
        fc = np.asarray(model.fresnel)[:, c]
        for end, hit in (("lower 0", fc <= 1e-9), ("upper 1", fc >= 1 - 1e-9)):
            if hit.any():
                at_bound.setdefault("fresnel", {})[ch] = f"{end} at theta_d nodes {_nodes(np.flatnonzero(hit))}"
                fr_se[hit, c] = np.nan
    zero = np.asarray(model.ndf) <= 0
    if zero.any():
        at_bound["ndf"] = {"value": f"lower 0 at theta_h nodes {_nodes(np.flatnonzero(zero))}"}
        ndf_se[zero] = np.nan
    if nempty.any():
        notes.append(unmeasured_note("D", "theta_h", nempty, ndf_nodes(n_ndf)))
    fempty = np.any([e[1:] for _, e in fmats], axis=0)
    if fempty.any():
        notes.append(unmeasured_note("F", "theta_d", fempty, fresnel_nodes(n_fresnel)))
    rms_rel, chi2_red = d.fit_quality(model.eval(d.wi, d.wo), k)
    thin = 4 * k > 3 * len(d)
    if thin:
        notes.append(f"{len(d)} samples for {k} parameters: the tables are barely determined")
    return FitResult(model_name=Dupuy2015.name, params=model.params,
                     uncertainty={"kd": kd_se.tolist(), "ndf": ndf_se.tolist(), "fresnel": fr_se.tolist()},
                     loss=loss.name, cost=cost, rms_rel=rms_rel, n_used=len(d), n_params=k, chi2_red=chi2_red,
                     identifiable=not thin, method="power iteration + alternating least squares",
                     n_evals=it_best + 1, seconds=time.perf_counter() - t0, notes=notes,
                     dropped=dict(d.dropped), at_bound=at_bound)


def _inverse(a: np.ndarray) -> np.ndarray:
    """(Pseudo-)inverse of a symmetric normal matrix, scaled for conditioning."""
    s = np.sqrt(np.maximum(np.diag(a), 1e-300))
    return np.linalg.pinv(a / np.outer(s, s), hermitian=True) / np.outer(s, s)


def _nodes(idx: np.ndarray, label=str) -> str:
    """Node indices as short ranges: ``0-3, 7`` (each end written by ``label``)."""
    out, start = [], None
    for i, j in enumerate(idx):
        if start is None:
            start = j
        if i + 1 == len(idx) or idx[i + 1] != j + 1:
            out.append(label(start) if start == j else f"{label(start)}-{label(j)}")
            start = None
    return ", ".join(out)
