"""Fit one analytic BRDF model to measured samples.

Two solvers, same optimum:

* ``varpro`` (default when the model is affine in its colour parameters and the loss is linear):
  variable projection (Golub & Pereyra 1973, :mod:`gonio.fit.solve`) — the colours are solved in
  closed form (bounded least squares per channel) for each value of the shape parameters, and only
  the shape parameters are searched: a seeded coarse scan, then Brent's method (one shape parameter)
  or L-BFGS-B (several) from the best starts. Non-linear losses (log, cube root) are then polished
  from that start by ``plain``. Where a profile kernel applies (:data:`gonio.fit.kernels.PROFILES`:
  microfacet and lambert+ggx with the Fresnel f0 tied, the default), f0 is minimized exactly inside
  the projection as well (:class:`gonio.fit.solve.ProfiledProjection`), so only α is searched, and the
  Jacobian of the uncertainties is analytic.
* ``plain``: :func:`scipy.optimize.least_squares` (trust-region reflective, bounds from the model's
  ``PARAMS``) over every parameter, from a heuristic start and seeded random starts.

Standard uncertainties come from the Gauss–Newton covariance s² (JᵀJ)⁻¹ (Press et al., *Numerical
Recipes*, 3rd ed., §15.5), with s² = 2·cost/(m − k) unless the loss is χ² with known σ (s² = 1).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from gonio.errors import ConfigError, DataError, GonioError
from gonio.fit.bounds import NEAR_BOUND, ON_BOUND, bound_flags, bound_report, ratio_flags
from gonio.fit.data import DEFAULT_MAX_THETA_DEG, FitData, prepare
from gonio.fit.correlated import pose_covariance
from gonio.fit.geometry import calibration_covariance
from gonio.fit.kernels import jacobian_for, profile_for
from gonio.fit.layout import (CHANNELS, Basis, Layout, SubSpace, auto_tied, linked_lobes, make_basis, model_class,
                              resolve_fixed, separated)
from gonio.fit.losses import LOSSES, Loss, get_loss
from gonio.fit.result import FitResult
from gonio.fit.solve import Projection, ProfiledProjection, jtj_from_elements

METHODS = ("auto", "varpro", "plain")
#: How the lobes of a sum repeating a lobe get their colours (``chroma`` of :func:`fit`).
CHROMA = ("auto", "shared", "free")


def resolve_loss(loss: str, data: FitData) -> Loss:
    """``auto`` is χ² when every sample has an uncertainty, else the robust loss (the cube-root error
    linearized at the data, :mod:`gonio.fit.losses`): a cosine-weighted L2 lets a metal's specular peak,
    10⁵× the diffuse level, decide everything (chrome's diffuse albedo came out 1 instead of 0.003)."""
    if loss == "auto":
        return LOSSES["chi2" if data.sigma is not None else "robust"]
    obj = get_loss(loss, source="--loss")
    if obj.needs_sigma and data.sigma is None:
        raise ConfigError.field("--loss", "loss", loss,
                                f"{data.source} has no (positive, finite) uncertainty for every sample")
    return obj


def heuristics(data: FitData) -> dict[str, Any]:
    """Data summaries used to start and to sanity-check a fit: diffuse floor, peak height, lobe width.

    floor = 10th percentile of f per channel (× π: the albedo of a Lambertian floor); peak = maximum of
    f minus the floor; width = largest θh where the mean-channel value exceeds floor + peak/2 (the
    half-width at half maximum of the specular lobe in the half-angle, Ngan et al. 2005 plot lobes this way).
    """
    y = data.y
    floor = np.percentile(y, 10, axis=0)
    peak = y.max(axis=0) - floor
    m = y.mean(axis=1)
    thr = floor.mean() + 0.5 * peak.mean()
    th = np.degrees(np.arccos(np.clip(data.cos_h, -1, 1)))
    above = m > thr
    width = float(th[above].max()) if above.any() and peak.mean() > 0 else float("nan")
    return {"floor_albedo": (np.pi * floor).tolist(), "peak": peak.tolist(), "width_deg": width}


class _Problem:
    """A model, a loss and the data; evaluates model values and residuals for packed parameters."""

    def __init__(self, data: FitData, layout: Layout, loss: Loss, basis: Basis | None):
        self.d, self.L, self.loss, self.basis = data, layout, loss, basis
        self._cache: dict[tuple, Any] = {}
        self.n_evals = 0
        self._last_values: tuple | None = None
        self.profile = None  # a profile kernel (gonio.fit.kernels.PROFILES): tied f0 profiled out
        self.jacobian = None  # a kernel with an exact Jacobian (gonio.fit.kernels.jacobian_for)

    def _basis_at(self, shape):
        key = tuple(np.asarray(shape, dtype=np.float64).tolist())
        if key not in self._cache:
            if len(self._cache) > 8:
                self._cache.clear()
            self._cache[key] = self.basis(np.asarray(shape))
        return self._cache[key]

    def values(self, p, index=slice(None)) -> np.ndarray:
        """Model values f_m (N, 3) at packed parameters ``p`` (the last full-data result is kept: the final
        cost, RMS and χ² share one evaluation)."""
        full = isinstance(index, slice) and index == slice(None)
        key = np.asarray(p, dtype=np.float64).tobytes()
        if full and self._last_values is not None and self._last_values[0] == key:
            return self._last_values[1]
        m = self._values(p, index)
        if full:
            self._last_values = (key, m)
        return m

    def _values(self, p, index) -> np.ndarray:
        self.n_evals += 1
        colour, shape = self.L.unpack(p)
        if self.basis is not None and self.basis.separable:
            f0, cols = self._basis_at(shape)
            m = np.array(f0[index])  # plain ndarray (the offset may be a ZeroOffset)
            for k, B in enumerate(cols):
                Bi = B[index]
                m += (colour[k] - self.basis.ref[k]) * (Bi[:, None] if Bi.ndim == 1 else Bi)
            return m
        return self.L.eval(colour, shape, self.d.wi[index], self.d.wo[index])

    def residuals(self, p, index=slice(None)) -> np.ndarray:
        d = self.d
        if isinstance(index, slice) and index == slice(None):
            return self.loss.residuals_of(self.values(p), d)
        sigma = None if d.sigma is None else d.sigma[index]
        return self.loss.residual(self.values(p, index), d.y[index], d.cos_i[index], sigma)

    def cost(self, p) -> float:
        r = self.residuals(p)
        return 0.5 * float(np.sum(r * r))

    def jtj(self, p, chunk: int = 200_000) -> np.ndarray:
        """JᵀJ of the residual vector at ``p``, by central differences, accumulated in row chunks.

        For a linear loss on a separable model the colour columns are exact (√w Bₖ) and only the
        shape columns need differences of the basis (:meth:`_jtj_linear`)."""
        if self.loss.linear and self.jacobian is not None:
            colour, shape = self.L.unpack(p)
            elems, C = self.jacobian.jacobian(self.d, self.L, colour, shape)
            return jtj_from_elements(elems, C, self.loss.channel_weights_of(self.d))
        if self.loss.linear and self.basis is not None and self.basis.separable:
            return self._jtj_linear(p)
        P = p.size
        lo, hi = self.L.bounds()
        h = 1e-6 * np.maximum(np.abs(p), 1e-3)
        out = np.zeros((P, P))
        n = len(self.d)
        for start in range(0, n, chunk):
            idx = slice(start, min(n, start + chunk))
            cols = []
            for j in range(P):
                up, dn = p.copy(), p.copy()
                up[j] = min(p[j] + h[j], hi[j])
                dn[j] = max(p[j] - h[j], lo[j])
                cols.append(((self.residuals(up, idx) - self.residuals(dn, idx)) / (up[j] - dn[j])).ravel())
            J = np.stack(cols, axis=1)
            out += J.T @ J
        return out


    def _jtj_linear(self, p) -> np.ndarray:
        L, d = self.L, self.d
        colour, shape = L.unpack(p)
        w = self.loss.weights_of(d)
        _, cols = self._basis_at(shape)
        Bs = [np.broadcast_to(B[:, None] if B.ndim == 1 else B, d.y.shape) for B in cols]
        dm = []
        lo, hi = L.shape_lo, L.shape_hi
        for j in range(L.S):
            h = 1e-6 * max(abs(shape[j]), 1e-3)
            up, dn = shape.copy(), shape.copy()
            up[j], dn[j] = min(shape[j] + h, hi[j]), max(shape[j] - h, lo[j])
            mu = self.values(L.pack(colour, up))
            md = self.values(L.pack(colour, dn))
            dm.append((mu - md) / (up[j] - dn[j]))
        K, S = L.K, L.S
        A = np.zeros((3 * K + S, 3 * K + S))
        for c in range(3):
            for k in range(K):
                wb = w[:, c] * Bs[k][:, c]
                for l in range(k, K):
                    A[3 * k + c, 3 * l + c] = A[3 * l + c, 3 * k + c] = wb @ Bs[l][:, c]
                for j in range(S):
                    A[3 * k + c, 3 * K + j] = A[3 * K + j, 3 * k + c] = wb @ dm[j][:, c]
        for i in range(S):
            for j in range(i, S):
                A[3 * K + i, 3 * K + j] = A[3 * K + j, 3 * K + i] = float(np.sum(w * dm[i] * dm[j]))
        return A


def _coordinate_scan(f, u0, c0: float, u_lo, u_hi, cycles: int = 2, points: int = 17):
    """Cyclic coordinate search (e.g. Nocedal & Wright, *Numerical Optimization*, 2nd ed., §9.3) on grids:
    each parameter in turn over ``points`` values of its whole search range, the others held, ``cycles``
    times. Returns the best point and its cost."""
    u, c = np.array(u0, dtype=np.float64), float(c0)
    for _ in range(cycles):
        for j in range(u.size):
            for x in np.linspace(u_lo[j], u_hi[j], points):
                t = u.copy()
                t[j] = x
                ct = f(t)
                if ct < c:
                    u, c = t, ct
    return u, c


def _search_shape(proj: Projection, L: Layout, rng, n_starts: int):
    """Global-then-local search of the projected cost over the shape parameters."""
    from scipy.optimize import minimize, minimize_scalar

    if L.S == 0:
        cost, colour = proj(np.empty(0))
        return np.empty(0), colour, cost
    u_lo, u_hi, _ = L.search_space()

    def f(u):
        return proj(L.to_shape(np.atleast_1d(u)))[0]

    results = []
    if L.S == 1:
        grid = np.linspace(u_lo[0], u_hi[0], 11)
        costs = np.array([f(u) for u in grid])
        order = [j for j in np.argsort(costs)
                 if (j == 0 or costs[j] <= costs[j - 1]) and (j == len(grid) - 1 or costs[j] <= costs[j + 1])]
        for j in order[:max(1, n_starts)]:
            a, b = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
            res = minimize_scalar(f, bounds=(a, b), method="bounded", options={"xatol": 1e-6})
            results.append((float(res.fun), np.array([res.x])))
            results.append((float(costs[j]), np.array([grid[j]])))
    else:
        cand = [L.to_u(L.default_shape())] + list(rng.uniform(u_lo, u_hi, (8 * L.S + 4 * n_starts, L.S)))
        costs = np.array([f(u) for u in cand])
        best = list(np.argsort(costs)[:max(1, n_starts)])
        # and from a coordinate scan of the best point: a narrow valley between parameters (ABC's B and C)
        # that no random point hits is found along the axes
        u_scan, c_scan = _coordinate_scan(f, cand[best[0]], costs[best[0]], u_lo, u_hi)
        cand.append(u_scan)
        costs = np.append(costs, c_scan)
        fg = _with_gradient(proj, L)
        for j in best + [len(cand) - 1]:
            res = minimize(f if fg is None else fg, cand[j], method="L-BFGS-B", jac=fg is not None,
                           bounds=list(zip(u_lo, u_hi)), options={"eps": 1e-7, "ftol": 1e-13, "gtol": 1e-10, "maxiter": 200})
            results.append((float(res.fun), np.asarray(res.x)))
            results.append((float(costs[j]), np.asarray(cand[j])))
    cost, u = min(results, key=lambda t: t[0])
    shape = L.to_shape(u)
    cost, colour = proj(shape)
    return shape, colour, cost


def _with_gradient(proj, L):
    """``fg(u) = (cost, ∂cost/∂u)`` of the projected cost in the search space of ``L`` where the projection has an
    exact gradient (:meth:`gonio.fit.solve.Projection.value_and_grad`, carried through ``L.to_shape`` by
    :func:`gonio.fit.gradient.map_jacobian`), so L-BFGS-B needs no finite differences; else None."""
    if not getattr(proj, "has_gradient", False):
        return None
    from gonio.fit.gradient import map_jacobian

    def fg(u):
        u = np.atleast_1d(u)
        cost, g = proj.value_and_grad(L.to_shape(u))
        return cost, map_jacobian(L, u).T @ g

    return fg


#: Above this many samples the global shape search runs on a seeded random subset of this size and only
#: a local refinement runs on all samples (the optimum is the full-data one; see :func:`_refine`).
COARSE_N = 20_000


def _refine(proj: Projection, L: Layout, u0: np.ndarray, width: float = 0.1):
    """Local minimization of the full-data projected cost from ``u0`` (the subset optimum): bounded
    Brent's method in [u0 − width, u0 + width] for one shape parameter, else L-BFGS-B (Byrd et al.
    1995, as :func:`scipy.optimize.minimize`) within the search box."""
    from scipy.optimize import minimize, minimize_scalar

    u_lo, u_hi, _ = L.search_space()

    def f(u):
        return proj(L.to_shape(np.atleast_1d(u)))[0]

    if L.S == 1:
        a, b = max(u0[0] - width, u_lo[0]), min(u0[0] + width, u_hi[0])
        res = minimize_scalar(f, bounds=(a, b), method="bounded", options={"xatol": 1e-5})
        u = np.array([res.x])
    else:
        fg = _with_gradient(proj, L)
        res = minimize(f if fg is None else fg, u0, method="L-BFGS-B", jac=fg is not None, bounds=list(zip(u_lo, u_hi)),
                       options={"eps": 1e-6, "ftol": 1e-10, "gtol": 1e-6, "maxiter": 8})
        u = np.asarray(res.x)
    shape = L.to_shape(u)
    cost, colour = proj(shape)
    return shape, colour, cost


def _plain(prob: _Problem, starts: list[np.ndarray], max_nfev: int | None = None):
    """scipy least_squares (TRF, bounds) from each start; the best result."""
    from scipy.optimize import least_squares

    L = prob.L
    lo, hi = L.bounds()
    m = 3 * len(prob.d)

    def fun(p):
        try:
            return prob.residuals(p).ravel()
        except ConfigError:  # a combination the model rejects (e.g. kd + ks > 1): steer away
            return np.full(m, 1e6)

    best = None
    for p0 in starts:
        span = np.where(np.isfinite(hi - lo), hi - lo, np.maximum(np.abs(p0), 1.0))
        p0 = np.clip(p0, lo + 1e-9 * span, hi - 1e-9 * span)
        res = least_squares(fun, p0, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=max_nfev)
        if best is None or res.cost < best.cost:
            best = res
    return best.x, float(best.cost)


def _starts(prob: _Problem, rng, n_starts: int, heur: dict) -> list[np.ndarray]:
    """Heuristic start (model defaults for shapes; colours from the projection if separable, else from
    the diffuse floor) plus ``n_starts − 1`` seeded random starts."""
    L = prob.L
    shape0 = L.default_shape()
    colour0 = np.empty((L.K, 3))
    floor = np.asarray(heur["floor_albedo"])
    for k, name in enumerate(L.colour):
        d = L.cls.PARAMS[name].default
        colour0[k] = np.clip(floor if d is None else d, L.colour_lo[k], L.colour_hi[k])
    starts = [L.pack(colour0, shape0)]
    u_lo, u_hi, _ = L.search_space()
    for _ in range(max(0, n_starts - 1)):
        c = rng.uniform(np.maximum(L.colour_lo, 0)[:, None], np.minimum(L.colour_hi, 1.0)[:, None], (L.K, 3))
        starts.append(L.pack(c, L.to_shape(rng.uniform(u_lo, u_hi))))
    return starts


def canonical_order(L: Layout, p: np.ndarray) -> np.ndarray:
    """Order repeated lobes of a sum (``lambert+2ggx``) by their shape parameters, sharpest first, so a
    fit reports one answer instead of one of its label-switched twins (the sum is symmetric in them)."""
    parts = getattr(L.cls, "PARTS", ())
    groups: dict[tuple, list[str]] = {}
    for slot, cls, fixed in parts:
        groups.setdefault((cls, tuple(sorted(dict(fixed).items()))), []).append(slot)
    colour, shape = L.unpack(p)
    colour, shape = colour.copy(), shape.copy()
    for slots in groups.values():
        if len(slots) < 2:
            continue

        def idx(names, slot):
            return [i for i, n in enumerate(names) if n.split(".", 1)[0] == slot]

        keys = [tuple(shape[idx(L.shape, s)]) for s in slots]
        order = sorted(range(len(slots)), key=lambda j: keys[j])
        src_c = [idx(L.colour, slots[j]) for j in order]
        src_s = [idx(L.shape, slots[j]) for j in order]
        old_c, old_s = colour.copy(), shape.copy()
        for dst, (sc, ss) in zip(slots, zip(src_c, src_s)):
            dc, ds = idx(L.colour, dst), idx(L.shape, dst)
            if len(dc) != len(sc) or len(ds) != len(ss):
                break
            colour[dc], shape[ds] = old_c[sc], old_s[ss]
    return L.pack(colour, shape)


def _shape_dependent_bounds(basis, L: Layout, p: np.ndarray) -> np.ndarray:
    """Entries of the packed ``p`` on a colour bound that depends on the shape (:func:`colour_upper`: a linked
    colour's range, a lobe's albedo ≤ 1, :func:`gonio.fit.kernels_abc.abc_smooth_albedo`), within
    :data:`gonio.fit.bounds.ON_BOUND`."""
    out = np.zeros(p.size, dtype=bool)
    colour, shape = L.unpack(p)
    hi = colour_upper(L, basis, shape)
    dependent = np.isfinite(hi) & (hi < L.colour_hi)
    out[:3 * L.K] = ((colour >= hi[:, None] * (1 - 1e-6)) & dependent[:, None]).ravel()
    return out


def _uncertainty(prob: _Problem, p: np.ndarray, cost: float, notes: list[str], A: np.ndarray | None = None,
                 extra_bound: np.ndarray | None = None):
    """Standard uncertainties from s²(JᵀJ)⁻¹ over the parameters that are off their bounds and
    identifiable; ``nan`` on a bound, ``inf`` when not identifiable.

    s² = 2·cost/(m − k) for losses without known σ; for χ², s² = max(1, χ²_red): when the scatter
    exceeds the stated σ the covariance is inflated by the reduced χ² (Birge ratio; Press et al.,
    *Numerical Recipes*, 3rd ed., §15.1.1), else the stated σ are trusted.

    Returns ``(err, identifiable, redundancy)``; for a sum of lobes ``redundancy`` is the largest
    correlation between parameters of two different terms, ``(|ρ|, name_a, name_b)`` (``None`` otherwise):
    |ρ| → 1 means the data cannot tell the terms apart.
    """
    L = prob.L
    labels = L.labels()
    P = p.size
    m = 3 * len(prob.d)
    err = np.full(P, np.nan)
    lower, upper = bound_flags(L, p, ON_BOUND)  # each parameter on its own scale (gonio.fit.bounds)
    on_bound = lower | upper
    for j in ratio_flags(L, L.unpack(p)[1], ON_BOUND):  # a repeated lobe's width on the width-ratio bound
        on_bound[3 * L.K + j] = True
    if extra_bound is not None:
        on_bound |= extra_bound
    A = prob.jtj(p) if A is None else A
    free = ~on_bound
    ident = free.copy()
    diag = np.sqrt(np.clip(np.diag(A), 0, None))
    ident &= diag > 1e-12 * max(diag.max(), 1e-300)
    idx = np.flatnonzero(ident)
    if idx.size:
        D = diag[idx]
        C = A[np.ix_(idx, idx)] / np.outer(D, D)
        evals, evecs = np.linalg.eigh(C)
        weak = evals < 1e-10 * max(evals.max(), 1e-300)
        if weak.any():
            bad = np.abs(evecs[:, weak]).max(axis=1) > 0.3
            ident[idx[bad]] = False
            idx = np.flatnonzero(ident)
    unident = free & ~ident
    err[unident] = np.inf
    if idx.size:
        s2 = 2.0 * cost / max(m - P, 1)
        if prob.loss.name == "chi2":
            if s2 > 1.5:
                notes.append(f"uncertainties scaled by sqrt(chi2_red) = {np.sqrt(s2):.3g}: the scatter exceeds "
                             f"the stated sigma")
            s2 = max(s2, 1.0)
        cov = s2 * np.linalg.pinv(A[np.ix_(idx, idx)])
        pc = pose_covariance(prob, p, idx, s2 if prob.loss.name == "chi2" else 1.0)
        if pc is not None:  # a session's samples: errors correlated within a pose (gonio.fit.correlated)
            v = np.maximum(np.diag(cov), np.diag(pc[0]))  # never below the independent samples' estimate
            sd = np.sqrt(np.clip(np.diag(pc[0]), 1e-300, None))
            cov = pc[0] / np.outer(sd, sd) * np.sqrt(np.outer(v, v))
            notes.append(pc[1])
        gc = calibration_covariance(prob, p, idx)
        if gc is not None:  # the calibration's error, shared by every pose (gonio.fit.geometry)
            cov = cov + gc[0]
            notes.append(gc[1])
        err[idx] = np.sqrt(np.clip(np.diag(cov), 0, None))
    redundancy = None
    if idx.size and getattr(L.cls, "PARTS", None):
        sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
        R = np.abs(cov / np.outer(sd, sd))
        slot = np.array([labels[j].split(".", 1)[0] for j in idx])
        R[slot[:, None] == slot[None, :]] = 0.0
        if R.size:
            i, j = np.unravel_index(np.argmax(R), R.shape)
            if R[i, j] > 0:
                redundancy = (float(R[i, j]), labels[idx[i]], labels[idx[j]])
    if unident.any():
        names = sorted({labels[j].split(".")[0] for j in np.flatnonzero(unident)})
        notes.append(f"not identifiable from these data: {', '.join(names)}")
    bound_names = sorted({labels[j] if j >= 3 * L.K else labels[j].rsplit(".", 1)[0] for j in np.flatnonzero(on_bound)})
    if bound_names:
        notes.append(f"at a bound (no uncertainty): {', '.join(bound_names)}")
    return err, not unident.any(), redundancy


def fit(data, model: str | type, *, loss: str = "auto", fixed: dict | None = None,
        free: tuple[str, ...] = (), max_theta_deg: float | None = DEFAULT_MAX_THETA_DEG, n_starts: int = 3, seed: int = 0,
        method: str = "auto", kernel: str | None = "auto", use_flagged: bool = False,
        max_nfev: int | None = None, report: bool = True, start: dict | None = None, chroma: str = "auto",
        geometry=None, image_weight: float | None = None, search_n: int | None = None) -> FitResult:
    """Fit the model ``model`` to ``data``.

    Parameters
    ----------
    data : SampleSet, FitData or ``(wi, wo, f[, sigma])``
        Measured samples (see :func:`gonio.fit.data.prepare` for what is dropped).
    model : str or BRDF subclass
        Registry name (``gonio models`` lists them) or class.
    loss : str
        ``auto`` (χ² with uncertainties, else cosine), ``cosine``, ``chi2``, ``log``, ``cbrt``.
    fixed : dict
        Parameters held fixed (choice parameters are always fixed, at their default unless given), named as
        ``gonio fit`` prints them: ``lobe1.f0``, a bare ``f0`` for every lobe's f0, or per channel
        (``kd.r``, all three channels) — :func:`gonio.fit.layout.resolve_fixed`.
    free : sequence of str
        Parameters fitted per channel although tied by default (the Fresnel ``f0``, see
        :data:`gonio.fit.layout.AUTO_TIED`; e.g. ``("f0",)`` or ``("lobe1.f0",)``). A tied parameter
        the data cannot determine (standard uncertainty above :data:`TIED_MAX_SE`, e.g. only
        near-normal θd where Schlick's F ≈ f0 is indistinguishable from ks) is held at 1 instead — ks
        is then the specular reflectance ks·F — and a note says so. A later copy of a repeated lobe's ``ks``
        (``lobe2.ks`` of ``lambert+2ggx``) is fitted as a ratio times the first copy's — one chromaticity for
        the lobes (:func:`gonio.fit.layout.linked_lobes`) — unless named here.
    chroma : {"auto", "shared", "free"}
        For a sum repeating a lobe: ``shared`` fits the lobes with one chromaticity (the later copies' ``ks`` a
        ratio times the first's, :func:`gonio.fit.layout.linked_lobes`), ``free`` each with its own colour,
        ``auto`` both and keeps the shared one unless the data demand otherwise (:func:`_shared_or_free`).
    image_weight : float or None
        The data-driven model (``dupuy2015``) only: weight of the squared relative image error (rendered spheres,
        :func:`gonio.fit.metrics.image_error`) beside the loss's in what is minimized (None: its default
        :data:`gonio.fit.dupuy.IMAGE_WEIGHT`; 0: the loss alone; :func:`gonio.fit.dupuy.fit_dupuy`).
    max_theta_deg : float or None
        Grazing cutoff for θi and θo (default 80°); None keeps all samples above the horizon.
    n_starts : int
        Number of local refinements (multi-start); the starts are seeded by ``seed``.
    method : {"auto", "varpro", "plain"}
        Solver (see the module docstring).
    kernel : "auto" or None
        Use a precomputed-geometry kernel of :mod:`gonio.fit.kernels` when one exists for the model.
    search_n : int or None
        Above this many samples the global shape search runs on a seeded random subset of this size and only a
        local refinement on all samples (coarse to fine; default :data:`COARSE_N`). :func:`gonio.fit.select.select`
        passes a smaller one on large tables (:data:`gonio.fit.select.SEARCH_N`), for time.
    start : dict
        Parameters of an earlier fit of the same model (e.g. on a subset of these data): the shape search
        is replaced by a local refinement from them (a warm start; :func:`gonio.fit.select.select` refits
        its winner on all samples this way).
    geometry : :class:`gonio.fit.geometry.CalibrationModes` or None
        A session's geometric calibration error (:func:`gonio.session.calibration_modes.session_modes`):
        propagated into the parameters' σ (:func:`gonio.fit.geometry.calibration_covariance`).
    report : bool
        Also compute the error measures of :mod:`gonio.fit.metrics` and the directional-albedo check of
        :mod:`gonio.fit.energy` (about a second on a full MERL table; selection skips them for losers).

    Returns
    -------
    FitResult

    Raises
    ------
    DataError
        No usable sample, or fewer residuals than parameters + 1.
    ConfigError
        Unknown model, loss, method or parameter.
    """
    t0 = time.perf_counter()
    if method not in METHODS:
        raise ConfigError.field("--method", "method", method, f"must be one of {', '.join(METHODS)}")
    d = prepare(data, max_theta_deg=max_theta_deg, use_flagged=use_flagged, geometry=geometry)
    cls = model_class(model) if isinstance(model, str) else model
    if getattr(cls, "name", "").startswith("dupuy2015"):  # tabulated D: its own solver (gonio.fit.dupuy)
        return _fit_data_driven(d, cls, loss, fixed, free, report, t0, image_weight)
    if image_weight is not None:
        raise ConfigError.field("--image-weight", "image_weight", image_weight,
                                "only the data-driven model dupuy2015 is fitted in the image error; for the others "
                                "use --select --criterion image")
    fixed = resolve_fixed(cls, dict(fixed or {}))
    tied = auto_tied(cls, fixed, free)
    if chroma not in CHROMA:
        raise ConfigError.field("--chroma", "chroma", chroma, f"must be one of {', '.join(CHROMA)}")
    links = tuple((dst, src) for dst, src in linked_lobes(cls) if dst not in free and chroma != "free")
    lossobj = resolve_loss(loss, d)
    if search_n is not None and not (isinstance(search_n, (int, np.integer)) and search_n >= 100):
        raise ConfigError.field("search_n", "search_n", search_n, "must be an integer >= 100 (samples)")
    kw = dict(n_starts=n_starts, seed=seed, method=method, kernel=kernel, max_nfev=max_nfev, start=start,
              search_n=search_n)
    r = _restart_at_bound(_fit_tied(d, cls, fixed, tied, links, lossobj, kw), d, cls, fixed, tied, links, lossobj, kw)
    if links and chroma == "auto":  # the lobes' own colours only where the data demand them
        free_fit = _fit_tied(d, cls, fixed, tied, (), lossobj, kw)
        r = _shared_or_free(r, _restart_at_bound(free_fit, d, cls, fixed, tied, (), lossobj, kw))
    return _finish(r, d, report, t0)


def _finish(r: FitResult, d: FitData, report: bool, t0: float) -> FitResult:
    """The last steps of every :func:`fit`: the bounds reached said in a note, the report added on request, the
    time taken recorded."""
    from gonio.fit.kernels_abc import FIT_NOTES

    if r.model_name in FIT_NOTES:  # what the fitted parameters mean physically (a conductor's index, its scale)
        r.notes.append(FIT_NOTES[r.model_name](r.params))
    if r.at_bound:
        r.notes.append("at or near a bound of its range: " + "; ".join(
            f"{k} ({', '.join(f'{c} {w}' for c, w in v.items())})" for k, v in r.at_bound.items()))
    if report:
        add_report(r, d)
    r.seconds = time.perf_counter() - t0
    return r


def _fit_data_driven(d: FitData, cls, loss: str, fixed, free, report: bool, t0: float,
                     image_weight: float | None) -> FitResult:
    """:func:`fit` of the data-driven model of Dupuy et al. 2015 (:mod:`gonio.fit.dupuy`; its conductor variant
    :mod:`gonio.fit.dupuy_conductor`): no parameter of its tables can be held fixed or freed (one line saying so)."""
    from gonio.fit.dupuy import fit_dupuy

    if fixed or free:
        raise ConfigError.field("--fix", f"{cls.name}.{next(iter(fixed or free))}", "fixed" if fixed else "free",
                                f"the tables of {cls.name} are fitted together; none can be fixed or freed")
    from gonio.fit.dupuy import IMAGE_WEIGHT

    if image_weight is not None and not (isinstance(image_weight, (int, float)) and 0 <= image_weight < np.inf):
        raise ConfigError.field("--image-weight", "image_weight", image_weight, "must be a number >= 0")
    image = IMAGE_WEIGHT if image_weight is None else float(image_weight)
    if cls.name == "dupuy2015":
        r = fit_dupuy(d, resolve_loss(loss, d), image=image)
    elif cls.name == "dupuy2015-coated":
        from gonio.fit.dupuy_coated import fit_dupuy_coated

        r = fit_dupuy_coated(d, resolve_loss(loss, d), image=image)
    else:
        from gonio.fit.dupuy_conductor import fit_dupuy_conductor

        r = fit_dupuy_conductor(d, resolve_loss(loss, d), image=image)
    return _finish(r, d, report, t0)


def _fit_tied(d: FitData, cls, fixed: dict, tied, linked, lossobj: Loss, kw: dict) -> FitResult:
    """One fit of ``cls`` with ``tied`` parameters and ``linked`` colours; a tied f0 the data cannot determine
    is held at 1 and the fit repeated (see :func:`fit`, ``free``)."""
    L = Layout(cls, fixed, tied, linked)
    if 3 * len(d) <= L.n_params:
        raise DataError(f"{d.source}: {len(d)} usable samples ({3 * len(d)} values) cannot determine "
                        f"{L.n_params} parameters of {L.name}; need at least {L.n_params // 3 + 1} samples")
    r = _fit_layout(d, L, lossobj, **kw)
    weak = [t for t in L.tied if not r.uncertainty[t] <= TIED_MAX_SE]  # inf, or too wide; nan = on a bound
    # f0 multiplies ks: with ks pinned at a bound, f0 looks determined only because the bound fixes the product
    hit = r.at_bound
    weak += [t for t in L.tied if t not in weak and _partner(t, "ks") in hit]
    if weak:
        L2 = Layout(cls, {**fixed, **{t: 1.0 for t in weak}}, [t for t in tied if t not in weak], linked)
        optimum = None
        if all(abs(r.params[t] - 1.0) <= 1e-7 for t in weak):
            # on its upper bound (the tolerance of _uncertainty), at the value it is now held at: the held
            # fit's minimizer is this one (the same point is feasible and nothing lower is), so the search is
            # not repeated; the colours are solved again at the held value
            held = {**r.params, **_link_values(r, L2)}
            optimum = (np.array([r.params[n] for n in L2.colour], dtype=np.float64),
                       np.array([float(np.mean(held[n])) for n in L2.shape], dtype=np.float64))
        r2 = _fit_layout(d, L2, lossobj, **kw, optimum=optimum)
        if optimum is not None:
            r2.method = r.method
        why = ", ".join(f"{t} = {r.params[t]:.3g} " + ("on its upper bound" if not np.isfinite(r.uncertainty[t])
                                                        and abs(r.params[t] - 1.0) <= 1e-7
                                                        else f"with {_partner(t, 'ks')} on a bound" if _partner(t, "ks") in hit
                                                        else f"± {r.uncertainty[t]:.2g}") for t in weak)
        r2.notes.insert(0, f"not identifiable from these data: {why} (the angular range does not separate the "
                           f"Fresnel rise from ks); held at 1, so ks is the specular reflectance ks·F")
        r2.n_evals += r.n_evals
        r2.identifiable = False
        r = r2
    return r


#: Extra seeded starts of a fit whose shape parameters ended on a bound (:func:`_restart_at_bound`).
RESTARTS = 2


def _structural_bounds(r: FitResult) -> list[str]:
    """Shape parameters (one value for R, G, B: widths, exponents, ABC's B and C, the lobes' width ratio) of
    ``r`` at a bound."""
    return [k for k, v in r.at_bound.items() if "value" in v]


def _restart_at_bound(r: FitResult, d, cls, fixed, tied, linked, lossobj, kw) -> FitResult:
    """A fit whose shape parameters ended on a bound (a local search may stop on one: a two-lobe fit at the
    width-ratio bound, ABC's B at an end of its eight decades) is searched again globally from
    :data:`RESTARTS` more seeded starts (multi-start, e.g. Nocedal & Wright, *Numerical Optimization*, 2nd ed.,
    §2.3 on global minimization), without the warm start; the lower cost wins and a note says what was
    tried. A bound that remains is then the data's answer, reported in ``at_bound``. Not with ``n_starts = 1``
    (a single local refinement asked for: :func:`gonio.fit.select.select` on a large table, for time)."""
    hit = _structural_bounds(r)
    if int(kw.get("n_starts") or 1) <= 1:  # a single local refinement was asked for (the big-table selection's budget)
        return r
    if not hit or not (separated(Layout(cls, fixed, tied)) or cls.name.startswith("abc")):
        return r  # multi-start where a local search stops on structural bounds: repeated lobes, ABC's B and C
    kw2 = {**kw, "start": None, "n_starts": max(int(kw.get("n_starts") or 1), 1) + RESTARTS,
           "seed": int(kw.get("seed") or 0) + 1}
    r2 = _fit_tied(d, cls, fixed, tied, linked, lossobj, kw2)
    best, other = (r2, r) if r2.cost < r.cost * (1 - 1e-9) else (r, r2)
    best.n_evals += other.n_evals
    still = _structural_bounds(best)
    best.notes.append(f"{', '.join(hit)} ended on a bound; searched again from {kw2['n_starts']} starts: "
                      + (f"{', '.join(still)} stays there (the data's optimum)" if still else "off the bound now"))
    return best


def _shared_or_free(shared: FitResult, free: FitResult) -> FitResult:
    """The fit with lobes of one chromaticity (``shared``, :func:`gonio.fit.layout.linked_lobes`) unless the data
    demand each lobe's own colour (``free``): the free fit is kept when its BIC (Schwarz 1978;
    :attr:`FitResult.bic`) is lower *and* its lobes are not held apart only by the width-ratio bound (lobes of
    nearly one width told apart by colour: a lobe whose width varies by channel, issue 29). Either way a note
    says which and why."""
    ratio_bound = any("ratio" in str(v) for v in free.at_bound.values())
    delta = free.bic - shared.bic
    if delta < 0 and not ratio_bound:
        free.notes.append(f"each lobe has its own colour: BIC {delta:+.4g} against lobes of one chromaticity")
        free.n_evals += shared.n_evals
        return free
    why = ("the lobes of their own colours are held apart only by the width-ratio bound" if delta < 0
           else f"their own colours do not pay (BIC {delta:+.4g})")
    shared.notes.append(f"lobes of one chromaticity: {why}")
    shared.n_evals += free.n_evals
    return shared


def _link_values(r: FitResult, L: Layout) -> dict[str, float]:
    """The ratios of ``L``'s links as fitted in ``r`` (``r.links``)."""
    return {name: r.links[name] for _, _, name in L.links}


def _partner(name: str, other: str) -> str:
    """The parameter ``other`` of the same term as ``name`` (``lobe1.f0`` -> ``lobe1.ks``, ``f0`` -> ``ks``)."""
    return f"{name.rsplit('.', 1)[0]}.{other}" if "." in name else other


def add_report(r: FitResult, d: FitData, scored: tuple | None = None) -> None:
    """Fill ``r.metrics`` (:mod:`gonio.fit.metrics`), ``r.goodness`` (:mod:`gonio.fit.gof`) and ``r.energy``
    (:mod:`gonio.fit.energy`); a note when the model does not fit or the fitted parameters do not conserve
    energy. ``scored = (values, goodness, energy)``: what a caller computed already for this result on these data
    (:func:`gonio.fit.select.select` scores every candidate so), not computed again."""
    from gonio.fit.energy import albedo_check
    from gonio.fit.gof import goodness_of_fit
    from gonio.fit.metrics import metrics

    m, goodness, energy = scored or (np.asarray(r.model.eval(d.wi, d.wo), dtype=np.float64), None, None)
    r.metrics = metrics(r.model, d, values=m)
    r.goodness = goodness if goodness is not None else goodness_of_fit(m, d, LOSSES[r.loss], r.n_params)
    r.energy = energy if energy is not None else albedo_check(r.model)
    if not r.energy["ok"]:
        r.notes.append(f"not energy conserving: directional albedo {r.energy['albedo_max']:.3g} > 1 at "
                       f"theta_i = {r.energy['theta_deg']:g} deg")


#: A tied parameter (f0) whose standard uncertainty exceeds this is reported as not identifiable and
#: held at 1 (its whole range is [0, 1]).
TIED_MAX_SE = 0.2


def colour_upper(L: Layout, basis, shape) -> np.ndarray:
    """Upper bounds (K,) of the colours at ``shape``: the model's, the links' (:meth:`Layout.linked_colour_hi`)
    and the basis's shape-dependent ones (``basis.colour_hi``: a lobe's albedo ≤ 1)."""
    hi = L.linked_colour_hi(shape)
    hook = getattr(basis, "colour_hi", None)
    extra = hook(shape) if hook is not None else None
    return hi if extra is None else np.minimum(hi, extra)


def _data_projection(basis, loss: Loss, d: FitData, L: Layout) -> Projection:
    """The colours' projection of all of ``d`` under ``loss``'s weights, with the channels-first copies of the
    weights and values remembered on the data (:meth:`Loss.weights_T_of`, :attr:`FitData.yT`)."""
    return Projection(basis, np.ascontiguousarray(loss.weights_of(d)), d.y, L.colour_lo, L.colour_hi,
                      (loss.weights_T_of(d), d.yT))


def within_bounds(prob: _Problem, L: Layout, basis, lossobj: Loss, p: np.ndarray, cost: float,
                  notes: list[str]) -> tuple[np.ndarray, float]:
    """``(p, cost)`` of a solver's answer made feasible: every fitting path (variable projection, a warm-started
    refinement, ``scipy.optimize.least_squares`` with its box bounds, a known optimum) ends here, so no fit
    returns a parameter outside its range. A box-bounded solver cannot see the bounds that depend on other
    parameters (a linked colour ``lobe2.ks`` = w · ``lobe1.ks`` ≤ its upper bound, a lobe's albedo ≤ 1): a point
    beyond them is projected back — shapes clipped to their ranges, then the colours solved again at that shape
    by the bounded linear least squares of :class:`gonio.fit.solve.Projection` (exact for a linear loss on a
    separable model; else clipped) — and a note says so. A feasible ``p`` is returned unchanged. A non-finite
    ``p`` (a solver that diverged on data that do not determine the model) is a one-line DataError, never a
    model that cannot be built."""
    colour, shape = L.unpack(p)
    if not np.all(np.isfinite(p)):
        bad = [n for n, v in zip(L.colour + L.shape, list(colour) + list(shape)) if not np.all(np.isfinite(v))]
        raise DataError(f"{prob.d.source}: fitting {L.name} gave non-finite parameters ({', '.join(bad)}): these "
                        f"samples do not determine it")
    shape2 = np.clip(shape, L.shape_lo, L.shape_hi)
    hi = colour_upper(L, basis, shape2)
    tol = 1e-9 * np.maximum(np.abs(hi), 1.0)
    if (np.array_equal(shape2, shape) and np.all(colour >= L.colour_lo[:, None])
            and np.all(colour <= (hi + tol)[:, None])):
        return p, cost
    beyond = [f"{L.colour[k]} = {colour[k].max():.4g} > {hi[k]:.4g}" for k in range(L.K) if np.any(colour[k] > hi[k] + tol[k])]
    beyond += [f"{L.colour[k]} = {colour[k].min():.4g} < {L.colour_lo[k]:.4g}" for k in range(L.K)
               if np.any(colour[k] < L.colour_lo[k])]
    beyond += [f"{n} = {shape[j]:.4g}" for j, n in enumerate(L.shape) if shape2[j] != shape[j]]
    colour2 = np.clip(colour, L.colour_lo[:, None], hi[:, None])
    if basis is not None and basis.separable and lossobj.linear:
        wl = lossobj if lossobj.weight else LOSSES["cosine"]
        _, colour2 = _data_projection(basis, wl, prob.d, L)(shape2)
        colour2 = np.clip(colour2, L.colour_lo[:, None], hi[:, None])
    q = L.pack(colour2, shape2)
    notes.append(f"the solver ended outside the parameters' ranges ({'; '.join(beyond)}): projected back onto them")
    return q, float(prob.cost(q))


def _fit_layout(d: FitData, L: Layout, lossobj: Loss, *, n_starts, seed, method, kernel, max_nfev,
                optimum: tuple[np.ndarray, np.ndarray] | None = None, start: dict | None = None,
                search_n: int | None = None) -> FitResult:
    """One fit of the layout ``L`` (free, tied and fixed parameters decided) to prepared data.

    ``optimum = (colour, shape)`` skips the search: the caller knows the minimizer already (a tied
    parameter that sat exactly at the value it is now held at); the result is then built around it."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    heur = heuristics(d if len(d) <= COARSE_N else d.subset(rng.choice(len(d), COARSE_N, replace=False)))
    basis = make_basis(L, d, use_kernels=kernel == "auto", seed=seed)
    separable = basis is not None and basis.separable
    if method == "varpro" and not separable:
        raise ConfigError.field("--method", "method", method, f"{L.name} is not affine in its colour parameters")
    if method == "auto":
        method = "varpro" if separable else "plain"
    prob = _Problem(d, L, lossobj, basis if separable else None)
    prob.profile = profile_for(L) if separable and kernel == "auto" else None
    prob.jacobian = jacobian_for(L) if separable and kernel == "auto" else None
    notes: list[str] = []
    if np.all(d.y == 0):
        notes.append("all values are zero")
    if optimum is not None:
        colour, shape = optimum
        if separable and lossobj.linear:  # colours solved again at the held value
            _, colour = _data_projection(basis, lossobj, d, L)(shape)
        p = L.pack(colour, shape)
        cost = prob.cost(p)
    elif method == "varpro":
        wl = lossobj if lossobj.weight else LOSSES["cosine"]
        w = wl.weights_of(d)
        profile = prob.profile

        def projection(data_, w_, basis_=None):
            if profile is not None:  # the tied parameter is minimized exactly inside (kernels.PROFILES)
                return ProfiledProjection(profile, L, data_, w_, L.shape.index(profile.tied),
                                          wl.weights_T_of(d) if data_ is d else None)
            basis_ = basis_ or make_basis(L, data_, use_kernels=kernel == "auto", seed=seed)
            return Projection(basis_, np.ascontiguousarray(w_), data_.y, L.colour_lo, L.colour_hi,
                              (wl.weights_T_of(d), d.yT) if data_ is d else None)

        space = (separated(L) or L) if profile is None else SubSpace(L, [j for j, n in enumerate(L.shape) if n != profile.tied])
        proj = projection(d, w, basis)
        names = [L.shape[j] for j in (space.keep if isinstance(space, SubSpace) else range(L.S))]
        if start is not None and space.S and all(n in start for n in names):
            s0 = np.array([float(np.mean(start[n])) for n in names])
            shape, colour, cost = _refine(proj, space, space.to_u(s0))
        elif len(d) > (search_n or COARSE_N) and space.S:
            idx = np.sort(rng.choice(len(d), search_n or COARSE_N, replace=False))
            proj_s = projection(d.subset(idx), w[idx])
            shape_s, _, _ = _search_shape(proj_s, space, rng, n_starts)
            shape, colour, cost = _refine(proj, space, space.to_u(shape_s))
            prob.n_evals += proj_s.n_evals
        else:
            shape, colour, cost = _search_shape(proj, space, rng, n_starts)
        if profile is not None:
            shape = proj.full_shape(shape)
        p = L.pack(colour, shape)
        prob.n_evals += proj.n_evals
        if not lossobj.linear:
            p, cost = _plain(prob, [p], max_nfev)
            method = "varpro+plain"
        else:
            cost = prob.cost(p)
    else:
        p, cost = _plain(prob, _starts(prob, rng, n_starts, heur), max_nfev)
    p, cost = within_bounds(prob, L, basis, lossobj, p, cost, notes)
    p = p if L.links else canonical_order(L, p)  # linked lobes are ordered by the link itself
    shape_hi = _shape_dependent_bounds(basis, L, p)
    err, ident, redundancy = _uncertainty(prob, p, cost, notes, extra_bound=shape_hi)
    colour, shape = L.unpack(p)
    ecolour, eshape = L.unpack(err)
    params = L.params(colour, shape)
    params = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in params.items()}
    unc = {name: ecolour[k].tolist() for k, name in enumerate(L.colour)}
    unc.update({name: float(eshape[j]) for j, name in enumerate(L.shape)})
    rms_rel, chi2_red = d.fit_quality(prob.values(p), L.n_params)
    try:
        L.build(colour, shape)
    except GonioError as exc:
        notes.append(f"the fitted parameters violate a model constraint: {exc}")
    at_bound = bound_report(L, {**params, **L.link_values(shape)}, unc)
    for e in np.flatnonzero(shape_hi):
        reason = getattr(basis, "colour_hi_reason", None) or "a linked colour (ratio x its source) at its upper bound"
        at_bound.setdefault(L.colour[e // 3], {})[CHANNELS[e % 3]] = f"upper ({reason})"
    return FitResult(
        model_name=L.name, params=params, uncertainty=unc, loss=lossobj.name, cost=float(cost), rms_rel=rms_rel,
        n_used=len(d), n_params=L.n_params, chi2_red=chi2_red, identifiable=ident, method=method,
        n_evals=prob.n_evals, seconds=time.perf_counter() - t0, notes=notes, heuristics=heur,
        dropped=dict(d.dropped), redundancy=redundancy, at_bound=at_bound,
        links=L.link_values(shape),
    )


__all__ = ["fit", "within_bounds", "colour_upper", "resolve_loss", "heuristics", "bound_report", "NEAR_BOUND", "METHODS", "CHANNELS"]
