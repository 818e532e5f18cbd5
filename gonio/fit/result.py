"""The result of a fit: parameters, standard uncertainties, errors and how they were obtained."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


def _clean(x):
    """JSON-safe: arrays to lists, non-finite floats to None."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


@dataclass
class FitResult:
    """One fitted model.

    Attributes
    ----------
    model : str
        Registry name; ``params`` rebuild it with :func:`gonio.brdf.make`.
    params : dict
        Fitted parameters (RGB as 3 floats, shape parameters as floats, choices as strings).
    uncertainty : dict
        Standard uncertainty of every fitted parameter (same layout); ``inf`` where the data do not
        determine it (see ``notes``), ``nan`` where the value sits on a bound.
    loss : str
        Name of the minimized loss (:data:`gonio.fit.losses.LOSSES`).
    cost : float
        ½ Σ r² at the optimum.
    rms_rel : float
        Relative cosine-weighted RMS error √(Σ cos²θi (f_m − f)² / Σ cos²θi f²), whatever the loss.
    n_used, n_params : int
        Samples used (each has 3 channels) and free parameters.
    chi2_red : float or None
        χ²/(m − k) with the stated uncertainties (None without them).
    """

    model: str
    params: dict[str, Any]
    uncertainty: dict[str, Any]
    loss: str
    cost: float
    rms_rel: float
    n_used: int
    n_params: int
    chi2_red: float | None = None
    identifiable: bool = True
    method: str = ""
    n_evals: int = 0
    seconds: float = 0.0
    notes: list[str] = field(default_factory=list)
    heuristics: dict[str, Any] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    #: For sums of lobes: largest |correlation| between parameters of two different terms and their
    #: names, ``(|ρ|, a, b)``; near 1 the data cannot tell the terms apart (see :mod:`gonio.fit.select`).
    redundancy: tuple | None = None

    @property
    def n_residuals(self) -> int:
        return 3 * self.n_used

    @property
    def neg2_log_likelihood(self) -> float:
        """−2 ln L up to a constant: χ² when the loss is χ², else m ln(RSS/m) (Gaussian, unknown variance)."""
        m = self.n_residuals
        if self.loss == "chi2":
            return 2.0 * self.cost
        return m * math.log(max(2.0 * self.cost / m, 1e-300))

    @property
    def aic(self) -> float:
        """Akaike information criterion −2 ln L + 2k (Akaike 1974)."""
        return self.neg2_log_likelihood + 2.0 * self.n_params

    @property
    def bic(self) -> float:
        """Bayesian information criterion −2 ln L + k ln m (Schwarz 1978), m = number of residuals."""
        return self.neg2_log_likelihood + self.n_params * math.log(self.n_residuals)

    def build(self):
        """The fitted :class:`gonio.brdf.BRDF` instance."""
        from gonio.brdf import make

        return make(self.model, source="fit result", **self.params)

    def to_dict(self) -> dict[str, Any]:
        """The JSON report of ``gonio fit --json`` (without ``candidates``)."""
        return _clean({
            "model": self.model,
            "params": self.params,
            "uncertainty": self.uncertainty,
            "loss": self.loss,
            "error": {"cost": self.cost, "rms_rel": self.rms_rel, "chi2_red": self.chi2_red,
                      "aic": self.aic, "bic": self.bic},
            "n_used": self.n_used,
            "n_params": self.n_params,
            "identifiable": self.identifiable,
            "method": self.method,
            "notes": self.notes,
            "heuristics": self.heuristics,
            "dropped": self.dropped,
            "redundancy": list(self.redundancy) if self.redundancy else None,
        })
