"""Fitting analytic BRDF models to measured samples, and choosing among them.

>>> from gonio.fit import fit, select          # doctest: +SKIP
>>> result = fit(samples, "lambert")           # doctest: +SKIP
>>> report = select(samples)                    # doctest: +SKIP
"""

from gonio.fit.data import DEFAULT_MAX_THETA_DEG, FitData, prepare
from gonio.fit.fit import METHODS, fit
from gonio.fit.losses import LOSSES, Loss, get_loss
from gonio.fit.result import FitResult

__all__ = ["fit", "prepare", "FitData", "FitResult", "LOSSES", "Loss", "get_loss", "METHODS",
           "DEFAULT_MAX_THETA_DEG"]
