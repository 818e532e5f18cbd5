"""Fitting analytic BRDF models to measured samples, and choosing among them.

>>> import gonio
>>> result = gonio.fit(data, "lambert")        # doctest: +SKIP
>>> choice = gonio.select(data)                 # doctest: +SKIP

This package is callable: ``gonio.fit(data, model, ...)`` is :func:`gonio.api.fit` (``data`` a path,
a :func:`gonio.load` result or a SampleSet). The functions on samples are :func:`gonio.fit.fit.fit`
and :func:`gonio.fit.select.select`.
"""

import sys as _sys
import types as _types

from gonio.fit.data import DEFAULT_MAX_THETA_DEG, FitData, prepare
from gonio.fit.fit import METHODS, fit
from gonio.fit.losses import LOSSES, Loss, get_loss
from gonio.fit.result import FitResult

__all__ = ["fit", "prepare", "FitData", "FitResult", "LOSSES", "Loss", "get_loss", "METHODS",
           "DEFAULT_MAX_THETA_DEG"]


class _CallableFitPackage(_types.ModuleType):
    """``gonio.fit`` the package, callable as :func:`gonio.api.fit`."""

    def __call__(self, data, model: str = "microfacet", **options):
        from gonio.api import fit as api_fit

        return api_fit(data, model, **options)


_sys.modules[__name__].__class__ = _CallableFitPackage
