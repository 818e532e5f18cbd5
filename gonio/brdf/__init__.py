"""Analytic BRDF models, one published model per module, and their registry.

>>> from gonio.brdf import make
>>> make("lambert", albedo=0.5).eval([0, 0, 1], [0, 0, 1])  # doctest: +SKIP
array([0.159..., 0.159..., 0.159...])
"""

from __future__ import annotations

from typing import Any

from gonio.brdf.abc import ABCMicrofacet, ABCSmooth
from gonio.brdf.abc_conductor import ABCSmoothConductor
from gonio.brdf.ashikhmin_shirley import AshikhminShirley
from gonio.brdf.base import BRDF, Param
from gonio.brdf.blinn_phong import BlinnPhong
from gonio.brdf.coated import Dupuy2015Coated
from gonio.brdf.cook_torrance import CookTorrance
from gonio.brdf.dupuy import Dupuy2015, Dupuy2015Conductor
from gonio.brdf.gtr import GTR
from gonio.brdf.lafortune import Lafortune
from gonio.brdf.lambert import Lambert
from gonio.brdf.lobes import PRESETS, is_sum_name, lobe_sum
from gonio.brdf.microfacet import Microfacet
from gonio.brdf.oren_nayar import OrenNayar
from gonio.brdf.phong import Phong
from gonio.brdf.ward import Ward
from gonio.errors import ConfigError

#: Registry: model name -> class. Names are a contract (material files, CLI, fit reports).
MODELS: dict[str, type[BRDF]] = {
    cls.name: cls
    for cls in (Lambert, Phong, BlinnPhong, CookTorrance, Microfacet, Ward, Lafortune, OrenNayar, AshikhminShirley)
}
MODELS.update({cls.name: cls for cls in (ABCMicrofacet, ABCSmooth, GTR)})  # models for real measurements (issue 14)
MODELS[ABCSmoothConductor.name] = ABCSmoothConductor  # a metal's Fresnel with its own scale (issue 29)
MODELS.update({c.name: c for c in (Dupuy2015, Dupuy2015Conductor)})  # data-driven microfacet (Dupuy et al. 2015)
MODELS[Dupuy2015Coated.name] = Dupuy2015Coated  # a metal under a thin dielectric coat (issue 29)
MODELS.update({name: lobe_sum(name) for name in PRESETS})


def make(name: str, *, source: str | None = None, **params: Any) -> BRDF:
    """Construct the model registered as ``name`` with ``params``.

    Sums of lobes (``"lambert+2ggx"`` etc., :mod:`gonio.brdf.lobes`) are accepted by name even when
    not listed in ``MODELS``. ``source`` (a file name or option) is named in the :class:`ConfigError` raised for an unknown
    model or a bad parameter.
    """
    try:
        cls = MODELS[name]
    except KeyError:
        if is_sum_name(name):
            try:
                cls = lobe_sum(name)
            except ConfigError as exc:
                raise ConfigError(f"{source + ': ' if source else ''}{exc}") from None
            return cls(_source=source, **params)
        raise ConfigError.field(source, "model", name, f"unknown model; known: {', '.join(sorted(MODELS))}") from None
    return cls(_source=source, **params)


__all__ = ["BRDF", "Param", "MODELS", "make"]
