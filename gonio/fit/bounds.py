"""Where a fitted parameter sits in its range, judged on the parameter's own scale.

A parameter searched in log space (:meth:`gonio.fit.layout.Layout.search_space`: a positive range wider
than 100×, e.g. ABC's B in [10⁻², 10⁸], a roughness, an exponent, a tied Fresnel f0) is at a bound when
its *logarithm* is within a fraction ``tol`` of the log range of an end; any other parameter when its
value is within ``tol`` of the linear range (an unbounded range counts as max(|lo|, 1) wide). Judging a
log-scaled parameter against its linear range would call ABC's B = 9.23 "at its lower bound 0.01"
(within 10⁻⁷ · 10⁸ = 10 of it) although it sits 7 decades from both ends (issue 29).

The width ratio of two repeated lobes of a sum (:class:`gonio.fit.layout.SeparatedLobes`: the broad lobe
at least :data:`gonio.fit.layout.LOBE_RATIO_MIN` times the narrow one) is a structural bound too: a fit
that ends on it is reported under the broad lobe's width (``lobe2.alpha``), and that width has no
standard uncertainty.

Two tolerances: :data:`ON_BOUND` (the bound is active: no standard uncertainty, the Gauss–Newton
covariance of Press et al., *Numerical Recipes* 3rd ed. §15.5, does not apply to a constrained
parameter) and :data:`NEAR_BOUND` (reported in ``at_bound``). Every parameter on a bound is therefore
also reported.
"""

from __future__ import annotations

import numpy as np

from gonio.fit.layout import CHANNELS, LOBE_RATIO_MIN, Layout, auto_tied, separated

__all__ = ["ON_BOUND", "NEAR_BOUND", "entry_scales", "bound_flags", "ratio_flags", "bound_report"]

#: Fraction of a parameter's own-scale range within which a bound is active (no standard uncertainty).
ON_BOUND = 1e-7
#: Fraction of a parameter's own-scale range within which it is reported at or near a bound.
NEAR_BOUND = 1e-3


def entry_scales(L: Layout):
    """Per entry of the packed vector ``p`` of ``L`` (colours K×3, then shapes): ``(lo, hi, is_log,
    shown_lo)`` — the ends on the entry's own scale (logarithms where ``is_log``), and the lower end as
    reported (the floor of a log search of a range starting at 0, e.g. an exponent's 1)."""
    u_lo, u_hi, is_log = L.search_space()
    c_lo, c_hi = np.repeat(L.colour_lo, 3), np.repeat(L.colour_hi, 3)
    lo = np.concatenate([c_lo, u_lo])
    hi = np.concatenate([c_hi, u_hi])
    log = np.concatenate([np.zeros(c_lo.size, dtype=bool), is_log])
    shown = np.concatenate([c_lo, np.where(is_log, np.exp(u_lo), L.shape_lo)])
    return lo, hi, log, shown


def bound_flags(L: Layout, p: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` boolean masks over the packed ``p``: entries within ``tol`` of their range's end
    on their own scale (module docstring)."""
    p = np.asarray(p, dtype=np.float64)
    lo, hi, log, _ = entry_scales(L)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(log, np.log(np.maximum(p, 1e-300)), p)
    finite = np.isfinite(hi)
    span = np.where(finite, hi - lo, np.maximum(np.abs(lo), 1.0))
    lower = u - lo <= tol * span
    upper = finite & (hi - u <= tol * span)
    return lower, upper & ~lower


def ratio_flags(L: Layout, shape: np.ndarray, tol: float) -> dict[int, int]:
    """Shape entries of repeated lobes at the width-ratio bound :data:`LOBE_RATIO_MIN` within ``tol`` (of
    the log-ratio range): ``{index of the broad lobe's width: index of the narrower one's}``."""
    sep = separated(L)
    out: dict[int, int] = {}
    if sep is None:
        return out
    u_lo, u_hi, _ = sep.search_space()
    shape = np.asarray(shape, dtype=np.float64)
    for chain in sep.chains:
        for prev, j in zip(chain, chain[1:]):
            r = np.log(max(shape[j], 1e-300) / max(shape[prev], 1e-300))
            if r - u_lo[j] <= tol * max(u_hi[j] - u_lo[j], 1e-12):
                out[j] = prev
    return out


def _layout_of(model) -> Layout:
    if isinstance(model, Layout):
        return model
    return Layout(model, tied=auto_tied(model, {}))


def bound_report(model, params: dict, uncertainty: dict | None = None, tol: float = NEAR_BOUND) -> dict:
    """Fitted parameters at or near a bound: name -> {channel ("r", "g", "b") or "value": "lower 0",
    "upper 1", or for a repeated lobe's width "lower ratio 2 to lobe1.alpha"}.

    ``model`` is the fit's :class:`~gonio.fit.layout.Layout` (or a model class: its default layout, the
    Fresnel f0 tied). Only the parameters in ``uncertainty`` (the fitted ones; all of ``params`` when
    None) are judged, each on its own scale (module docstring)."""
    L = _layout_of(model)
    judged = set(params if uncertainty is None else uncertainty)
    colour = np.zeros((L.K, 3))
    shape = L.default_shape()
    present = np.zeros(3 * L.K + L.S, dtype=bool)
    for k, n in enumerate(L.colour):
        if n in params and n in judged:
            colour[k] = np.broadcast_to(np.asarray(params[n], dtype=np.float64), (3,))
            present[3 * k:3 * k + 3] = True
    for j, n in enumerate(L.shape):
        if n in params and n in judged:
            shape[j] = float(np.mean(params[n]))
            present[3 * L.K + j] = True
    p = L.pack(colour, shape)
    lower, upper = bound_flags(L, p, tol)
    _, hi, log, shown = entry_scales(L)
    out: dict = {}
    for e in np.flatnonzero((lower | upper) & present):
        if e < 3 * L.K:
            name, key = L.colour[e // 3], CHANNELS[e % 3]
        else:
            name, key = L.shape[e - 3 * L.K], "value"
        end = f"lower {shown[e]:g}" if lower[e] else f"upper {(np.exp(hi[e]) if log[e] else hi[e]):g}"
        out.setdefault(name, {})[key] = end
    for j, prev in ratio_flags(L, shape, tol).items():
        if present[3 * L.K + j] and L.shape[j] not in out:
            out[L.shape[j]] = {"value": f"lower ratio {LOBE_RATIO_MIN:g} to {L.shape[prev]}"}
    return out
