"""Nielsen, Jensen & Ramamoorthi 2015 ("On optimal, minimal BRDF sampling for reflectance acquisition", ACM TOG
34(6), article 186), as published — the baseline ``benchmarks sparse`` compares gonio's prior with, trained on
the same materials, on the same grid, with the same candidate directions and direction budget.

1. Mapping (their §4): ρ' = ln((ρ·cos θi·cos θo + ε)/(ρ_ref·cos θi·cos θo + ε)), ε = 10⁻³, ρ_ref the median of
   the training tables; each colour channel of each material is one column of the data matrix.
2. Principal components of the mean-centred mapped columns (their §4.1): an orthonormal basis Q.
3. Sampling directions (their §5): chosen greedily so that the rows of Q at the sampled directions, restricted to
   the first k components at the k-th pick, have the smallest condition number.
4. Reconstruction (their §6): ridge regression of the coefficients of the first k ≤ n components from the n
   sampled values, c = (Q_sᵀQ_s + η I)⁻¹ Q_sᵀ (x_s − μ_s), x = μ + Q c, unmapped at the grid nodes. (With all
   components and 20 samples the regression is hopeless — 0.7–1.3 cube-root error on the real materials.)

Departures forced by the setting, the same for both methods: tables live on the prior's grid (not MERL's
1.46 M cells) and are interpolated to other directions in ln(f + ε) (:func:`predict_nodes` returns node values;
:func:`interpolate` takes them anywhere); the ridge parameter η and the number of components k (their fixed
choices do not carry over to this data and basis scale) are chosen per fold and budget on the training
materials only (:func:`choose_eta`: half of them build the components, the other half is reconstructed, and
vice versa). The condition number is computed from the Gram matrix of
the sampled rows (λmax/λmin = cond²: the same ranking).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.prior.grid import PriorGrid
from gonio.prior.mapping import EPSILON, cos_weight

__all__ = ["NielsenModel", "build_nielsen", "select_condition", "reconstruct_coefficients", "predict_nodes",
           "interpolate", "choose_eta", "ETAS", "KS"]

#: Ridge parameters :func:`choose_eta` chooses among (the basis is orthonormal over the grid's nodes, so the
#: scale of AᵀA is ~ n/G: η spans it).
ETAS = tuple(10.0 ** k for k in range(-9, 0))


@dataclass(frozen=True, eq=False)
class NielsenModel:
    grid: PriorGrid
    mean: np.ndarray  # (G,)
    basis: np.ndarray  # (G, K) orthonormal
    f_ref: np.ndarray  # (G,)
    w: np.ndarray  # (G,) cosine weight of the nodes
    eps: float = EPSILON


def _mapped(f, f_ref, w, eps):
    """ρ' of their §4 (``f`` (..., G) or with RGB last, ``f_ref`` and ``w`` broadcasting)."""
    return np.log(np.maximum(f * w + eps, 0.5 * eps)) - np.log(f_ref * w + eps)


def build_nielsen(values: np.ndarray, grid: PriorGrid, n_components: int | None = None,
                  eps: float = EPSILON) -> NielsenModel:
    """Steps 1–2 from filled node values ``values`` (M, G, 3) (:func:`gonio.prior.build.fill_nodes`)."""
    wi, wo = grid.node_directions()
    w = cos_weight(wi, wo)
    cols = np.moveaxis(np.asarray(values, dtype=np.float64), 2, 1).reshape(-1, grid.size)  # (3M, G)
    f_ref = np.maximum(np.median(cols, axis=0), 0.0)
    x = _mapped(cols, f_ref[None, :], w[None, :], eps).T  # (G, 3M)
    mu = x.mean(axis=1)
    xc = x - mu[:, None]
    lam, vec = np.linalg.eigh(xc.T @ xc)
    order = np.argsort(lam)[::-1]
    lam, vec = lam[order], vec[:, order]
    keep = lam > lam[0] * 1e-12
    if n_components is not None:
        keep[n_components:] = False
    basis = (xc @ vec[:, keep]) / np.sqrt(lam[keep])[None, :]
    return NielsenModel(grid, mu, basis, f_ref, w, eps)


def select_condition(model: NielsenModel, h, n: int) -> np.ndarray:
    """Step 3: indices of ``n`` candidates (rows of the sparse weights ``h`` (N, G)), the k-th chosen to minimise
    the condition number of the sampled rows of the first k components."""
    a = np.asarray(h @ model.basis)
    chosen: list[int] = []
    avail = np.ones(len(a), dtype=bool)
    for k in range(1, min(n, len(a)) + 1):
        kk = min(k, a.shape[1])
        prev = a[chosen, :kk]
        # condition number² of the sampled rows = λmax/λmin of their Gram matrix (kk × kk), for every candidate
        gram = (prev.T @ prev)[None] + a[:, :kk, None] * a[:, None, :kk]
        lam = np.linalg.eigvalsh(gram)
        with np.errstate(divide="ignore", invalid="ignore"):
            cond = lam[:, -1] / lam[:, 0]
        cond = np.where(np.isfinite(cond) & (lam[:, 0] > 0) & avail, cond, np.inf)
        j = int(np.argmin(cond)) if np.isfinite(cond).any() else int(np.argmax(avail))
        chosen.append(j)
        avail[j] = False
    return np.array(chosen, dtype=np.int64)


