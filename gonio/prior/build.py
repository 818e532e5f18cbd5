"""Learning a :class:`gonio.prior.model.Prior` from measured materials.

Method (Nielsen, Jensen & Ramamoorthi 2015, §4, with a Bayesian calibration of ours):

1. each material's BRDF at the grid's nodes, ``F`` (M, G, 3) (:func:`node_values`: any source
   :func:`gonio.load` reads — MERL ``.binary``, RGL ``.bsdf``, gonio NPZ with a table);
2. nodes below the horizon (and cells a table did not measure) take the value of the nearest node above it
   along θd, then θh (:func:`fill_nodes`): a constant continuation, so that interpolating near the horizon
   uses only measured values;
3. ``f_ref`` = the per-node median over all materials and channels; every channel of every material mapped
   (:func:`gonio.prior.mapping.to_mapped`) is one column of ``X`` (G, 3M) — the channels are observations
   sharing one basis, as in Nielsen et al.;
4. principal components of the centred columns through their Gram matrix (3M × 3M, cheap when 3M ≪ G):
   ``Xcᵀ Xc = V Λ Vᵀ``, basis ``B = Xc V Λ^(-1/2)`` (orthonormal), first K kept;
5. variances by leave-one-material-out (:func:`loo_calibration`): the prior must describe a material it was
   *not* built from, and principal components overfit the materials they come from (their in-sample
   variances are too small for a new one). For each material, the components of the others (from the same
   Gram matrix) give its held-out coefficients ``a`` and residual ``r``; ``s²_k`` = mean of ``a_k²`` over held-out
   columns (at least the in-sample λ_k/(N−1)) and ``τ²_g`` = mean of ``r_g²`` — the part of a new material no
   component explains, per node. With fewer than 4 materials the in-sample values are used.
"""

from __future__ import annotations

import time
from typing import Sequence

import numpy as np

from gonio.errors import DataError
from gonio.prior.grid import DEFAULT_GRID, PriorGrid
from gonio.prior.mapping import EPSILON, cos_weight, to_mapped
from gonio.prior.model import Prior

__all__ = ["node_values", "cell_weight", "mapped_columns", "fill_nodes", "build_prior", "build_from_sources", "loo_calibration",
           "MAX_COMPONENTS"]

#: Most principal components kept (the shipped prior's size: G × K float16).
MAX_COMPONENTS = 96
#: Largest fraction of a source's valid nodes that may lack a value (unmeasured table cells).
MAX_MISSING = 0.2


def node_values(source, grid: PriorGrid = DEFAULT_GRID) -> np.ndarray:
    """The BRDF (1/sr, RGB) of a gonio source (a path or :class:`gonio.io.source.Measured`) at the grid's
    nodes, ``(G, 3)``; NaN where the source has no value. :class:`DataError` when more than
    :data:`MAX_MISSING` of the nodes above the horizon have none (a sparse measurement cannot teach a prior)."""
    from gonio.io.source import Measured, load_source

    m = source if isinstance(source, Measured) else load_source(source)
    wi, wo = grid.node_directions()
    valid = cos_weight(wi, wo) > 0  # below the horizon a table has no value (and half vectors may not exist)
    f = np.full((grid.size, 3), np.nan)
    f[valid] = np.asarray(m.eval(wi[valid], wo[valid]), dtype=np.float64).reshape(-1, 3)
    missing = ~np.isfinite(f).all(axis=1) & valid
    if missing.sum() > MAX_MISSING * valid.sum():
        raise DataError(f"{m.path}: no value at {100 * missing.sum() / valid.sum():.0f} % of the prior's grid (a prior "
                        "is built from full tables; `gonio reconstruct` a sparse measurement first)")
    return f


def cell_weight(grid: PriorGrid) -> np.ndarray:
    """Each node's share of the MERL cells above the horizon (its trilinear weights summed over them), (G,)."""
    out = np.zeros(grid.size)
    for i in range(0, 90, 15):  # 15 θh rows at a time: ~250k cells, bounded memory
        out += np.asarray(grid.weights_merl(slice(i, i + 15)).sum(axis=0)).ravel()
    return out / out.sum()


