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


def shared_weights(w: np.ndarray) -> np.ndarray | None:
    """``w`` (N, 3) as one contiguous column (N,) when every channel has the same weight (the cosine
    loss: one Gram matrix then serves R, G and B), else None."""
    if w.strides[1] == 0 or (np.array_equal(w[:, 0], w[:, 1]) and np.array_equal(w[:, 0], w[:, 2])):
        return np.ascontiguousarray(w[:, 0])
    return None


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


def bounded_lsq_batch(G: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """:func:`bounded_lsq` for a stack of problems: G (..., K, K), b (..., K) -> a (..., K).

    The same exact method, vectorized over the stack and over the active sets: every active set (each variable
    free, at its lower or at its upper bound; Lawson & Hanson 1974, ch. 23) of every problem is one K×K system —
    the free rows of G a = b with each bound variable's row replaced by aₖ = its bound, which is the free block's
    system with the bound variables moved to the right-hand side — and all of them are solved in one call; each
    problem keeps its feasible candidate of least ½ aᵀGa − bᵀa (the first in active-set order on a tie).

    Most problems are settled before the enumeration: the active set that clipping the unconstrained solution
    suggests (each variable beyond a bound held at it) is solved, and its point is the minimum if it satisfies the
    Karush–Kuhn–Tucker conditions — its free variables within their bounds, and the objective's gradient Ga − b
    pointing into the box at each held one (≥ 0 at a lower bound, ≤ 0 at an upper one), which for a convex
    quadratic suffice (Nocedal & Wright, *Numerical Optimization*, 2nd ed., Thm. 16.4) — the point the enumeration
    finds, to rounding. The others (a wrong guess, a degenerate multiplier) are enumerated.
    """
    K = b.shape[-1]
    stack = b.shape[:-1]
    Gs = np.asarray(G, dtype=np.float64).reshape((-1, K, K))
    bs = np.asarray(b, dtype=np.float64).reshape((-1, K))
    best, good = _kkt_guess(Gs, bs, lo, hi)
    if not good.all():
        best[~good] = _enumerated(Gs[~good], bs[~good], lo, hi)
    return np.minimum(np.maximum(best.reshape(stack + (K,)), lo), hi)  # np.clip's answer, less overhead


def _kkt_guess(Gs: np.ndarray, bs: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(x (P, K), good (P,))``: the solution of each problem's clipped active set (:func:`bounded_lsq_batch`) and
    whether it satisfies the Karush–Kuhn–Tucker conditions (then it is the minimum)."""
    P, K = bs.shape
    none = (np.zeros((P, K)), np.zeros(P, dtype=bool))
    with np.errstate(all="ignore"):
        try:
            a = np.linalg.solve(Gs, bs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return none
        at_lo, at_hi = a < lo, a > hi
        free = ~(at_lo | at_hi)
        A = np.where(free[:, :, None], Gs, _active_sets(lo, hi, K)[3])  # free rows of G, unit rows for held ones
        rhs = np.where(free, bs, np.where(at_lo, lo, hi))
        try:
            x = np.linalg.solve(A, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return none
        grad = np.einsum("pij,pj->pi", Gs, x) - bs
        good = (np.isfinite(a).all(-1) & np.isfinite(x).all(-1)
                & np.all(~free | ((x >= lo - 1e-12) & (x <= hi + 1e-12)), axis=-1)
                & np.all(~at_lo | (grad >= 0.0), axis=-1) & np.all(~at_hi | (grad <= 0.0), axis=-1))
    return x, good


def _enumerated(Gs: np.ndarray, bs: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The enumeration of :func:`bounded_lsq_batch` (every active set of every problem), unclipped: (P, K)."""
    K = bs.shape[-1]
    free, fixval, ok_free, eye = _active_sets(lo, hi, K)  # (C, K) each, cached per pattern of finite bounds
    x = _two_colours(Gs, bs, free, fixval) if K == 2 else None
    if x is None:
        A = np.where(free[:, None, :, None], Gs[None], eye)  # (C, P, K, K): free rows of G, unit rows for bound ones
        rhs = np.where(free[:, None, :], bs[None], fixval[:, None, :])  # (C, P, K)
        try:
            x = np.linalg.solve(A, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a singular free block somewhere: the minimum-norm solution of each free block
            x = _solve_free_blocks(Gs, bs, free, fixval)
    with np.errstate(invalid="ignore"):
        ok = np.all(ok_free[:, None, :] | ((x >= lo - 1e-12) & (x <= hi + 1e-12)), axis=-1)  # (C, P)
        val = 0.5 * np.einsum("cpi,pij,cpj->cp", x, Gs, x) - np.einsum("pi,cpi->cp", bs, x)
    val = np.where(ok & ~np.isnan(val), val, np.inf)
    j = np.argmin(val, axis=0)  # the first of the least (the enumeration order of bounded_lsq)
    p = np.arange(x.shape[1])
    best = x[j, p]
    best[~np.isfinite(val[j, p])] = 0.0
    return best


def _two_colours(G: np.ndarray, b: np.ndarray, free: np.ndarray, fixval: np.ndarray) -> np.ndarray | None:
    """x (C, P, 2) of every active set of :func:`bounded_lsq_batch` for two colours (K = 2, the common case: a
    diffuse and a specular weight), in closed form: both free by Cramer's rule, one free as
    xᵢ = (bᵢ − Gᵢⱼ vⱼ)/Gᵢᵢ with the other at its bound vⱼ, none free at the bounds — where a batched LAPACK solve
    of 3² systems per problem costs ~20× more than the flops. None when a free block is singular (the caller's
    minimum-norm path then decides, as before)."""
    g00, g01, g10, g11 = G[:, 0, 0], G[:, 0, 1], G[:, 1, 0], G[:, 1, 1]
    x = np.empty((free.shape[0], G.shape[0], 2))
    det = None
    for c, (f0, f1) in enumerate(free):
        v0, v1 = fixval[c]
        if f0 and f1:
            if det is None:
                det = g00 * g11 - g01 * g10
                if not np.all(det != 0.0):
                    return None
            x[c, :, 0] = (g11 * b[:, 0] - g01 * b[:, 1]) / det
            x[c, :, 1] = (g00 * b[:, 1] - g10 * b[:, 0]) / det
        elif f0 or f1:
            i, j, v = (0, 1, v1) if f0 else (1, 0, v0)
            gii = G[:, i, i]
            if not np.all(gii != 0.0):
                return None
            x[c, :, i] = (b[:, i] - G[:, i, j] * v) / gii
            x[c, :, j] = v
        else:
            x[c, :, 0], x[c, :, 1] = v0, v1
    return x


_ACTIVE_SETS: dict[tuple, tuple[np.ndarray, ...]] = {}


def _active_sets(lo: np.ndarray, hi: np.ndarray, K: int):
    """Every active set of :func:`bounded_lsq_batch` in :func:`bounded_lsq`'s order (itertools.product of
    free / lower / upper per variable): ``free`` (C, K) bool, the bound values ``fixval`` (C, K) (0 where free),
    ``~free`` as a (C, K) mask and the K x K identity. The sets depend only on which bounds are finite, so they are
    cached per that pattern (a fit calls this thousands of times, and building them cost more than the solves; a
    linked colour's upper bound moves with the shape, so caching per bound value missed every time); the bound
    values are filled in per call."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    lo_finite, hi_finite = tuple(np.isfinite(lo).tolist()), tuple(np.isfinite(hi).tolist())
    key = (K, lo_finite, hi_finite)
    hit = _ACTIVE_SETS.get(key)
    if hit is None:
        options = [["free"] + (["lo"] if lf else []) + (["hi"] if hf else []) for lf, hf in zip(lo_finite, hi_finite)]
        combos = list(itertools.product(*options))
        C = len(combos)
        free = np.array([[c == "free" for c in combo] for combo in combos], dtype=bool).reshape(C, len(options))
        at_lo = np.array([[c == "lo" for c in combo] for combo in combos], dtype=bool).reshape(C, len(options))
        at_hi = np.array([[c == "hi" for c in combo] for combo in combos], dtype=bool).reshape(C, len(options))
        _ACTIVE_SETS[key] = hit = (free, at_lo, at_hi, ~free, np.eye(K))
    free, at_lo, at_hi, bound, eye = hit
    fixval = np.where(at_lo, lo, np.where(at_hi, hi, 0.0))
    return free, fixval, bound, eye


def _solve_free_blocks(G: np.ndarray, b: np.ndarray, free: np.ndarray, fixval: np.ndarray) -> np.ndarray:
    """x (C, P, K) of every active set of :func:`bounded_lsq_batch`, the free block solved by its pseudo-inverse
    (minimum-norm least squares) where it is singular."""
    C, P, K = free.shape[0], G.shape[0], G.shape[-1]
    x = np.broadcast_to(fixval[:, None, :], (C, P, K)).copy()
    for c in range(C):
        f = free[c]
        if not f.any():
            continue
        Gff = G[:, f][:, :, f]
        rhs = b[:, f] - np.einsum("pij,j->pi", G[:, f][:, :, ~f], fixval[c, ~f])
        try:
            x[c][:, f] = np.linalg.solve(Gff, rhs[..., None])[..., 0]
        except np.linalg.LinAlgError:
            x[c][:, f] = np.einsum("pij,pj->pi", np.linalg.pinv(Gff), rhs)
    return x


class Projection:
    """The projected cost of the shape parameters for a linear loss with weights ``w`` (N, 3).

    ``__call__(shape)`` returns ``(cost, colour (K, 3))`` with cost = ½ Σ w (f₀ + Σ aₖBₖ − y)²
    minimized over the bounded colours a. The Gram matrices are formed per channel, so one evaluation
    costs one basis evaluation plus O(N K²) flops.

    The cost is summed from the residuals themselves, not expanded as c₀ − 2bᵀa + aᵀGa: that expansion
    cancels (c₀ = Σ w y² is 10⁴–10⁶ × the cost of a χ² fit), leaving the cost noisy at ~10⁻¹² of its value,
    which is what the finite-difference gradients of the shape search see (its line searches then fail and
    the search crawls for hundreds of evaluations without progress); the normal equations lose accuracy
    the same way (Björck, *Numerical Methods for Least Squares Problems*, SIAM 1996, §2.2.1).
    """

    def __init__(self, basis, w: np.ndarray, y: np.ndarray, lo: np.ndarray, hi: np.ndarray, channels_first=None):
        self.basis, self.w, self.y, self.lo, self.hi = basis, w, y, lo, hi
        self.n_evals = 0
        self.w1 = shared_weights(w)
        self._c0 = np.einsum("nc,nc,nc->c", y, w, y)
        # channels-first copies of w and y, (3, N) C-contiguous: the caller's (``channels_first = (wT, yT)``, the
        # ones remembered on the data: Loss.weights_T_of, FitData.yT), else made on first use
        self._wT, self._yT = (None, None) if channels_first is None else channels_first

    def normal_equations(self, shape):
        f0, cols = self._last = self.basis(shape)
        if all(B.ndim == 1 for B in cols):
            # the Gram matrices and right-hand sides as blocked matrix products (weighted_gram), channels first
            if self._wT is None:
                self._wT, self._yT = np.ascontiguousarray(self.w.T), np.ascontiguousarray(self.y.T)
            tT = self._yT if getattr(f0, "is_zero", False) else self._yT - np.asarray(f0).T
            G, b = weighted_gram(cols, self._wT.T if self.w1 is None else self.w1, tT)  # _wT.T: no copy
            c0 = self._c0 if tT is self._yT else (tT * self._wT * tT).sum(axis=1)
            return G, b, c0
        K = len(cols)
        t = np.asarray(self.y) - np.asarray(f0)
        # column sums of (N, 3) products, all channels at once (no threaded BLAS for these thin products: on a
        # busy machine its threads cost more than the flops, and einsum's generic loops are slower still)
        Bs = [B[:, None] if B.ndim == 1 else B for B in cols]
        WB = [B * self.w for B in Bs]
        G = np.empty((3, K, K))
        for k in range(K):
            for l in range(k, K):
                G[:, k, l] = G[:, l, k] = (WB[k] * Bs[l]).sum(axis=0)
        b = np.stack([(x * t).sum(axis=0) for x in WB], axis=-1)
        c0 = (t * self.w * t).sum(axis=0)
        return G, b, c0

    def upper(self, shape) -> np.ndarray:
        """Upper bounds of the colours at ``shape``: the layout's, or lower where the basis bounds them by the
        shape (``basis.colour_hi``, e.g. a lobe's albedo ≤ 1, :func:`gonio.fit.kernels_abc.abc_smooth_albedo`)."""
        hook = getattr(self.basis, "colour_hi", None)
        extra = hook(shape) if hook is not None else None
        return self.hi if extra is None else np.minimum(self.hi, extra)

    #: Points remembered by :meth:`__call__` (the last ones evaluated): enough for a whole coordinate scan
    #: (:func:`gonio.fit.fit._coordinate_scan`: 2 cycles × 17 points per shape parameter), whose second cycle and
    #: later lines return to points of the first more than 32 evaluations apart. An entry is a cost and K × 3
    #: colours (~100 bytes).
    MEMO = 256

    def __call__(self, shape) -> tuple[float, np.ndarray]:
        """``(cost, colour (K, 3))`` at ``shape``. A point asked for again (a line search or a quasi-Newton step
        returning to a point, the second cycle of a coordinate scan, the search's final evaluation at its best
        point: about one request in six of a fit) is answered from the last :data:`MEMO` points: the same
        numbers, without the evaluation."""
        self.n_evals += 1
        key = np.asarray(shape, dtype=np.float64).tobytes()
        memo = self.__dict__.setdefault("_memo", {})
        hit = memo.get(key)
        if hit is not None:
            return hit[0], hit[1].copy()
        cost, colour = self._evaluate(shape)
        self._remember(key, cost, colour)
        return cost, colour.copy()

    def _remember(self, key: bytes, cost: float, colour: np.ndarray) -> None:
        """Keep ``(cost, colour)`` of the point ``key`` (its shape's bytes) among the last :data:`MEMO` points (the
        oldest forgotten first); a point already kept stays as it is."""
        memo = self.__dict__.setdefault("_memo", {})
        if key not in memo:
            if len(memo) >= self.MEMO:
                del memo[next(iter(memo))]  # the oldest
            memo[key] = (cost, colour)

    def _evaluate(self, shape) -> tuple[float, np.ndarray]:
        cost, a, _ = self._solve(shape)
        return cost, a.T.copy()

    def _solve(self, shape) -> tuple[float, np.ndarray, np.ndarray]:
        """``(cost, colours a (3, K), their upper bounds (K,))`` at ``shape``."""
        G, b, c0 = self.normal_equations(shape)
        if G.shape[0] != 3 or not G.flags.c_contiguous:
            G = np.ascontiguousarray(np.broadcast_to(G, (3,) + G.shape[-2:]))
        hi = self.upper(shape)
        with np.errstate(all="ignore"):
            try:
                a = np.linalg.solve(G, b[..., None])[..., 0]  # the three channels at once
                ok = np.isfinite(a).all(-1) & (a >= self.lo).all(-1) & (a <= hi).all(-1)
            except np.linalg.LinAlgError:
                a, ok = np.zeros_like(b), np.zeros(3, dtype=bool)
        if not ok.all():  # exact active-set solution where a bound is active (Lawson & Hanson 1974)
            a[~ok] = bounded_lsq_batch(G[~ok], b[~ok], self.lo, hi)
        return self._cost(a), a, hi

    @property
    def has_gradient(self) -> bool:
        """Whether :meth:`value_and_grad` applies: the basis supplies its derivatives
        (:func:`gonio.fit.gradient.has_derivatives`)."""
        has = self.__dict__.get("_has_gradient")
        if has is None:
            from gonio.fit.gradient import has_derivatives

            has = self._has_gradient = has_derivatives(self.basis)
        return has

    def value_and_grad(self, shape) -> tuple[float, np.ndarray]:
        """``(cost, ∂cost/∂shape (S,))`` at ``shape``: the exact gradient of the projected cost
        (:func:`gonio.fit.gradient.projection_gradient`: one evaluation and the basis's derivative vectors, where
        finite differences cost one or two evaluations per shape parameter); only where :attr:`has_gradient`.
        Counts as one evaluation; the point is remembered as :meth:`__call__` does."""
        from gonio.fit.gradient import projection_gradient

        self.n_evals += 1
        shape = np.asarray(shape, dtype=np.float64)
        cost, a, hi = self._solve(shape)
        self._remember(shape.tobytes(), cost, a.T.copy())
        wr, first = self._wr
        return cost, projection_gradient(self.basis, shape, a, wr, first, hi)

    def _cost(self, a: np.ndarray) -> float:
        """½ Σ w (f₀ + Σ aₖBₖ − y)² at colours ``a`` (3, K), from the residuals of the basis of the last
        :meth:`normal_equations` (see the class docstring for why not from the Gram matrices); the weighted
        residuals are kept for :meth:`value_and_grad`."""
        f0, cols = self._last
        first = all(B.ndim == 1 for B in cols)
        if first:  # channels first, as in normal_equations
            if self._wT is None:
                self._wT, self._yT = np.ascontiguousarray(self.w.T), np.ascontiguousarray(self.y.T)
            r = -self._yT if getattr(f0, "is_zero", False) else np.asarray(f0).T - self._yT
            for k, B in enumerate(cols):
                r = r + a[:, k, None] * B
            w = self._wT if self.w1 is None else self.w1
        else:
            r = -self.y if getattr(f0, "is_zero", False) else np.asarray(f0) - self.y
            for k, B in enumerate(cols):
                r = r + (B[:, None] if B.ndim == 1 else B) * a[:, k]
            w = self.w
        wr = w * r
        self._wr = (wr, first)
        return float(0.5 * np.sum(wr * r))


#: Samples per block of :func:`weighted_gram`: the block's elementary vectors (J x 8192 doubles, ~0.4 MB for
#: J = 6) stay in the cache while every channel's products are taken from them.
GRAM_BLOCK = 8192


def weighted_gram(elems, w: np.ndarray, yT: np.ndarray | None = None):
    """Weighted Gram matrix of elementary vectors: H[c, i, j] = Σₙ w[n, c] eᵢ[n] eⱼ[n] and, with the
    measured values ``yT`` (3, N) (channels first, contiguous), h[c, j] = Σₙ w[n, c] eⱼ[n] y[n, c].

    ``elems`` holds arrays (N,) or floats (a constant vector); ``w`` is (N,) — one weight for every
    channel — or (N, 3). Returns ``(H (3, J, J), h (3, J) or None)``.

    The sums are matrix products over blocks of :data:`GRAM_BLOCK` samples, (E_b w_b) E_bᵀ with E the J x N
    matrix of the elementary vectors: each block is read from memory once for all channels and every
    pair (i, j), where one dot product per pair and channel read the whole vectors J²/2 times
    (memory-bound: 20x slower on a MERL table's 4e5 samples). The same sums, in another order (to ~1e-15).
    E_b and E_b w_b are formed block by block in two (J, GRAM_BLOCK) buffers that stay in the cache (a
    whole J x N copy of the vectors went through memory first, and ``w.T`` was copied on every call); the
    same products of the same numbers. Per-channel ``w`` is read channels first: pass ``wT.T`` of a
    C-contiguous (3, N) ``wT`` (as :class:`Projection` and :class:`ProfiledProjection` do) and no copy is made.
    """
    J = len(elems)
    w = np.asarray(w, dtype=np.float64)
    N = w.shape[0]
    per_channel = w.ndim != 1
    W = np.ascontiguousarray(w.T) if per_channel else w[None]
    C = W.shape[0]
    H = np.zeros((C, J, J))
    h = None if yT is None else np.zeros((3, J))
    E = np.empty((J, min(N, GRAM_BLOCK)))
    WE = np.empty_like(E)
    vectors = []
    for j, e in enumerate(elems):
        if np.ndim(e) == 0:
            E[j] = e  # a constant vector: the same in every block
        else:
            vectors.append((j, e))
    for s in range(0, N, GRAM_BLOCK):
        n = min(GRAM_BLOCK, N - s)
        Eb, We = E[:, :n], WE[:, :n]
        for j, e in vectors:
            Eb[j] = e[s:s + n]
        for c in range(C):
            np.multiply(Eb, W[c, s:s + n], out=We)
            H[c] += We @ Eb.T
            if yT is not None:
                if per_channel:
                    h[c] += We @ yT[c, s:s + n]
                else:
                    h += yT[:, s:s + n] @ We.T
    H3 = H if per_channel else np.broadcast_to(H[0], (3, J, J))
    return H3, h


def jtj_from_elements(elems, C: np.ndarray, w: np.ndarray) -> np.ndarray:
    """JᵀJ of residuals r = √w (f − y) whose Jacobian columns are ∂f_c/∂p_q = Σⱼ C[c, j, q] eⱼ:
    JᵀJ = Σ_c C_cᵀ H_c C_c with the weighted Gram matrix H of the elementary vectors (exact; no finite
    differences of the model)."""
    H, _ = weighted_gram(elems, w)
    return np.einsum("cjp,cjl,clq->pq", C, H, C)


class ProfiledProjection:
    """The projected cost of the *non-tied* shape parameters, a tied affine parameter t minimized exactly.

    For a profile kernel (:data:`gonio.fit.kernels.PROFILES`) the colour bases are Bₖ = Σⱼ T(t)ₖⱼ eⱼ(s)
    with T affine in t. For each s the Gram matrix H and right-hand sides h of the elementary vectors eⱼ
    are formed once (one pass over the data); then for any t, G = T H Tᵀ and b = T h give the
    variable-projection cost (Golub & Pereyra 1973) in O(K³), so t is found by nested dense grids at
    negligible cost. ``__call__(s)`` returns ``(cost, colour)`` like :class:`Projection`;
    :meth:`full_shape` inserts the optimal t.

    Parameters
    ----------
    profile : profile kernel (``elements``, ``transform``)
    layout : Layout
    data : FitData
    w : ndarray (N, 3)
        Weights of the linear loss.
    t_index : int
        Position of the tied parameter in ``layout.shape``.
    wT : ndarray (3, N), optional
        ``w`` channels first, C-contiguous (the data's remembered copy, :meth:`gonio.fit.losses.Loss.weights_T_of`).
    """

    def __init__(self, profile, layout, data, w: np.ndarray, t_index: int, wT: np.ndarray | None = None):
        self.profile, self.L, self.data = profile, layout, data
        self.t_index = t_index
        w1 = shared_weights(w)
        if w1 is None:  # channels first in memory (weighted_gram): the caller's (3, N) copy ``wT`` if given
            wT = np.ascontiguousarray(w.T) if wT is None else wT
        self.w = wT.T if w1 is None else w1
        self.yT = data.yT  # remembered on the data (a second projection of the same data shares it)
        self.c0 = np.einsum("nc,nc,nc->c", data.y, w, data.y)
        self.lo, self.hi = layout.colour_lo, layout.colour_hi
        u_lo, u_hi, is_log = layout.search_space()
        self.t_space = (float(u_lo[t_index]), float(u_hi[t_index]), bool(is_log[t_index]))
        self.n_evals = 0
        self._memo: dict[tuple, tuple] = {}

    def _t_of(self, u):
        return np.exp(u) if self.t_space[2] else np.asarray(u)

    def _affine(self) -> tuple[np.ndarray, np.ndarray]:
        """``(T0, T1)`` (K, J) with T(t) = T0 + t T1 (the profile's transform is affine in t), once per projection."""
        hit = self.__dict__.get("_T01")
        if hit is None:
            T0, T1 = self.profile.transform(self.L, np.array([0.0, 1.0]))
            hit = self._T01 = (T0, T1 - T0)
        return hit

    def _pieces(self, H, h):
        """The Gram matrices and right-hand sides of the colours as polynomials in t, from those of the elementary
        vectors (H (3, J, J), h (3, J)): with T = T0 + t T1, G(t) = T H Tᵀ = G₀ + t G₁ + t² G₂ (3, K, K) and
        b(t) = T h = b₀ + t b₁ (3, K) — formed once per shape, so a grid of t costs a few array operations."""
        T0, T1 = self._affine()
        HT0, HT1 = H @ T0.T, H @ T1.T  # (3, J, K)
        G1 = T0 @ HT1
        return (T0 @ HT0, G1 + G1.transpose(0, 2, 1), T1 @ HT1), (h @ T0.T, h @ T1.T)

    def _costs(self, t, pieces, colours: bool = False):
        """Projected costs (len(t),) at tied values ``t`` (colours unconstrained where feasible — for two colours by
        Cramer's rule, else one batched solve — and :func:`bounded_lsq_batch`, exact, otherwise), from
        :meth:`_pieces`; with ``colours`` also the colours (len(t), 3, K)."""
        (G0, G1, G2), (b0, b1) = pieces
        t = np.asarray(t, dtype=np.float64)
        tg = t[:, None, None, None]
        G = G0 + tg * G1 + (tg * tg) * G2  # (T, 3, K, K)
        b = b0 + t[:, None, None] * b1  # (T, 3, K)
        with np.errstate(all="ignore"):
            if G.shape[-1] == 2:
                g00, g01, g10, g11 = G[..., 0, 0], G[..., 0, 1], G[..., 1, 0], G[..., 1, 1]
                det = g00 * g11 - g01 * g10
                a = np.empty_like(b)
                a[..., 0] = (g11 * b[..., 0] - g01 * b[..., 1]) / det
                a[..., 1] = (g00 * b[..., 1] - g10 * b[..., 0]) / det
            else:
                try:
                    a = np.linalg.solve(G, b[..., None])[..., 0]
                except np.linalg.LinAlgError:
                    a = np.full_like(b, np.nan)
            ok = np.isfinite(a).all(-1) & (a >= self.lo).all(-1) & (a <= self.hi).all(-1)
        if not ok.all():
            a[~ok] = bounded_lsq_batch(G[~ok], b[~ok], self.lo, self.hi)
        q = self.c0 - 2.0 * np.einsum("tck,tck->tc", b, a) + np.einsum("tck,tckm,tcm->tc", a, G, a)
        cost = 0.5 * np.maximum(q, 0.0).sum(axis=1)
        return (cost, a) if colours else cost

    def _solve(self, shape_nl) -> tuple[float, float, np.ndarray]:
        """``(t, cost, colour)`` at the non-tied shape ``shape_nl``: t global over a 65-point grid of its
        search interval, then the bracket around the best point is gridded again (each round vectorized,
        32-fold shrink) down to 1e-9; colours by the exact bounded solve at that t. Memoized per ``shape_nl``."""

        shape_nl = np.atleast_1d(np.asarray(shape_nl, dtype=np.float64))
        key = tuple(shape_nl.tolist())
        hit = self._memo.get(key)
        if hit is not None:
            return hit
        H, h = weighted_gram(self.profile.elements(self.data, self.L, shape_nl), self.w, self.yT)
        pieces = self._pieces(H, h)
        a, b = self.t_space[:2]
        for _ in range(10):  # each round shrinks the bracket 32-fold: 10 rounds reach ~1e-15 of the range
            grid = np.linspace(a, b, 65)
            costs = self._costs(self._t_of(grid), pieces)
            j = int(np.argmin(costs))
            u = float(grid[j])
            a, b = grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)]
            if b - a <= 1e-9 * max(1.0, abs(u)):
                break
        t = float(np.clip(self._t_of(u), self.L.shape_lo[self.t_index], self.L.shape_hi[self.t_index]))
        cost, colour = self._costs(np.array([t]), pieces, colours=True)
        if len(self._memo) > 256:
            self._memo.clear()
        self._memo[key] = out = (t, float(cost[0]), colour[0].T.copy())
        return out

    def full_shape(self, shape_nl) -> np.ndarray:
        """All shape parameters: ``shape_nl`` with the optimal tied value inserted."""
        shape_nl = np.atleast_1d(np.asarray(shape_nl, dtype=np.float64))
        return np.insert(shape_nl, self.t_index, self._solve(shape_nl)[0])

    def __call__(self, shape_nl) -> tuple[float, np.ndarray]:
        self.n_evals += 1
        _, cost, colour = self._solve(shape_nl)
        return cost, colour
