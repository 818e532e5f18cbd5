"""The exact gradient of the variable-projection cost over the shape parameters, for the shape search.

For r(a, s) = f₀(s) + Σₖ aₖ Bₖ(s) − y and the projected cost C(s) = min_{lo ≤ a ≤ hi(s)} ½ Σ w r², the envelope
theorem (Danskin's theorem for a minimum over a set; for variable projection Golub & Pereyra 1973, §4; the
gradient of the reduced functional, Kaufman, BIT 15, 1975) gives, at the minimizing colours a*,

    ∂C/∂sⱼ = Σ w r (∂f₀/∂sⱼ + Σₖ a*ₖ ∂Bₖ/∂sⱼ) + Σ_{k at hiₖ(s)} (Σ w r Bₖ) ∂hiₖ/∂sⱼ

— the colours' own change drops out (∂C/∂a = 0 where a colour is free, and a fixed bound does not move); a bound
that depends on the shape (a linked colour's ``top / ratio``, :meth:`gonio.fit.layout.Layout.linked_colour_hi`)
moves its colour with it. So one gradient costs one evaluation plus the derivative vectors of the basis, where
central differences cost 2 evaluations per shape parameter (forward ones: one each).

The derivative vectors come from the basis: :class:`gonio.fit.layout.Basis` asks its kernel
(``kernel.derivatives(data, layout, shape)``, e.g. GGX's ∂S/∂α, :func:`gonio.fit.kernels._ggx_spec_dalpha`),
:class:`gonio.fit.layout.SumBasis` assembles its terms' and its links'. A basis without them (no kernel, a kernel
without derivatives, a shape-dependent bound without a derivative) has no gradient here: the search then
differentiates the cost numerically as before. The search runs in the transformed space of
:mod:`gonio.fit.layout` (log-scaled widths, lobe width ratios), so the gradient is carried through
``to_shape`` by the chain rule (:func:`map_jacobian`). ``tests/fit/test_gradient.py`` checks all of it against
central differences.
"""

from __future__ import annotations

import numpy as np


def has_derivatives(basis) -> bool:
    """Whether :func:`basis_derivatives` can differentiate ``basis`` (checked once, from its structure)."""
    from gonio.fit.layout import Basis, SumBasis

    if isinstance(basis, SumBasis):
        return all(has_derivatives(b) for _, b, _, _ in basis.parts)
    if not isinstance(basis, Basis):
        return False
    if basis.layout.S == 0:
        return True
    k = basis.kernel
    return (k is not None and getattr(k, "derivatives", None) is not None
            and getattr(k, "colour_hi", None) is None and k.derivatives.supports(basis.layout))


def basis_derivatives(basis, shape) -> list[tuple]:
    """``[(∂f₀/∂sⱼ or None, [∂Bₖ/∂sⱼ or None for each colour k]) for each shape parameter j]`` at ``shape``
    (arrays (N,) or (N, 3), None where zero), for a basis with :func:`has_derivatives`."""
    from gonio.fit.layout import SumBasis

    shape = np.asarray(shape, dtype=np.float64)
    L = basis.layout
    if not isinstance(basis, SumBasis):
        if L.S == 0:
            return []
        per = basis.kernel.derivatives(basis.data, L, dict(zip(L.shape, map(float, shape))))
        return [per[name] for name in L.shape]
    out: list[list] = [[None, {}] for _ in range(L.S)]
    cols: dict[str, np.ndarray] = {}
    for sub, b, shape_idx, names in basis.parts:
        if b.layout.S:
            _, pcols = b(shape[shape_idx])
            for j, (df0, dcols) in zip(shape_idx, basis_derivatives(b, shape[shape_idx])):
                out[j][0] = df0
                out[j][1].update((n, d) for n, d in zip(names, dcols) if d is not None)
        else:
            _, pcols = b(shape[shape_idx])
        cols.update(zip(names, pcols))
    for (dst, src, r), jr in zip(L.links, basis._link_index):  # colour src's basis is B_src + w B_dst
        w = shape[jr]
        for j in range(L.S):
            d = out[j][1].pop(dst, None)
            if d is not None:
                out[j][1][src] = _add(out[j][1].get(src), w * d)
        out[jr][1][src] = _add(out[jr][1].get(src), cols[dst])
    return [(df0, [dcols.get(n) for n in L.colour]) for df0, dcols in out]