def fill_nodes(values: np.ndarray, grid: PriorGrid) -> np.ndarray:
    """``values`` (M, G, 3) with nodes below the horizon and missing (NaN) values replaced by the nearest
    valid node at lower θd (same θh, φd), then at lower θh; what is still missing takes the mean of the other
    materials at that node (module docstring, step 2)."""
    wi, wo = grid.node_directions()
    v = np.array(values, dtype=np.float64)
    v[:, cos_weight(wi, wo) <= 0] = np.nan
    v = v.reshape((len(v),) + grid.shape + (3,))
    for j in range(1, grid.n_d):
        hole = np.isnan(v[:, :, j])
        v[:, :, j][hole] = v[:, :, j - 1][hole]
    for i in range(1, grid.n_h):
        hole = np.isnan(v[:, i])
        v[:, i][hole] = v[:, i - 1][hole]
    v = v.reshape(len(v), grid.size, 3)
    if np.isnan(v).any():
        with np.errstate(invalid="ignore"):
            fill = np.nan_to_num(np.nanmean(v, axis=(0, 2)))
        v = np.where(np.isnan(v), fill[None, :, None], v)
    return v


def mapped_columns(values: np.ndarray, f_ref: np.ndarray, eps: float = EPSILON) -> np.ndarray:
    """``X`` (G, 3M): column ``3m + c`` is channel c of material m mapped (:func:`gonio.prior.mapping.to_mapped`)."""
    x = to_mapped(np.asarray(values, dtype=np.float64), f_ref[None, :, None], eps)  # (M, G, 3)
    return np.ascontiguousarray(np.moveaxis(x, 1, 0).reshape(len(f_ref), -1))


