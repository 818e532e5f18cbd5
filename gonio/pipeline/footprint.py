"""A tile's value is the mean of the BRDF over its pixels' directions, reported at their mean direction: where
the BRDF curves (a glossy lobe's peak) the mean is biased, by the second-order term of its Taylor series (the
delta method: E[f(h)] − f(E[h]) ≈ ½ tr(H Σ_h); Casella & Berger 2002, *Statistical Inference*, §5.5.4):
``H`` the Hessian of f in the half vector's (h_x, h_y) (Rusinkiewicz 1998: the variable that carries a lobe's
variation) and ``Σ_h`` the covariance of the tile's pixels' half vectors. At the default 2° tiles a GGX lobe of
α = 0.1 reads ~1 % low at its peak (so a fitted α comes out ~0.5 % wide and ks ~1.5 % low) — many times the
value's own σ there.

:func:`footprint_correction` removes it: ``H`` from a quadratic least-squares fit of the tile values over each
tile and its 8 neighbours on the tile grid (as :func:`gonio.pipeline.uncertainty.local_h_gradient` fits the
gradient), so the correction is a linear combination ``Σ_k c_k f_k`` of the values; its variance
``Σ_k c_k² σ_k²`` (the tiles' noise, independent) is added to the corrected value's (GUM, JCGM 100 §5.1.2). A
tile with fewer than 7 valid tiles around it, or neighbours that do not span (h_x, h_y), is left as it is.
"""

from __future__ import annotations

import numpy as np

from gonio.pipeline.uncertainty import _neighbour_table

__all__ = ["footprint_correction", "tile_half_moments"]

#: Least number of valid tiles (the tile and its neighbours) for the quadratic fit (6 unknowns).
MIN_TILES = 7


def tile_half_moments(h: np.ndarray, label: np.ndarray, nt: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(nt, 2)`` and covariance ``(nt, 2, 2)`` of the half vectors' (h_x, h_y) of each tile's pixels
    (``h`` (n, 3) per pixel, ``label`` its tile)."""
    cnt = np.bincount(label, minlength=nt).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx = np.bincount(label, h[:, 0], minlength=nt) / cnt
        my = np.bincount(label, h[:, 1], minlength=nt) / cnt
        dx, dy = h[:, 0] - mx[label], h[:, 1] - my[label]
        sxx = np.bincount(label, dx * dx, minlength=nt) / cnt
        sxy = np.bincount(label, dx * dy, minlength=nt) / cnt
        syy = np.bincount(label, dy * dy, minlength=nt) / cnt
    cov = np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)
    return np.stack([mx, my], -1), cov


def footprint_correction(f: np.ndarray, var: np.ndarray, h_mean: np.ndarray, h_cov: np.ndarray,
                         n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(delta, dvar)`` (nt, C) on an ``n × n`` tile grid: the bias ½ tr(H Σ_h) of each tile's mean value
    (subtract it) and the change of the value's variance when it is subtracted (the corrected value
    ``f₀ − Σ c_k f_k`` has ``(1 − c₀)² σ₀² + Σ_{k>0} c_k² σ_k²``; ``dvar`` is that minus ``σ₀²``, so ``var + dvar``
    stays ≥ 0). 0 where it cannot be estimated (module docstring)."""
    nt, chans = f.shape
    ok = np.isfinite(f).all(axis=1) & np.isfinite(h_mean).all(axis=1) & np.isfinite(var).all(axis=1)
    j, inside = _neighbour_table(n)
    # the tile itself first, then its neighbours: (9, nt)
    idx = np.concatenate([np.arange(nt)[None, :], j], axis=0)
    use = np.concatenate([ok[None, :], inside & ok[j] & ok[None, :]], axis=0)
    hm = np.where(ok[:, None], h_mean, 0.0)
    d = np.where(use[..., None], hm[idx] - hm[None, :, :], 0.0)  # (9, nt, 2)
    dx, dy = d[..., 0], d[..., 1]
    one = use.astype(np.float64)
    X = np.stack([one, dx * one, dy * one, dx * dx * one, dx * dy * one, dy * dy * one], axis=-1)  # (9, nt, 6)
    # correction = ½ tr(H Σ) = ½ (Hxx Sxx + 2 Hxy Sxy + Hyy Syy), with f ≈ a + g·d + ½ Hxx dx² + Hxy dx dy + ½ Hyy dy²:
    # coefficients b = (a, gx, gy, Hxx/2, Hxy, Hyy/2) → correction = b3 Sxx + b4 Sxy + b5 Syy
    S = np.where(ok[:, None, None], h_cov, 0.0)
    q = np.zeros((nt, 6))
    q[:, 3], q[:, 4], q[:, 5] = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    Xt = np.transpose(X, (1, 0, 2))  # (nt, 9, 6)
    XtX = np.einsum("tki,tkj->tij", Xt, Xt)
    scale = np.maximum(np.abs(XtX).max(axis=(1, 2)), 1e-300)
    good = (use.sum(axis=0) >= MIN_TILES) & ok
    good &= np.linalg.matrix_rank(XtX / scale[:, None, None], tol=1e-10) == 6 if nt else good
    delta = np.zeros((nt, chans))
    vdel = np.zeros((nt, chans))
    if not good.any():
        return delta, vdel
    g = np.flatnonzero(good)
    # c_k: the weight of each of the 9 values in the correction, c = X (XᵀX)⁻¹ q
    c = np.einsum("tki,ti->tk", Xt[g], np.linalg.solve(XtX[g], q[g][..., None])[..., 0])  # (ng, 9)
    fz, vz = np.where(ok[:, None], f, 0.0), np.where(ok[:, None], var, 0.0)  # invalid tiles weigh 0 (not NaN·0)
    fv = fz[idx[:, g]].transpose(1, 0, 2)  # (ng, 9, C)
    vv = vz[idx[:, g]].transpose(1, 0, 2)
    cu = c * use[:, g].T
    delta[g] = np.einsum("tk,tkc->tc", cu, fv)
    # variance of the corrected value f0 − Σ c_k f_k: (1 − c0)² σ0² + Σ_{k>0} c_k² σ_k², minus σ0² (already counted)
    vdel[g] = ((1 - cu[:, :1]) ** 2 - 1) * vv[:, 0] + np.einsum("tk,tkc->tc", cu[:, 1:] ** 2, vv[:, 1:])
    return delta, vdel