def _add(a, b):
    if a is None:
        return b
    if a.ndim != b.ndim:
        a, b = (a if a.ndim == 2 else a[:, None]), (b if b.ndim == 2 else b[:, None])
    return a + b


def colour_hi_gradient(basis, shape, hi: np.ndarray) -> np.ndarray | None:
    """∂hiₖ/∂sⱼ (K, S) of the shape-dependent upper bounds of the colours where they are the ones in force
    (``hi``, the bounds the projection used), or None where no bound depends on the shape: a linked colour's
    source is bounded by ``top / w`` (:meth:`gonio.fit.layout.Layout.linked_colour_hi`), whose derivative in the
    ratio w is −top / w²."""
    L = basis.layout
    if not L.links:
        return None
    L.linked_colour_hi(shape)  # fills L._link_steps
    out = np.zeros((L.K, L.S))
    for k, j, top in L._link_steps:
        w = max(float(shape[j]), 1e-300)
        if top / w <= hi[k]:
            out[k, j] = -top / (w * w)
    return out


def projection_gradient(basis, shape, a: np.ndarray, wr: np.ndarray, first: bool, hi: np.ndarray) -> np.ndarray:
    """∂C/∂s (S,) of :class:`gonio.fit.solve.Projection`'s cost at ``shape`` (module docstring) on ``basis``, from
    its colours ``a`` (3, K), its weighted residuals ``wr`` = w r (channels first, (3, N), when ``first``, else
    (N, 3)) and the colours' upper bounds ``hi`` (K,) there."""
    derivs = basis_derivatives(basis, shape)

    def contract(v) -> np.ndarray:
        """Σₙ w r v per channel (3,) for a vector v (N,) or (N, 3)."""
        if first:
            return wr @ v if v.ndim == 1 else np.einsum("cn,nc->c", wr, v)
        return v @ wr if v.ndim == 1 else np.einsum("nc,nc->c", wr, v)

    g = np.zeros(len(derivs))
    for j, (df0, dcols) in enumerate(derivs):
        if df0 is not None and not getattr(df0, "is_zero", False):
            g[j] += contract(np.asarray(df0)).sum()
        for k, d in enumerate(dcols):
            if d is not None:
                g[j] += contract(d) @ a[:, k]
    dhi = colour_hi_gradient(basis, shape, hi)
    if dhi is not None:
        at_hi = a >= hi[None, :]  # (3, K): the colours held at a bound that moves with the shape
        if at_hi.any():
            _, cols = basis(shape)
            for k in np.flatnonzero(at_hi.any(axis=0)):
                lam = contract(cols[k]) * at_hi[:, k]  # ∂C/∂aₖ per channel, where at the bound
                g += lam.sum() * dhi[k]
    return g


def map_jacobian(space, u) -> np.ndarray:
    """ds/du (S, S) of ``space.to_shape`` (:class:`gonio.fit.layout.Layout`, :class:`~gonio.fit.layout.SubSpace`:
    diagonal, s for a log-scaled parameter and 1 for a linear one; :class:`~gonio.fit.layout.SeparatedLobes`: a
    later lobe's width s_prev · exp(u) follows the one before), 0 where ``to_shape`` clips."""
    from gonio.fit.layout import SeparatedLobes

    u = np.asarray(u, dtype=np.float64)
    s = space.to_shape(u)
    if isinstance(space, SeparatedLobes):
        _, _, is_log = space.layout.search_space()
        J = np.diag(np.where(is_log, s, 1.0) * _inside(space.layout, u))
        for prev, j, _, lo, hi in space._steps:  # in chain order: row prev is final when row j is formed
            raw = s[prev] * np.exp(u[j])
            J[j] = 0.0
            if _within(raw, lo, hi):
                J[j] = np.exp(u[j]) * J[prev]
                J[j, j] = raw
        return J
    _, _, is_log = space.search_space()
    d = np.where(is_log, s, 1.0)
    d[~_inside(space, u)] = 0.0
    return np.diag(d)


def _inside(space, u) -> np.ndarray:
    """Whether each parameter's unclipped value exp(u) (or u) lies within its range, to rounding (``to_shape``
    does not clip it: the search box's own ends, exp(log(hi)), are inside)."""
    _, _, is_log = space.search_space()
    return _within(np.where(is_log, np.exp(u), u), space.shape_lo, space.shape_hi)


def _within(x, lo, hi):
    tol = 1e-9 * np.maximum(np.abs(lo), np.abs(hi))
    return (x >= lo - tol) & (x <= hi + tol)