def _pca(gram: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Largest ``k`` eigenpairs ``(λ, V)`` of a centred Gram matrix, λ > 0 only, descending."""
    lam, vec = np.linalg.eigh(gram)
    order = np.argsort(lam)[::-1]
    lam, vec = lam[order], vec[:, order]
    keep = lam > lam[0] * 1e-12
    keep[k:] = False
    return lam[keep], vec[:, keep]


def _centred_gram(gu: np.ndarray) -> np.ndarray:
    """Gram matrix of mean-centred columns from the Gram matrix ``gu`` of the raw columns."""
    r = gu.mean(axis=0)
    return gu - r[None, :] - r[:, None] + r.mean()


def loo_calibration(x: np.ndarray, n_materials: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Held-out coefficient variances (k,) and per-node residual variances (G,) by leaving each material's
    3 columns out of ``x`` (G, 3M) in turn (module docstring, step 4); all from the Gram matrix of ``x``
    plus one (G × 3M)·(3M) product per fold."""
    g, n = x.shape
    gu = x.T @ x
    a2 = np.zeros(k)
    a2_n = np.zeros(k)
    r2 = np.zeros(g)
    for m in range(n_materials):
        out = np.arange(3 * m, 3 * m + 3)
        tr = np.setdiff1d(np.arange(n), out)
        lam, vec = _pca(_centred_gram(gu[np.ix_(tr, tr)]), k)
        # Xc_trᵀ (x_out − μ) from Gram entries: Xc_tr = X_tr − μ 1ᵀ
        cross = gu[np.ix_(tr, out)] - gu[np.ix_(tr, tr)].mean(axis=1)[:, None]
        cross = cross - cross.mean(axis=0)[None, :]
        coef = (vec.T @ cross) / np.sqrt(lam)[:, None]  # (k', 3): held-out coefficients
        beta = vec @ (coef / np.sqrt(lam)[:, None])  # (n_tr, 3): B a = Xc_tr β = X_tr β − μ (1ᵀβ), μ = X_tr 1/n_tr
        # residual x_out − μ − Xc_tr β as one product with the whole of x (no copy of the training columns)
        mix = np.zeros((n, 3))
        mix[tr] = -beta - (1.0 - beta.sum(axis=0))[None, :] / len(tr)
        mix[out, np.arange(3)] += 1.0
        resid = x @ mix
        kk = len(lam)
        a2[:kk] += np.sum(coef ** 2, axis=1)
        a2_n[:kk] += 3
        r2 += np.sum(resid ** 2, axis=1)
    with np.errstate(invalid="ignore"):
        s2 = np.where(a2_n > 0, a2 / np.maximum(a2_n, 1), 0.0)
    return s2, r2 / (3 * n_materials)


def build_prior(values: np.ndarray, names: Sequence[str], grid: PriorGrid = DEFAULT_GRID, *,
                n_components: int | None = None, eps: float = EPSILON, calibrate: bool = True,
                metadata: dict | None = None, weight: np.ndarray | None = None) -> Prior:
    """A prior from the node values ``values`` (M, G, 3) of M materials named ``names`` (module docstring).

    ``n_components``: K (default min(3M − 1, :data:`MAX_COMPONENTS`)). ``calibrate``: leave-one-out variances
    (M ≥ 4). ``weight``: the nodes' cell shares (default :func:`cell_weight`, about a second)."""
    t0 = time.perf_counter()
    v = np.asarray(values, dtype=np.float64)
    m = v.shape[0]
    if v.ndim != 3 or v.shape[1:] != (grid.size, 3):
        raise DataError(f"prior: node values of shape {v.shape}, expected (M, {grid.size}, 3)")
    if m < 2:
        raise DataError(f"prior: {m} material(s): a prior needs at least 2")
    if len(names) != m:
        raise DataError(f"prior: {len(names)} names for {m} materials")
    v = fill_nodes(v, grid)
    f_ref = np.maximum(np.median(np.moveaxis(v, 2, 1).reshape(-1, grid.size), axis=0), 0.0)
    x = mapped_columns(v, f_ref, eps)
    n = x.shape[1]
    k = min(n - 1, MAX_COMPONENTS) if n_components is None else int(n_components)
    if not 1 <= k <= n - 1:
        raise DataError(f"prior: n_components = {k}: must be in [1, {n - 1}] for {m} materials")
    mu = x.mean(axis=1)
    xc = x - mu[:, None]
    lam, vec = _pca(xc.T @ xc, k)
    k = len(lam)
    basis = (xc @ vec) / np.sqrt(lam)[None, :]
    s2_in = lam / (n - 1)
    resid = xc - basis @ (basis.T @ xc)
    tau2_in = np.mean(resid ** 2, axis=1)
    total = float(np.sum(xc ** 2))
    how = "in-sample PCA variances (fewer than 4 materials: no leave-one-out)"
    s2, tau2 = s2_in, tau2_in
    if calibrate and m >= 4:
        s2_loo, tau2_loo = loo_calibration(x, m, k)
        s2 = np.maximum(s2_in, s2_loo[:k])
        tau2 = np.maximum(tau2_in, tau2_loo)
        how = (f"leave-one-material-out: held-out coefficient variances {np.median(s2 / s2_in):.2g}× the in-sample "
               f"ones (median), residual variance {np.sum(tau2_loo) / max(np.sum(tau2_in), 1e-300):.2g}× (sum)")
    meta = {"name": None, "n_materials": m, "variance_kept": float(np.sum(lam) / total) if total > 0 else 1.0,
            "calibration": how, "build_seconds": None, **(metadata or {})}
    prior = Prior(grid=grid, mean=mu, basis=basis, variance=s2, residual=tau2, f_ref=f_ref,
                  weight=cell_weight(grid) if weight is None else weight, eps=eps, materials=tuple(names),
                  metadata=meta)
    prior.metadata["build_seconds"] = round(time.perf_counter() - t0, 2)
    return prior


def build_from_sources(sources: Sequence, grid: PriorGrid = DEFAULT_GRID, **kw) -> Prior:
    """:func:`build_prior` from gonio sources (paths or :class:`~gonio.io.source.Measured`), each read with
    :func:`gonio.load`; the materials are named by their file names."""
    from pathlib import Path

    values = np.stack([node_values(s, grid) for s in sources])
    names = [Path(getattr(s, "path", s)).stem for s in sources]
    meta = dict(kw.pop("metadata", None) or {})
    meta.setdefault("sources", [str(getattr(s, "path", s)) for s in sources])
    return build_prior(values, names, grid, metadata=meta, **kw)
