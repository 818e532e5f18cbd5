"""Lafortune's generalized cosine lobes (isotropic form), with any number of lobes.

Parametrization (numeric, for fitting): ``kd`` (RGB) plus, for lobe j = 1..N,
``lobe{j}.cx`` (= C_x = C_y, scalar in [−1, 1]), ``lobe{j}.cz`` (scalar in [−1, 1]),
``lobe{j}.n`` (exponent in [0, 1e6]) and ``lobe{j}.rho`` (RGB lobe weight ρ_j ≥ 0, 1/sr).
Constructed by the one registry name ``lafortune``; the number of lobes follows from the
parameters given:

>>> make("lafortune", kd=0.1, **{"lobe1.cx": -1, "lobe1.cz": 1, "lobe1.n": 30, "lobe1.rho": 5})  # doctest: +SKIP
>>> make("lafortune", kd=0.1, lobes=[(-1, 1, 30, 5.0), (-0.5, 0.8, 4, [1, 0.8, 0.6])])  # doctest: +SKIP
>>> make("lafortune", lobes=2)  # two lobes with default values  # doctest: +SKIP

``lobes`` (a count, or a list of ``(cx, cz, n, rho)`` tuples or ``{"cx", "cz", "n", "rho"}`` dicts) is
a convenience that is expanded into the flat ``lobe{j}.*`` parameters; ``params`` always returns
the flat form, so ``make("lafortune", **model.params)`` round-trips.

Why |C| ≤ 1: |C_x(u_x v_x + u_y v_y) + C_z u_z v_z| ≤ max(|C_x|, |C_z|) for unit vectors, so the
base of the power never exceeds 1 and the lobe stays finite for exponents up to 1e6. This costs no
generality: scaling C by s scales the lobe by s^n, which ρ absorbs; only the ratio C_x/C_z (the
lobe's direction: −1/1 is the mirror direction, C_x = 0 retro-/normal-directed, |C_x| < C_z
off-specular toward the normal) and n shape the lobe.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from gonio.brdf.base import BRDF, Param
from gonio.brdf.phong import EXPONENT_MAX, cosine_power
from gonio.errors import ConfigError

__all__ = ["Lafortune", "MAX_LOBES"]

#: Largest number of lobes accepted.
MAX_LOBES = 8
_LOBE_KEYS = ("cx", "cz", "n", "rho")


def _lobe_params(j: int) -> dict[str, Param]:
    return {
        f"lobe{j}.cx": Param("scalar", -1.0, 1.0, -1.0, doc=f"lobe {j}: C_x = C_y (-1: mirror direction)"),
        f"lobe{j}.cz": Param("scalar", -1.0, 1.0, 1.0, doc=f"lobe {j}: C_z"),
        f"lobe{j}.n": Param("scalar", 0.0, EXPONENT_MAX, 20.0, doc=f"lobe {j}: exponent n"),
        f"lobe{j}.rho": Param("rgb", 0.0, np.inf, 1.0, doc=f"lobe {j}: weight rho (1/sr), per RGB channel"),
    }


def _params_for(n_lobes: int) -> dict[str, Param]:
    params = {"kd": Param("rgb", 0.0, 1.0, 0.0, doc="diffuse albedo, per RGB channel")}
    for j in range(1, n_lobes + 1):
        params.update(_lobe_params(j))
    return params


def _count_lobes(params: dict[str, Any], source: str | None) -> int:
    if "lobes" in params:
        lobes = params["lobes"]
        n = lobes if isinstance(lobes, (int, np.integer)) and not isinstance(lobes, bool) else None
        if n is None:
            try:
                n = len(lobes)
            except TypeError:
                raise ConfigError.field(source, "lafortune.lobes", lobes, "must be a count or a list of lobes") from None
    else:
        n = max([int(k[4:].split(".")[0]) for k in params if k.startswith("lobe") and k[4:].split(".")[0].isdigit()],
                default=1)
    if not 1 <= n <= MAX_LOBES:
        raise ConfigError.field(source, "lafortune.lobes", params.get("lobes", n), f"must have 1 to {MAX_LOBES} lobes")
    return n


def _expand_lobes(lobes: Any, source: str | None) -> dict[str, Any]:
    if isinstance(lobes, (int, np.integer)):
        return {}
    flat = {}
    for j, lobe in enumerate(lobes, start=1):
        if isinstance(lobe, dict):
            unknown = sorted(set(lobe) - set(_LOBE_KEYS))
            if unknown:
                raise ConfigError.field(source, f"lafortune.lobes[{j - 1}].{unknown[0]}", lobe[unknown[0]],
                                        f"unknown lobe parameter; a lobe has {', '.join(_LOBE_KEYS)}")
            items = lobe.items()
        else:
            try:
                values = list(lobe)
            except TypeError:
                values = []
            if len(values) != 4:
                raise ConfigError.field(source, f"lafortune.lobes[{j - 1}]", lobe, "must be (cx, cz, n, rho) or a dict")
            items = zip(_LOBE_KEYS, values)
        flat.update({f"lobe{j}.{k}": v for k, v in items})
    return flat


@functools.lru_cache(maxsize=None)
def _lafortune_class(n_lobes: int) -> type:
    return type(f"Lafortune{n_lobes}", (Lafortune,), {
        "PARAMS": _params_for(n_lobes), "n_lobes": n_lobes, "__module__": __name__,
        "__doc__": f"Lafortune model with {n_lobes} lobe(s); see :class:`Lafortune`.",
    })


class Lafortune(BRDF):
    r"""Generalized cosine lobes of E. Lafortune, S. Foo, K. Torrance, D. Greenberg, "Non-Linear
    Approximation of Reflectance Functions", SIGGRAPH 1997, eq. 4 (isotropic: C_x = C_y):

    f(wi, wo) = kd/π + Σ_j ρ_j · max(0, C_x,j (wi_x wo_x + wi_y wo_y) + C_z,j wi_z wo_z)^n_j

    Reciprocal. Not normalized (ρ_j is in 1/sr; a Phong lobe of albedo ks is C = (−1, 1),
    ρ = ks (n + 2)/(2π)), so not marked energy conserving. See the module docstring for the
    parametrization and the ``lobes`` shorthand.
    """

    name = "lafortune"
    PARAMS = _params_for(1)
    n_lobes = 1
    energy_conserving = False

    def __new__(cls, *, _source: str | None = None, **params: Any):
        return object.__new__(_lafortune_class(_count_lobes(params, _source)))

    def __init__(self, *, _source: str | None = None, **params: Any):
        if "lobes" in params:
            lobes = params.pop("lobes")
            params = {**_expand_lobes(lobes, _source), **params}
        super().__init__(_source=_source, **params)

    def _eval(self, wi, wo):
        p = self._params
        xy = wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]
        zz = wi[..., 2] * wo[..., 2]
        total = self.kd / np.pi
        for j in range(1, self.n_lobes + 1):
            base = p[f"lobe{j}.cx"] * xy + p[f"lobe{j}.cz"] * zz
            total = total + p[f"lobe{j}.rho"] * cosine_power(base, p[f"lobe{j}.n"])[..., None]
        return total
