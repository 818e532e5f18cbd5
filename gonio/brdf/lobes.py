"""Sums of lobes as one model (e.g. diffuse + one or two specular lobes), for fitting multi-lobe
materials.

Names: a sum is named by its terms joined with ``+``; a digit before a term repeats it:
``"lambert+ggx"``, ``"lambert+2ggx"`` (diffuse + two GGX lobes), ``"oren-nayar+beckmann"``,
``"lambert+ggx+blinn-phong"``. Terms (:data:`TERMS`):

==============  ==========================================================  =====================
term            model (fixed parameters)                                    parameters
==============  ==========================================================  =====================
lambert         ``lambert``                                                 albedo (rgb)
oren-nayar      ``oren-nayar``                                              albedo (rgb), sigma
ggx, beckmann   ``microfacet`` (kd = 0, distribution fixed)                 ks (rgb), alpha, f0 (rgb)
blinn-phong     ``blinn-phong`` (kd = 0)                                    ks (rgb), exponent
phong           ``phong`` (kd = 0)                                          ks (rgb), exponent
cook-torrance   ``cook-torrance`` (kd = 0)                                  ks (rgb), roughness, f0 (rgb)
ward            ``ward`` (kd = 0)                                           ks (rgb), alpha_x, alpha_y
==============  ==========================================================  =====================

Parameters are namespaced by the term's slot: diffuse terms are ``diffuse`` (then ``diffuse2``...),
specular terms ``lobe1``, ``lobe2``, ... in order, e.g. for ``lambert+2ggx``: ``diffuse.albedo``,
``lobe1.ks``, ``lobe1.alpha``, ``lobe1.f0``, ``lobe2.ks``, ``lobe2.alpha``, ``lobe2.f0``. Each
keeps its :class:`~gonio.brdf.base.Param` (kind ``rgb``/``scalar``, range, default), so
``bounds()`` and ``params`` work as for any model and colour parameters stay per channel while
shape parameters are shared. ``gonio.brdf.make`` accepts any such name (the common ones are listed
in ``MODELS``); :func:`lobe_sum` returns the class.

f(wi, wo) = Σ_terms f_term(wi, wo). A sum is reciprocal/isotropic if all its terms are; it conserves
energy when its terms do and their weights (albedo, ks) add up to ≤ 1 per channel.
"""

from __future__ import annotations

import functools
import re
from types import MappingProxyType
from typing import Any


from gonio.brdf.base import BRDF, Param
from gonio.brdf.blinn_phong import BlinnPhong
from gonio.brdf.cook_torrance import CookTorrance
from gonio.brdf.lambert import Lambert
from gonio.brdf.microfacet import Microfacet
from gonio.brdf.oren_nayar import OrenNayar
from gonio.brdf.phong import Phong
from gonio.brdf.ward import Ward
from gonio.errors import ConfigError

__all__ = ["TERMS", "PRESETS", "Sum", "lobe_sum", "is_sum_name"]

#: term name -> (model class, fixed parameters, is diffuse)
TERMS: dict[str, tuple[type[BRDF], dict[str, Any], bool]] = {
    "lambert": (Lambert, {}, True),
    "oren-nayar": (OrenNayar, {}, True),
    "ggx": (Microfacet, {"kd": 0.0, "distribution": "ggx"}, False),
    "beckmann": (Microfacet, {"kd": 0.0, "distribution": "beckmann"}, False),
    "blinn-phong": (BlinnPhong, {"kd": 0.0}, False),
    "phong": (Phong, {"kd": 0.0}, False),
    "cook-torrance": (CookTorrance, {"kd": 0.0}, False),
    "ward": (Ward, {"kd": 0.0}, False),
}
#: Sums registered in ``gonio.brdf.MODELS`` (any other valid name also works with ``make``).
PRESETS = ("lambert+ggx", "lambert+2ggx", "lambert+beckmann", "lambert+2beckmann", "lambert+blinn-phong",
           "lambert+2blinn-phong", "lambert+cook-torrance", "lambert+2cook-torrance", "lambert+ward",
           "oren-nayar+ggx")
_TERM_RE = re.compile(r"^([1-9]?)(.+)$")