def _observed(model: NielsenModel, h, f):
    """Mapped observations (n, 3) at directions with trilinear weights ``h`` (their mapping with the interpolated
    cosine weight and reference, consistent with interpolating ρ' between nodes)."""
    w = h @ model.w
    return _mapped(np.asarray(f, dtype=np.float64), (h @ model.f_ref)[:, None], w[:, None], model.eps) - \
        (h @ model.mean)[:, None]


def reconstruct_coefficients(model: NielsenModel, h, f, eta: float, k: int | None = None) -> np.ndarray:
    """Step 4: ridge coefficients (3, K) from values ``f`` (n, 3) at directions with weights ``h`` (n, G), of
    the first ``k`` components (the others 0; default all)."""
    kk = model.basis.shape[1] if k is None else min(int(k), model.basis.shape[1])
    a = np.asarray(h @ model.basis[:, :kk])
    y = _observed(model, h, f)
    c = np.zeros((3, model.basis.shape[1]))
    c[:, :kk] = np.linalg.solve(a.T @ a + eta * np.eye(kk), a.T @ y).T
    return c


def predict_nodes(model: NielsenModel, coef: np.ndarray) -> np.ndarray:
    """BRDF at the nodes (3, G) from coefficients (3, K): ρ' unmapped where w > 0, continued below the horizon as
    the data were (:func:`gonio.prior.build.fill_nodes`)."""
    from gonio.prior.build import fill_nodes

    u = model.mean[None, :] + coef @ model.basis.T
    w = model.w
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        f = ((model.f_ref * w + model.eps) * np.exp(u) - model.eps) / w
    f = np.where(w > 0, np.maximum(np.nan_to_num(f, nan=0.0, posinf=1e6), 0.0), np.nan)
    return fill_nodes(f.T[None], model.grid)[0].T


def interpolate(f_nodes: np.ndarray, h, eps: float = EPSILON) -> np.ndarray:
    """Node values (3, G) at directions with weights ``h`` (n, G), interpolated in ln(f + ε): (n, 3)."""
    return np.maximum(np.exp(h @ np.log(np.maximum(f_nodes, 0.0) + eps).T) - eps, 0.0)


#: Numbers of components :func:`choose_eta` chooses among (at most the number of samples).
KS = (2, 3, 5, 8, 10, 12, 15, 20, 25, 30)


def choose_eta(values: np.ndarray, grid: PriorGrid, h, order, ns, etas=ETAS, ks=KS) -> dict:
    """``{n: (η, k)}``: the ridge parameter and number of components for each budget in ``ns``, chosen on
    training node values ``values`` (M, G, 3) alone: two halves, each reconstructed from its own values at the
    directions ``order`` (candidate rows of ``h``; the first n for budget n) under the other half's components;
    the pair with the smallest coefficient error (the mapped error over the nodes, up to what no component
    holds: the basis is orthonormal; dropped components count in full)."""
    m = len(values)
    halves = (np.arange(0, m, 2), np.arange(1, m, 2))
    ns = sorted(set(int(n) for n in ns))
    grid_k = {n: [k for k in ks if k <= n] or [n] for n in ns}
    err = {n: np.zeros((len(grid_k[n]), len(etas))) for n in ns}
    for fit_idx, val_idx in (halves, halves[::-1]):
        mod = build_nielsen(values[fit_idx], grid)
        for n in ns:
            hs = h[order[:n]]
            a_all = np.asarray(hs @ mod.basis)  # (n, K): the sampled rows, once per budget
            f_obs = np.stack([interpolate(v.T, hs) for v in values[val_idx]])  # (V, n, 3)
            y = np.concatenate([_observed(mod, hs, f) for f in f_obs], axis=1)  # (n, 3V)
            c_true = np.concatenate([(mod.basis.T @ (_mapped(v, mod.f_ref[:, None], mod.w[:, None], mod.eps)
                                                     - mod.mean[:, None])) for v in values[val_idx]], axis=1)
            for a, k in enumerate(grid_k[n]):
                ak = a_all[:, :min(k, a_all.shape[1])]
                kk = ak.shape[1]
                tail = float(np.sum(c_true[kk:] ** 2))  # the components left out count in full
                for i, eta in enumerate(etas):
                    c = np.linalg.solve(ak.T @ ak + eta * np.eye(kk), ak.T @ y)
                    err[n][a, i] += float(np.sum((c - c_true[:kk]) ** 2)) + tail
    out = {}
    for n in ns:
        a, i = np.unravel_index(int(np.argmin(err[n])), err[n].shape)
        out[n] = (float(etas[i]), int(grid_k[n][a]))
    return out
