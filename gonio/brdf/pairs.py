"""Geometry of a direction pair, computed once and shared by the lobes of a model (the NumPy path).

Models built from microfacet-type lobes (``microfacet``, ``cook-torrance``, ``gtr``, ``abc`` and sums of
them with ``lambert``) describe themselves as ``const + Σ lobes`` (:meth:`gonio.brdf.base.BRDF._lobes`):

    f_c(wi, wo) = const_c + Σ_l w_lc · s_l(P) · F_lc,     F_lc = f0_lc + (1 − f0_lc)(1 − cos θd)⁵

where P = :func:`pair_geometry` (half vector, cosines, tan², 1 − cos θd: what every lobe needs, computed
once per pair however many lobes there are), s_l a lobe's *spec function* (e.g.
:func:`gonio.brdf.microfacet.ggx_spec`: D G / (4 cos θi cos θo)), w_lc its colour weight and F_lc
Schlick's Fresnel factor (Schlick 1994, eq. 15; omitted when the lobe has no f0).

:func:`evaluate` is the NumPy reference; :mod:`gonio.brdf.compiled` runs the *same* functions (they are
:func:`gonio._jit.jitable`) per pair in a numba-compiled loop.
"""

from __future__ import annotations

from collections import namedtuple
from typing import Callable, NamedTuple

import numpy as np

from gonio._jit import jitable, power, select
from gonio.brdf.fresnel import one_minus_cos_d_xyz, schlick_m
from gonio.geometry import half_vector_xyz

__all__ = ["Pair", "Lobe", "pair_geometry", "cos_d", "split_value", "evaluate"]

#: Per-pair quantities shared by the lobes (arrays on the NumPy path, scalars in a compiled loop):
#: ``iz, oz`` cos θi, cos θo; ``hx, hy, hz`` the half vector (cos θh = hz); ``s2h`` = h_x² + h_y² (sin²θh);
#: ``hz2, iz2, oz2`` cos²θh, cos²θi, cos²θo; ``ih, oh`` wi·h, wo·h; ``vis`` 1.0 where h is above the surface and
#: wi, wo on the visible side of the microfacet ((v·h) v_z > 0, the condition of the Smith G1), else 0.0 (a
#: float, not a bool: every field of one type keeps the compiled loop vectorized);
#: ``si2, so2`` sin²θi, sin²θo (x² + y²); ``si, so`` sin θi, sin θo; ``th2`` tan²θh (a guarded
#: division); ``cc`` = max(cos θi cos θo, tiny); ``m`` = 1 − cos θd without cancellation; ``tiny`` the
#: dtype's smallest normal number.
Pair = namedtuple("Pair", "iz oz hx hy hz s2h hz2 iz2 oz2 ih oh vis si2 so2 si so th2 cc m tiny")


class Lobe(NamedTuple):
    """One term ``w_c · spec(P, *params) · F_c`` of a model (see the module docstring)."""

    spec: Callable
    params: tuple
    weight: np.ndarray
    f0: np.ndarray | None = None


@jitable
def pair_geometry(ix, iy, iz, ox, oy, oz, tiny):
    """:data:`Pair` of the directions wi = (ix, iy, iz), wo = (ox, oy, oz) (arrays or scalars).

    h = normalize(wi + wo) (:func:`gonio.geometry.half_vector_xyz`), sin θ = √(x² + y²),
    tan²θh = (h_x² + h_y²) / max(h_z², tiny), 1 − cos θd from :func:`gonio.brdf.fresnel.one_minus_cos_d_xyz`.
    On a compiled path the fields a lobe does not use are never computed; on the NumPy path what does not
    depend on a lobe's parameters (squares, the visibility test) is computed once, for every lobe (and for
    every parameter value a fit tries, :mod:`gonio.fit.kernels`).
    """
    hx, hy, hz = half_vector_xyz(ix, iy, iz, ox, oy, oz, tiny)
    si2 = ix * ix + iy * iy
    so2 = ox * ox + oy * oy
    s2h = hx * hx + hy * hy
    hz2 = hz * hz
    ih = ix * hx + iy * hy + iz * hz
    oh = ox * hx + oy * hy + oz * hz
    return Pair(
        iz, oz, hx, hy, hz, s2h, hz2, iz * iz, oz * oz, ih, oh,
        select((hz > 0.0) & (ih * iz > 0.0) & (oh * oz > 0.0), 1.0, 0.0),
        si2, so2, np.sqrt(si2), np.sqrt(so2),
        s2h / np.maximum(hz2, tiny),
        np.maximum(iz * oz, tiny),
        one_minus_cos_d_xyz(ix, iy, iz, ox, oy, oz, hx, hy, hz),
        tiny,
    )


@jitable
def cos_d(p):
    """cos θd = wi·h = wo·h of the pair geometry ``p``, as the mean of the two: equal in exact arithmetic, but
    each rounds differently, and the mean is exactly symmetric in (wi, wo) (a + b = b + a in IEEE 754), so a
    formula of cos θd gives the same bits with wi and wo swapped (reciprocity to the last bit, as
    :func:`gonio.brdf.fresnel.one_minus_cos_d_xyz`); with wi·h alone, a Fresnel term of η = 1 (exactly 0) gave
    4.6e-30 one way and 0 the other."""
    return 0.5 * (p.ih + p.oh)


@jitable
def split_value(base, exponent, factor):
    """A lobe given in split form ``(base, exponent, factor)``: base^exponent (:func:`gonio._jit.power`) · factor.
    The spec functions whose one transcendental is such a power are written as this of their split form; the
    compiled loop calls the split form and does this product itself (``SPLIT`` in :mod:`gonio.brdf.compiled`)."""
    return power(base, exponent) * factor


#: Pairs per block of :func:`evaluate`: the temporaries of a block stay in the CPU cache.
BLOCK = 8192


def evaluate(const, lobes, wi, wo) -> np.ndarray:
    """``const + Σ lobes`` at the pairs ``(wi, wo)`` (broadcast arrays ``(..., 3)``): shape ``(..., 3)``.

    The geometry is computed once (:func:`pair_geometry`) and shared by every lobe; per-pair work is done
    on per-pair arrays, only the colour combination on ``(..., 3)``; large inputs go in blocks of
    :data:`BLOCK` pairs (element-wise, so the values do not depend on the blocking).
    """
    shape = wi.shape[:-1] + (3,)
    if not lobes:
        return np.broadcast_to(const, shape)
    n = wi.size // 3
    if n <= BLOCK:
        return np.broadcast_to(_evaluate(const, lobes, wi, wo), shape)
    a, b = wi.reshape(-1, 3), wo.reshape(-1, 3)
    out = np.empty((n, 3), dtype=np.result_type(wi.dtype, _evaluate(const, lobes, a[:1], b[:1]).dtype))
    for start in range(0, n, BLOCK):
        out[start:start + BLOCK] = _evaluate(const, lobes, a[start:start + BLOCK], b[start:start + BLOCK])
    return out.reshape(shape)


def _evaluate(const, lobes, wi, wo):
    p = pair_geometry(wi[..., 0], wi[..., 1], wi[..., 2], wo[..., 0], wo[..., 1], wo[..., 2],
                      np.finfo(wi.dtype).tiny)
    total = const
    m = None
    for lobe in lobes:
        s = lobe.spec(p, *lobe.params)[..., None]
        if lobe.f0 is not None:
            if m is None:
                m = p.m[..., None]
            s = s * schlick_m(lobe.f0, m)
        total = total + lobe.weight * s
    return total