def is_sum_name(name: str) -> bool:
    """True if ``name`` looks like a sum (contains ``+`` or starts with a repeat count)."""
    return isinstance(name, str) and ("+" in name or bool(re.match(r"^[2-9]", name)))


def _parse(name: str) -> list[str]:
    terms = []
    for part in name.split("+"):
        m = _TERM_RE.match(part.strip())
        if not m or m.group(2) not in TERMS:
            raise ConfigError.field(None, "model", name,
                                    f"unknown term {part!r} in a sum; terms: {', '.join(TERMS)} (a digit repeats one)")
        terms += [m.group(2)] * int(m.group(1) or 1)
    if len(terms) < 2:
        raise ConfigError.field(None, "model", name, "a sum needs at least two terms")
    return terms


class Sum(BRDF):
    """Base of the generated sum classes (see the module docstring); use :func:`lobe_sum`."""

    #: (slot, model class, fixed parameters) of each term, in order.
    PARTS: tuple = ()

    def __init__(self, *, _source: str | None = None, **params: Any):
        super().__init__(_source=_source, **params)
        parts = []
        for slot, cls, fixed in self.PARTS:
            own = {k.split(".", 1)[1]: v for k, v in self._params.items() if k.split(".", 1)[0] == slot}
            parts.append(cls(_source=_source, **fixed, **own))
        object.__setattr__(self, "_parts", tuple(parts))

    def _astype(self, dtype) -> "BRDF":
        twin = super()._astype(dtype)
        object.__setattr__(twin, "_parts", tuple(p._astype(dtype) for p in self._parts))
        return twin

    @property
    def parts(self) -> tuple[BRDF, ...]:
        """The term models (with their fixed parameters filled in), in order."""
        return self._parts

    def _lobes(self):
        """The terms' lobes together (one shared geometry for all of them), if every term is written as
        lobes (:meth:`gonio.brdf.base.BRDF._lobes`); else None."""
        parts = [p._lobes() for p in self._parts]
        if any(p is None for p in parts):
            return None
        return _combine(parts)

    def _eval(self, wi, wo):
        """Σ terms: the terms written as lobes share one geometry (:func:`gonio.brdf.pairs.evaluate`), the
        others are evaluated on their own and added."""
        from gonio.brdf.pairs import evaluate

        described = [(p, p._lobes()) for p in self._parts]
        shared = [d for _, d in described if d is not None]
        total = evaluate(*_combine(shared), wi, wo) if shared else None
        for part, d in described:
            if d is None:
                v = part._eval(wi, wo)
                total = v if total is None else total + v
        return total


def _combine(parts):
    """``(const, lobes)`` of a sum from those of its terms: constants added, lobes concatenated."""
    const, lobes = parts[0][0], list(parts[0][1])
    for c, ls in parts[1:]:
        const = const + c
        lobes += ls
    return const, lobes


@functools.lru_cache(maxsize=None)
def lobe_sum(name: str) -> type[Sum]:
    """The :class:`Sum` subclass for a sum name such as ``"lambert+2ggx"`` (cached: one class per name)."""
    terms = _parse(name)
    n_diffuse = n_spec = 0
    parts, params = [], {}
    for term in terms:
        cls, fixed, diffuse = TERMS[term]
        if diffuse:
            n_diffuse += 1
            slot = "diffuse" if n_diffuse == 1 else f"diffuse{n_diffuse}"
        else:
            n_spec += 1
            slot = f"lobe{n_spec}"
        parts.append((slot, cls, MappingProxyType(dict(fixed))))
        for key, spec in cls.PARAMS.items():
            if key not in fixed:
                params[f"{slot}.{key}"] = Param(spec.kind, spec.lo, spec.hi, spec.default, spec.choices,
                                                f"{term}: {spec.doc}")
    classes = [TERMS[t][0] for t in terms]
    return type(f"Sum[{name}]", (Sum,), {
        "name": name, "PARAMS": MappingProxyType(params), "PARTS": tuple(parts), "__module__": __name__,
        "reciprocal": all(c.reciprocal for c in classes), "isotropic": all(c.isotropic for c in classes),
        "energy_conserving": all(c.energy_conserving for c in classes),
        "__doc__": f"Sum of lobes {' + '.join(terms)}; see :mod:`gonio.brdf.lobes`.",
    })
