"""A tile's value is the mean of the BRDF over its pixels' directions, reported at their mean direction: where
the BRDF curves (a glossy lobe's peak) the mean is biased, by the second-order term of its Taylor series (the
delta method: E[f(h)] − f(E[h]) ≈ ½ tr(H Σ_h); Casella & Berger 2002, *Statistical Inference*, §5.5.4):
``H`` the Hessian of f in the half vector's (h_x, h_y) (Rusinkiewicz 1998: the variable that carries a lobe's
variation) and ``Σ_h`` the covariance of the tile's pixels' half vectors. At the default 2° tiles a GGX lobe of
α = 0.1 reads 1–3 % low at its peak and up to 1 % high on its flanks — many times the value's own σ there.

:func:`footprint_correction` removes it. The local model is fitted by least squares to the tile values of a 3 × 3
block of the tile grid (6 unknowns, 9 values): the tile's own block when it has all 8 neighbours, the block of the
nearest tile that has them for a tile on the grid's edge or corner (the grid's edge is where a pose's highlight
often lies; its Hessian is then the block's, the quadratic model extrapolated by one tile).

* **Where the block's values are positive, the model is quadratic in g = ln f** (a lobe's logarithm is close to
  quadratic over a block several tiles wide: exactly so for a Gaussian lobe, to ~10 % of the curvature for a GGX
  lobe of α = 0.1, whereas f itself is not — a quadratic fitted to f underestimates the peak's curvature by
  ~25 % there). For ``f = e^g``, ``E[f] ≈ f(h̄) (1 + c)`` with ``c = ½ tr((H_g + ∇g ∇gᵀ) Σ_h)`` (the delta method
  for ``e^g``: ``∇²e^g = e^g (H_g + ∇g ∇gᵀ)``), so the value at the mean direction is ``f̄ / (1 + c)``.
* Elsewhere (a value ≤ 0: noise on a dark tile) the model is quadratic in f: ``δ = ½ tr(H_f Σ_h)``.

The neighbours' values are tile means too, biased by their own footprints (flattening the block, so the curvature
is underestimated): the fit is repeated :data:`ITERATIONS` times on the values corrected by the previous pass (a
fixed-point deconvolution; the change after the third pass is < 1 % of the correction).

The correction's variance is propagated to first order from the block's values (GUM JCGM 100:2008 §5.1.2, their
noise independent): the corrected value ``f̄_t − δ(f_block)`` has variance ``Σ_k u_k² σ_k²`` with
``u_k = ∂(f̄_t − δ)/∂f_k``; what it adds to the tile's own ``σ_t²`` is returned. A tile with fewer than
:data:`MIN_TILES` valid values in its block, or whose block's half vectors do not span a quadratic, or a grid
smaller than 3 × 3, is left as it is.

Measured on the default session's 38 poses with exact per-pixel values (perfect rig, GGX α = 0.1): the peak tiles
(θh < 1°) read −0.62 % on average uncorrected by the former quadratic-in-f correction of interior tiles only,
−0.13 % now; the fitted α was +0.25 % high, +0.06 % now (``tests/pipeline/test_footprint.py``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["footprint_correction", "tile_half_moments", "ITERATIONS", "MIN_TILES"]

#: Least number of valid tiles in a block for the quadratic fit (6 unknowns).
MIN_TILES = 7
#: Passes of the fit on the values corrected by the previous pass (module docstring).
ITERATIONS = 3


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


def _blocks(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Per tile of an ``n × n`` grid (n ≥ 3): the 9 tiles of the 3 × 3 block centred on the nearest tile that has all
    8 neighbours (itself when it has them; shifted inward by one on the grid's edges), ``(nt, 9)``, and the tile's
    position in its block, ``(nt,)``. Depends on n only (cached)."""
    hit = _BLOCKS.get(n)
    if hit is None:
        iy, ix = np.divmod(np.arange(n * n), n)
        cy, cx = np.clip(iy, 1, n - 2), np.clip(ix, 1, n - 2)
        oy, ox = np.divmod(np.arange(9), 3)
        idx = (cy[:, None] + oy[None, :] - 1) * n + (cx[:, None] + ox[None, :] - 1)
        own = (iy - cy + 1) * 3 + (ix - cx + 1)
        idx.flags.writeable = own.flags.writeable = False
        hit = _BLOCKS[n] = (idx, own)
    return hit


