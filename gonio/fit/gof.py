"""Goodness of fit: does a fitted model describe the data to within their noise?

Two tests, on the residuals of the fit's loss (:mod:`gonio.fit.losses`):

* **χ² test** (samples with stated uncertainties): χ² = Σ ((f_m − f)/σ)² against the χ² distribution
  with m − k degrees of freedom (Press et al., *Numerical Recipes*, 3rd ed., §15.1.1, "goodness of fit";
  ``scipy.special.chdtrc``, what ``scipy.stats.chi2.sf`` computes, without importing ``scipy.stats``, which
  costs about a second per process). With thousands of residuals the test detects an excess of a few per cent, far
  below what a mis-stated σ does; a model is said not to fit when the excess is *both* significant
  (p < :data:`P_MIN`) and material (χ²_red > :data:`MAX_RATIO`, the threshold of the error inflation of
  :mod:`gonio.fit.select`).
* **Residual structure** (always; the test without uncertainties): the correlation ρ between the residual
  of each sample and that of its nearest neighbour in the isotropic (half, difference) coordinates of
  :func:`gonio.fit.metrics.data_tree` — a spatial lag-1 autocorrelation (Moran's I with nearest-neighbour
  weights; P. A. P. Moran, "Notes on continuous stochastic phenomena", Biometrika 37, 1950). Residuals
  e = s + n of a systematic part s (smooth: equal at neighbours) and independent noise n have
  ρ = var(s)/(var(s) + var(n)), so the residual variance is 1/(1 − ρ) times the noise variance (the
  neighbour-difference estimate of the noise, Rice, "Bandwidth choice for nonparametric regression",
  Ann. Stat. 12, 1984): the same ratio as χ²_red, judged against the same :data:`MAX_RATIO`, and
  significant when ρ > 3/√n (ρ's standard error under independence is 1/√n). Neighbours with the very
  same values (a sample listed twice) are skipped; sparse data make neighbours far apart, which lowers ρ
  (the test is conservative there). Without stated uncertainties a fit whose relative residual is at most
  :data:`PRACTICAL_REL` is accepted whatever its structure (noise-free data have none to compare with).

Above :data:`GOF_N` samples a seeded subset is tested (its neighbours are taken among all samples).
"""

from __future__ import annotations

import numpy as np

from gonio.samples import all_channels

__all__ = ["MAX_RATIO", "P_MIN", "PRACTICAL_REL", "GOF_N", "goodness_of_fit", "describe"]

#: Residual variance over noise variance (χ²_red, or 1/(1 − ρ)) above which a model does not fit.
MAX_RATIO = 1.5
#: Significance level of both tests.
P_MIN = 1e-3
#: Without stated uncertainties, a relative RMS residual (in the loss's measure, against the data's) at or
#: below this fits whatever its structure: exact synthetic data leave residuals of rounding size that are
#: "structured" but far below the relative accuracy a gonioreflectometer reaches at best (the 1 % of
#: :data:`gonio.fit.select.EQUIVALENCE`).
PRACTICAL_REL = 0.01
#: Largest number of samples whose residual structure is tested (a seeded subset above it).
GOF_N = 50_000


def goodness_of_fit(model_values: np.ndarray, data, loss, n_params: int, seed: int = 0) -> dict:
    """The two tests of the module docstring for model values (N, 3) at the samples of ``data``
    (:class:`gonio.fit.data.FitData`) under ``loss`` (:class:`gonio.fit.losses.Loss`):
    ``{"fits", "ratio", "test", "rho", "rho_p", "chi2", "dof", "chi2_red", "chi2_p"}``."""
    from scipy.special import chdtrc, ndtr  # the χ² and normal survival functions of scipy.stats, imported cheaply

    m = np.asarray(model_values, dtype=np.float64)
    n = len(data)
    out: dict = {"test": "chi2" if data.sigma is not None else "residual structure"}
    if data.sigma is not None:
        dof = max(3 * n - n_params, 1)
        c2 = float(np.sum(((m - data.y) / data.sigma) ** 2))
        out.update(chi2=c2, dof=dof, chi2_red=c2 / dof, chi2_p=float(chdtrc(dof, c2)))
    res = loss.residuals_of(m, data)
    rho = rho_p = None
    pairs = _neighbour_pairs(data, seed) if n >= 10 else None
    if pairs is not None:
        a, b = res[pairs[0]], res[pairs[1]]
        if a.shape[0] >= 10:
            a, b = a - a.mean(axis=0), b - b.mean(axis=0)
        den = np.sqrt(np.sum(a * a) * np.sum(b * b)) if a.shape[0] >= 10 else 0.0
        if den > 0:
            rho = float(np.sum(a * b) / den)
            rho_p = float(ndtr(-rho * np.sqrt(a.size)))
    out.update(rho=rho, rho_p=rho_p)
    if data.sigma is not None:
        ratio, p = out["chi2_red"], out["chi2_p"]
    elif rho is not None:
        ratio, p = 1.0 / max(1.0 - rho, 1e-12), rho_p
    else:
        ratio, p = None, None
    ref = loss.residuals_of(np.zeros_like(m), data)
    rel = float(np.sqrt(np.sum(res * res) / max(float(np.sum(ref * ref)), 1e-300)))
    out["ratio"], out["rel"] = ratio, rel
    misfit = ratio is not None and ratio > MAX_RATIO and p is not None and p < P_MIN
    if data.sigma is None and rel <= PRACTICAL_REL:
        misfit = False  # no stated noise, and within the accuracy of any instrument (module docstring)
    out["fits"] = not misfit
    return out


def _neighbour_pairs(data, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(i, j)``: the samples tested (all, or a seeded :data:`GOF_N` of them) and the nearest other sample of each
    whose values differ (a sample listed twice is not a neighbour) — the pairs of the residual-structure test. They
    depend on the data only, so they are found once and cached on the data (a selection tests every candidate on the
    same samples)."""
    from gonio.fit.metrics import _hd_coords, data_tree, geometry_cache

    cache = data.__dict__.setdefault("_kernel_cache", {})
    key = ("gof_pairs", int(seed))
    if key not in cache:
        n = len(data)
        geometry = geometry_cache(data)  # the samples tested and their 4 nearest: the directions decide them
        if key not in geometry:
            idx = np.arange(n)
            if n > GOF_N:
                idx = np.sort(np.random.default_rng(seed).choice(n, GOF_N, replace=False))
            nb = data_tree(data).query(_hd_coords(data.wi[idx], data.wo[idx]), k=min(4, n))[1]
            idx.setflags(write=False)
            nb.setflags(write=False)
            geometry[key] = idx, nb
        idx, nb = geometry[key]
        same = all_channels(data.y[nb] == data.y[idx][:, None, :])
        same[:, 0] |= nb[:, 0] == idx
        first = np.argmax(~same, axis=1)
        ok = ~same[np.arange(idx.size), first]
        cache[key] = (idx[ok], nb[ok, first[ok]])
    return cache[key]


def describe(g: dict) -> str:
    """One line: what was tested and the verdict."""
    if g.get("ratio") is None:
        return "goodness of fit not tested (too few samples)"
    if g["test"] == "chi2":
        what = f"chi2_red {g['chi2_red']:.4g} on {g['dof']} degrees of freedom (p = {g['chi2_p']:.2g})"
    else:
        what = (f"residuals {g['ratio']:.3g}x the noise estimated from neighbouring samples "
                f"(neighbour correlation {g['rho']:.3f}, p = {g['rho_p']:.2g})")
    return ("fits the data to within their noise: " if g["fits"] else "DOES NOT FIT the data: ") + what
