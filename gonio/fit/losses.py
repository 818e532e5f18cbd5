"""Fitting losses as per-sample residual transforms (so any of them can be minimized by least squares).

Each loss maps a model value ``m`` and a measured value ``y`` (both BRDF values in 1/sr, shape
``(N, 3)``), the cosine of the incidence angle and the standard uncertainty ``sigma`` to residuals
``r`` of the same shape; the fit minimizes ``½ Σ r²``. A loss is *linear* when ``r`` is an affine
function of ``m`` (``r = √w · (m − y)``): then the colour parameters, which enter the models linearly,
can be solved in closed form (variable projection, :mod:`gonio.fit.fit`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from gonio.errors import ConfigError


@dataclass(frozen=True)
class Loss:
    """One fitting loss.

    Attributes
    ----------
    name : str
        Registry name (CLI ``--loss``, JSON reports).
    residual : callable ``(m, y, cos_i, sigma) -> r``
        Residuals, shape ``(N, 3)``.
    weight : callable ``(y, cos_i, sigma) -> w`` or None
        For linear losses, the weights with ``r = √w (m − y)``; ``None`` for non-linear losses.
    needs_sigma : bool
        The loss divides by the per-sample uncertainties.
    doc : str
        One line with the formula and its source.
    by_weight : bool
        ``residual`` is computed as √w (m − y) from ``weight`` itself, so :meth:`residuals_of` may use the weights
        remembered for the data.
    """

    name: str
    residual: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    weight: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None
    needs_sigma: bool
    doc: str
    by_weight: bool = False

    @property
    def linear(self) -> bool:
        """Residuals are affine in the model value (variable projection applies)."""
        return self.weight is not None

    def weights_of(self, d) -> np.ndarray:
        """``weight`` at the samples of prepared data ``d`` (:class:`gonio.fit.data.FitData`), computed once per
        data and remembered on it (a fit asks for them several times: the projection, the uncertainties, the
        costs; the robust loss's cost 0.13 CPU s a time on a MERL table). Read-only: the data's arrays are not
        changed after :func:`gonio.fit.data.prepare` (their geometry is cached on them the same way)."""
        return self._remembered(d, "weights", lambda: self.weight(d.y, d.cos_i, d.sigma))

    def root_weights_of(self, d) -> np.ndarray:
        """√``weight`` at the samples of ``d``, remembered on it like :meth:`weights_of` (every cost of a fit
        takes it: :meth:`residuals_of`)."""
        return self._remembered(d, "root weights", lambda: np.sqrt(self.weights_of(d)))

    def channel_weights_of(self, d) -> np.ndarray:
        """:meth:`weights_of` as :func:`gonio.fit.solve.weighted_gram` reads it, remembered on ``d``: one column
        (N,) when every channel has the same weight (:func:`gonio.fit.solve.shared_weights`), else (N, 3) laid
        out channels first (the transpose of a contiguous (3, N) array), so no call copies it."""
        from gonio.fit.solve import shared_weights

        def make():
            w1 = shared_weights(self.weights_of(d))
            return self.weights_T_of(d).T if w1 is None else w1

        return self._remembered(d, "channel weights", make)

    def weights_T_of(self, d) -> np.ndarray:
        """:meth:`weights_of` channels first, (3, N) C-contiguous, remembered on ``d``."""
        return self._remembered(d, "weights channels first", lambda: np.ascontiguousarray(self.weights_of(d).T))

    def _remembered(self, d, what: str, make) -> np.ndarray:
        cache = d.__dict__.setdefault("_kernel_cache", {})
        key = (what, self.name)
        w = cache.get(key)
        if w is None:
            w = make()
            if w.flags.writeable:
                w.setflags(write=False)
            cache[key] = w
        return w

    def residuals_of(self, m: np.ndarray, d) -> np.ndarray:
        """``residual`` of model values ``m`` at all samples of ``d``: the same numbers, from the remembered weights
        (:meth:`root_weights_of`) where the residual is defined by them (``by_weight``)."""
        if self.by_weight:
            return (m - d.y) * self.root_weights_of(d)
        return self.residual(m, d.y, d.cos_i, d.sigma)


def _cos_weight(y, cos_i, sigma):
    """Cosine-weighted L2 weights ``w = cos²θi``.

    E = Σ (f_m cos θi − f cos θi)²: the cosine-weighted error of Lafortune et al. (1997) used by
    Ngan, Durand & Matusik, "Experimental Analysis of BRDF Models", EGSR 2005 (their Eq. 3, without
    the square root and normalization, which do not move the minimum).
    """
    return np.broadcast_to((cos_i * cos_i)[:, None], y.shape)


def _cos_residual(m, y, cos_i, sigma):
    return (m - y) * cos_i[:, None]


def _chi2_weight(y, cos_i, sigma):
    """χ² weights ``w = 1/σ²`` (per sample and channel): the maximum-likelihood fit under Gaussian noise
    of known standard uncertainty σ (e.g. Press et al., *Numerical Recipes*, 3rd ed., §15.1)."""
    return 1.0 / (sigma * sigma)


def _chi2_residual(m, y, cos_i, sigma):
    return (m - y) / sigma


def _log_residual(m, y, cos_i, sigma):
    """``r = ln(1 + m cos θi) − ln(1 + y cos θi)``: the log-based metric of Löw, Kronander, Ynnerman &
    Unger, "BRDF Models for Accurate and Efficient Rendering of Glossy Surfaces", ACM TOG 31(1), 2012
    (Eq. 16). Compresses the dynamic range of sharp specular peaks."""
    c = cos_i[:, None]
    return np.log1p(np.maximum(m * c, -0.999999)) - np.log1p(np.maximum(y * c, -0.999999))


def _cbrt_residual(m, y, cos_i, sigma):
    """``r = ∛(m cos θi) − ∛(y cos θi)``: the cube-root metric found perceptually best by Forés,
    Ferwerda & Gu, "Toward a Perceptually Based Metric for BRDF Modeling", CIC 2012."""
    c = cos_i[:, None]
    return np.cbrt(m * c) - np.cbrt(y * c)


#: Floor ε (1/sr) of the robust loss's weights: below it a value counts as ε (noise-level values are not
#: given unbounded weight). 1e-4 1/sr is a diffuse albedo of 3·10⁻⁴, darker than any MERL material.
ROBUST_EPS = 1e-4


def _robust_weight(y, cos_i, sigma):
    """Weights of the *robust* loss, ``w = cos²θi / (9 (f cos θi + ε)^(4/3))``: the cube-root metric
    (∛(f_m cos θi) − ∛(f cos θi))² (Forés, Ferwerda & Gu 2012; the compression Ngan et al. 2005 compare
    fits with) linearized about the data, d∛x = dx / (3 x^(2/3)). Residuals stay linear in the model, so
    the colours are solved in closed form (variable projection), yet a specular peak 10⁶ times the diffuse
    level no longer outweighs the diffuse floor: an error counts relative to (f cos θi)^(2/3). ε =
    :data:`ROBUST_EPS` bounds the weight of values at the noise floor."""
    c = cos_i[:, None]
    return (c * c) / (9.0 * np.cbrt(y * c + ROBUST_EPS) ** 4)


def _robust_residual(m, y, cos_i, sigma):
    return (m - y) * np.sqrt(_robust_weight(y, cos_i, sigma))


#: Registry: loss name -> :class:`Loss`.
LOSSES: dict[str, Loss] = {
    loss.name: loss
    for loss in (
        Loss("cosine", _cos_residual, _cos_weight, False,
             "cosine-weighted L2: (f_m cos θi − f cos θi)² (Ngan, Durand & Matusik 2005)"),
        Loss("chi2", _chi2_residual, _chi2_weight, True,
             "χ²: ((f_m − f)/σ)² with the per-sample standard uncertainties"),
        Loss("log", _log_residual, None, False,
             "log: (ln(1 + f_m cos θi) − ln(1 + f cos θi))² (Löw et al. 2012)"),
        Loss("robust", _robust_residual, _robust_weight, False,
             "robust: cube-root error linearized at the data, cos²θi (f_m − f)² / (9 (f cos θi + ε)^(4/3)) "
             "(Forés et al. 2012, Ngan et al. 2005); the default without uncertainties", by_weight=True),
        Loss("cbrt", _cbrt_residual, None, False,
             "cube root: (∛(f_m cos θi) − ∛(f cos θi))² (Forés, Ferwerda & Gu 2012)"),
    )
}


def get_loss(name: str, *, source: str | None = "loss") -> Loss:
    """The :class:`Loss` registered as ``name``; :class:`ConfigError` naming the known ones otherwise."""
    try:
        return LOSSES[name]
    except KeyError:
        raise ConfigError.field(None, source or "loss", name,
                                f"unknown loss; known: {', '.join(LOSSES)}") from None