_BLOCKS: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def footprint_correction(f: np.ndarray, var: np.ndarray, h_mean: np.ndarray, h_cov: np.ndarray,
                         n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(delta, dvar)`` (nt, C) on an ``n × n`` tile grid: each tile's footprint bias (subtract it: the value at the
    tile's mean half vector) and what the correction adds to the value's variance (``var + dvar`` ≥ 0). 0 where it
    cannot be estimated. Model, passes and variance: the module docstring."""
    nt, chans = f.shape
    delta = np.zeros((nt, chans))
    vdel = np.zeros((nt, chans))
    if n < 3 or nt != n * n:
        return delta, vdel
    ok = (np.isfinite(f).all(axis=1) & np.isfinite(h_mean).all(axis=1) & np.isfinite(var).all(axis=1)
          & np.isfinite(h_cov).all(axis=(1, 2)))
    idx, own = _blocks(n)                                   # (nt, 9), (nt,)
    use = ok[idx] & ok[:, None]
    hm = np.where(ok[:, None], h_mean, 0.0)
    d = np.where(use[..., None], hm[idx] - hm[:, None, :], 0.0)  # (nt, 9, 2), centred on the tile's own mean
    dx, dy = d[..., 0], d[..., 1]
    one = use.astype(np.float64)
    X = np.stack([one, dx * one, dy * one, dx * dx * one, dx * dy * one, dy * dy * one], axis=-1)  # (nt, 9, 6)
    XtX = np.einsum("tki,tkj->tij", X, X)
    scale = np.maximum(np.abs(XtX).max(axis=(1, 2)), 1e-300)
    good = (use.sum(axis=1) >= MIN_TILES) & ok
    good &= np.linalg.matrix_rank(XtX / scale[:, None, None], tol=1e-10) == 6
    if not good.any():
        return delta, vdel
    g = np.flatnonzero(good)
    rows = np.arange(len(g))
    # b = P y: coefficients (a, g_x, g_y, H_xx/2, H_xy, H_yy/2) of the block's values y, at the tile's own mean
    P = np.linalg.solve(XtX[g], np.transpose(X[g], (0, 2, 1)))  # (ng, 6, 9)
    S = h_cov[g]
    sxx, sxy, syy = S[:, 0, 0, None], S[:, 0, 1, None], S[:, 1, 1, None]
    fz, vz = np.where(ok[:, None], f, 0.0), np.where(ok[:, None], var, 0.0)
    fv, vv = fz[idx[g]], vz[idx[g]]                         # (ng, 9, C)
    ft = fz[g]
    usg = use[g][..., None]
    logs = (np.where(usg, fv, 1.0) > 0).all(axis=1)         # (ng, C): the block's values all positive
    pos = np.where(usg & (fv > 0), fv, 1.0)
    y0 = np.where(logs[:, None, :], np.log(pos), fv)
    corr = np.zeros((nt, chans))  # each tile's correction on the model's scale: ln(1 + c), or δ
    for _ in range(ITERATIONS):
        b = np.einsum("tik,tkc->tic", P, np.where(usg, y0 - corr[idx[g]], 0.0))  # (ng, 6, C)
        b1, b2 = b[:, 1], b[:, 2]
        c = b[:, 3] * sxx + b[:, 4] * sxy + b[:, 5] * syy  # ½ tr(H Σ)
        c = c + np.where(logs, 0.5 * (sxx * b1 ** 2 + 2 * sxy * b1 * b2 + syy * b2 ** 2), 0.0)  # + ½ ∇gᵀ Σ ∇g
        corr[g] = np.where(logs, np.log1p(c), c)
    delta[g] = np.where(logs, ft * c / (1 + c), c)
    # first-order propagation at the fixed point (module docstring): W = ∂c_t/∂y_k over the block, then through the
    # neighbours' own corrections, dc = G_f df − G_y Φ' dc → dc = (I + G_y Φ')⁻¹ G_f df
    dc_db = np.zeros_like(b)
    dc_db[:, 1] = np.where(logs, sxx * b1 + sxy * b2, 0.0)
    dc_db[:, 2] = np.where(logs, sxy * b1 + syy * b2, 0.0)
    dc_db[:, 3], dc_db[:, 4], dc_db[:, 5] = sxx, sxy, syy
    W = np.einsum("tic,tik->tkc", dc_db, P) * usg             # (ng, 9, C)
    Gy = np.zeros((chans, nt, nt))
    Gf = np.zeros((chans, nt, nt))
    cols = idx[g]                                            # (ng, 9)
    for k in range(9):  # a block's 9 tiles are distinct: one (row, column) per k
        Gy[:, g, cols[:, k]] = W[:, k].T
        Gf[:, g, cols[:, k]] = (W[:, k] * np.where(logs, 1.0 / pos[:, k], 1.0)).T
    cf = np.zeros((nt, chans))
    cf[g] = c
    lg = np.zeros((nt, chans), bool)
    lg[g] = logs
    phi = np.zeros((nt, chans))
    phi[g] = np.where(logs, 1.0 / (1 + c), 1.0)
    Jc = np.linalg.solve(np.eye(nt)[None] + Gy * phi.T[:, None, :], Gf)  # (C, nt, nt)
    d1 = np.where(lg, fz / (1 + cf) ** 2, 1.0).T[:, :, None]  # ∂δ/∂c
    d2 = np.where(lg, cf / (1 + cf), 0.0).T                  # ∂δ/∂f_t (the log model's f̄_t factor)
    Jz = np.eye(nt)[None] - d1 * Jc
    Jz[:, np.arange(nt), np.arange(nt)] -= d2
    vdel[g] = (np.einsum("ctk,kc->tc", Jz ** 2, vz) - vz)[g]
    return delta, vdel
