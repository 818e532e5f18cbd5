"""Numerical pieces of the fit: bounded linear least squares for the colours, and the variable-projection
objective of the shape parameters.

Variable projection (Golub & Pereyra, "The Differentiation of Pseudo-Inverses and Nonlinear Least
Squares Problems Whose Variables Separate", SIAM J. Numer. Anal. 10(2), 1973): for residuals
r(a, s) = √w (f₀(s) + B(s) a − y) that are linear in a, the minimum over (a, s) equals the minimum over
s of the *projected* cost min_a ‖r(a, s)‖², and a(s) is a small least-squares solve.
"""

from __future__ import annotations

import itertools

import numpy as np


def bounded_lsq(G: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Minimize ½ aᵀGa − bᵀa subject to lo ≤ a ≤ hi, for a small K×K positive semi-definite G.

    Exact: the unconstrained solution if feasible, else enumeration of the 3ᴷ active sets (each
    variable free, at its lower or at its upper bound), solving the free subsystem by least squares
    (Lawson & Hanson, *Solving Least Squares Problems*, 1974, ch. 23, for the KKT view). K ≤ 4 here.
    """
    K = b.shape[0]
    a = np.linalg.lstsq(G, b, rcond=None)[0] if K else b
    if np.all(a >= lo) and np.all(a <= hi):
        return a
    best, best_val = None, np.inf
    options = []
    for k in range(K):
        opts = ["free"]
        if np.isfinite(lo[k]):
            opts.append("lo")
        if np.isfinite(hi[k]):
            opts.append("hi")
        options.append(opts)
    for combo in itertools.product(*options):
        x = np.zeros(K)
        free = np.array([c == "free" for c in combo])
        for k, c in enumerate(combo):
            if c == "lo":
                x[k] = lo[k]
            elif c == "hi":
                x[k] = hi[k]
        if free.any():
            rhs = b[free] - G[np.ix_(free, ~free)] @ x[~free]
            x[free] = np.linalg.lstsq(G[np.ix_(free, free)], rhs, rcond=None)[0]
            if np.any(x[free] < lo[free] - 1e-12) or np.any(x[free] > hi[free] + 1e-12):
                continue
        val = 0.5 * x @ G @ x - b @ x
        if val < best_val:
            best, best_val = x, val
    return np.clip(best, lo, hi)


class Projection:
    """The projected cost of the shape parameters for a linear loss with weights ``w`` (N, 3).

    ``__call__(shape)`` returns ``(cost, colour (K, 3))`` with cost = ½ Σ w (f₀ + Σ aₖBₖ − y)²
    minimized over the bounded colours a. The Gram matrices are formed per channel, so one evaluation
    costs one basis evaluation plus O(N K²) flops.
    """

    def __init__(self, basis, w: np.ndarray, y: np.ndarray, lo: np.ndarray, hi: np.ndarray):
        self.basis, self.w, self.y, self.lo, self.hi = basis, w, y, lo, hi
        self.n_evals = 0
        # Weights equal across channels (cosine loss): one Gram matrix serves R, G and B.
        self.w1 = w[:, 0].copy() if np.array_equal(w[:, 0], w[:, 1]) and np.array_equal(w[:, 0], w[:, 2]) else None
        self._c0 = np.einsum("nc,nc,nc->c", y, w, y)
        self._wb_cache: dict[int, tuple] = {}

    def normal_equations(self, shape):
        f0, cols = self.basis(shape)
        if self.w1 is not None and all(B.ndim == 1 for B in cols) and getattr(f0, "is_zero", False):
            # Shared Gram matrix; w·Bₖ is cached for bases that did not change (a Lambert term).
            wb = []
            for k, B in enumerate(cols):
                hit = self._wb_cache.get(k)
                if hit is None or hit[0] is not B:
                    hit = (B, B * self.w1)
                    self._wb_cache[k] = hit
                wb.append(hit[1])
            K = len(cols)
            G1 = np.empty((K, K))
            for k in range(K):
                for l in range(k, K):
                    G1[k, l] = G1[l, k] = wb[k] @ cols[l]
            b = np.stack([x @ self.y for x in wb])
            return np.broadcast_to(G1, (3, K, K)), b.T, self._c0
        t = self.y - f0
        K = len(cols)
        G = np.empty((3, K, K))
        b = np.empty((3, K))
        c0 = np.empty(3)
        for c in range(3):
            wc = self.w[:, c]
            Bc = np.stack([(B if B.ndim == 1 else B[:, c]) for B in cols], axis=1)
            WB = Bc * wc[:, None]
            G[c] = Bc.T @ WB
            b[c] = WB.T @ t[:, c]
            c0[c] = t[:, c] @ (wc * t[:, c])
        return G, b, c0

    def __call__(self, shape) -> tuple[float, np.ndarray]:
        self.n_evals += 1
        G, b, c0 = self.normal_equations(shape)
        colour = np.empty((b.shape[1], 3))
        cost = 0.0
        for c in range(3):
            a = bounded_lsq(G[c], b[c], self.lo, self.hi)
            colour[:, c] = a
            cost += 0.5 * max(c0[c] - 2.0 * b[c] @ a + a @ G[c] @ a, 0.0)
        return cost, colour
