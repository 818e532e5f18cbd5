"""Precomputed-geometry kernels: the colour basis of a model computed from geometry cached on the data.

A kernel returns exactly what :class:`gonio.fit.layout.Basis` would get from ``model.eval`` — the
offset f₀ and the basis functions Bₖ of the colour parameters — but from cosines cached once per
dataset on :class:`gonio.fit.data.FitData`, which makes each shape-parameter evaluation a handful of
array operations. Tests check every kernel against its model's ``eval``.
"""

from __future__ import annotations

from typing import Callable

#: Registry: model name -> kernel(data, fixed, shape) -> (offset or None, [basis per colour parameter]).
KERNELS: dict[str, Callable] = {}


def kernel_for(layout) -> Callable | None:
    """The kernel of ``layout``'s model, if one exists and supports its free/fixed parameters."""
    k = KERNELS.get(layout.name)
    return k if k is not None and getattr(k, "supports", lambda L: True)(layout) else None


def _lambert(data, layout, shape):
    """Lambert: f = albedo/π (:class:`gonio.brdf.lambert.Lambert`); basis 1/π."""
    import numpy as np

    return None, [np.full(len(data), 1.0 / np.pi)]


def _microfacet(data, layout, shape):
    """Walter et al. 2007 microfacet + Lambert (:class:`gonio.brdf.microfacet.Microfacet`): bases
    kd → 1/π, ks → D(h) G2 F(wo·h) / (4 cos θi cos θo), from the shared pieces of
    :mod:`gonio.brdf.microfacet` on the half vectors and cosines cached on the data.

    f0 is fixed (per channel) or tied (one value, a shape parameter). Schlick's
    F = f0 + (1 − f0)(1 − cos θd)⁵ (Schlick 1994, eq. 15) is formed from the cached (1 − cos θd)⁵, and
    D G2/(4 cos θi cos θo) is kept for the last α, so a step in f0 alone costs two array operations.
    """
    import numpy as np

    from gonio.brdf.fresnel import schlick
    from gonio.brdf.microfacet import distribution_d, smith_g2

    fixed = layout.fixed
    name, alpha = fixed["distribution"], shape["alpha"]
    specs = data.__dict__.setdefault("_kernel_cache", {}).setdefault("spec", {})
    key = (name, float(alpha))
    if key not in specs:
        if len(specs) >= 4:  # two lobes of a sum alternate: keep a few
            specs.clear()
        if name == "ggx":
            spec = _ggx_spec(data, alpha)
        else:
            h = data.half
            spec = distribution_d(name, h, alpha) * smith_g2(name, data.wi, data.wo, h, alpha)
            spec /= 4.0 * data.cos_i * data.cos_o
        specs[key] = spec
    spec = specs[key]
    if "f0" in shape:
        f0 = float(shape["f0"])
        if f0 != 1.0:
            spec = spec * (f0 + (1.0 - f0) * _schlick_m5(data))
    else:
        f0 = np.asarray(fixed["f0"])
        if not np.all(f0 == 1.0):  # Schlick F = 1 exactly when f0 = 1
            spec = spec[:, None] * _fresnel_cache(data, f0, schlick)
    basis = {"kd": np.full(len(data), 1.0 / np.pi), "ks": spec}
    offset = None
    for k in ("kd", "ks"):
        if k in fixed and np.any(np.asarray(fixed[k]) != 0):
            b = basis[k] if basis[k].ndim == 2 else basis[k][:, None]
            offset = (0.0 if offset is None else offset) + np.asarray(fixed[k]) * b
    return offset, [basis[k] for k in layout.colour]


def _schlick_m5(data):
    """(1 − cos θd)⁵ of Schlick's approximation, cached per dataset."""
    import numpy as np

    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "m5" not in cache:
        m = 1.0 - np.clip(data.cos_d, 0.0, 1.0)
        m2 = m * m
        cache["m5"] = m2 * m2 * m
    return cache["m5"]


def _geometry(data):
    """Cached per dataset: cos²θh, sin²θh, tan²θi, tan²θo and 1/(4 cos θi cos θo)."""
    cache = data.__dict__.setdefault("_kernel_cache", {})
    if "ggx" not in cache:
        c2h = data.cos_h ** 2
        ci2, co2 = data.cos_i ** 2, data.cos_o ** 2
        cache["ggx"] = (c2h, 1.0 - c2h, (1.0 - ci2) / ci2, (1.0 - co2) / co2, 0.25 / (data.cos_i * data.cos_o))
    return cache["ggx"]


def _ggx_spec(data, alpha):
    """D G2 / (4 cos θi cos θo) of GGX on cached geometry, for directions above the horizon.

    The formulas of :func:`gonio.brdf.microfacet.ggx_d` and :func:`~gonio.brdf.microfacet.smith_g1`
    (Walter et al. 2007, eqs. 33-34) written in θ instead of vector components:
    D = 1/(π α² (sin²θh/α² + cos²θh)²), G1(v) = 2/(1 + √(1 + α² tan²θv)). For reflection above the
    horizon wi·h > 0 always, so the visibility test of smith_g1 never applies. Equality with the
    model is a test (tests/fit/test_fit.py::test_kernels_match_model_eval).
    """
    import numpy as np

    from gonio.brdf.microfacet import clamp_alpha

    c2h, s2h, t2i, t2o, inv4 = _geometry(data)
    a2 = float(clamp_alpha(alpha)) ** 2
    q = s2h / a2
    q += c2h
    q *= q
    spec = inv4 / (np.pi * a2) / q
    gi = t2i * a2
    gi += 1.0
    np.sqrt(gi, out=gi)
    gi += 1.0
    go = t2o * a2
    go += 1.0
    np.sqrt(go, out=go)
    go += 1.0
    gi *= go
    spec *= 4.0
    spec /= gi
    return spec


def _fresnel_cache(data, f0, schlick):
    """Schlick F(wo·h) for fixed f0 depends only on the geometry: computed once per dataset."""
    key = ("fresnel", tuple(f0.tolist()))
    cache = data.__dict__.setdefault("_kernel_cache", {})
    if key not in cache:
        cache[key] = schlick(f0, data.cos_d)
    return cache[key]


_microfacet.supports = lambda L: L.shape in (["alpha"], ["alpha", "f0"]) and ("f0" in L.fixed or "f0" in L.shape)
_lambert.supports = lambda L: L.colour == ["albedo"]
KERNELS.update({"lambert": _lambert, "microfacet": _microfacet})
