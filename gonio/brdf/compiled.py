"""The compiled BRDF path: the lobe formulas of :mod:`gonio.brdf.pairs` run per pair in a numba loop.

Optional (``pip install 'gonio[fast]'``); :mod:`gonio.brdf.pairs` (NumPy) stays the reference, and the
two agree to ≤ 1e-12 relative (tests/brdf/test_compiled.py). Nothing here is a formula: the loop calls
the :func:`gonio._jit.jitable` functions the NumPy path calls — :func:`gonio.brdf.pairs.pair_geometry`,
the lobes' spec functions (:data:`SPECS`) and :func:`gonio.brdf.fresnel.schlick_m` — which numba compiles
from their Python source (``register_jitable``). Why a compiled loop: a NumPy expression makes one pass
over memory per operation (≈ 60 for a GGX lobe, most of them on 10⁶-element temporaries), a loop makes one
pass for the whole model and keeps every intermediate in registers, and the lobes of a sum share the
geometry of each pair (python -m benchmarks brdf).

A model has a compiled form when it is written as lobes (:meth:`gonio.brdf.base.BRDF._lobes`) whose spec
functions are all in :data:`SPECS`: ``microfacet`` (GGX, Beckmann), ``cook-torrance``, ``gtr``, ``abc``,
``lambert`` and sums of them. The kernel is compiled once per process on first use (numba's cache on disk
is not used: it does not notice a change in a called function's source).
"""

from __future__ import annotations

import functools
import importlib.util
import os

import numpy as np

from gonio.brdf.abc import abc_spec
from gonio.brdf.cook_torrance import cook_torrance_spec
from gonio.brdf.fresnel import schlick_m
from gonio.brdf.gtr import gtr_spec
from gonio.brdf.microfacet import beckmann_spec, ggx_spec
from gonio.brdf.pairs import pair_geometry

__all__ = ["MIN_PAIRS", "SPECS", "available", "supports", "wanted", "evaluate"]

#: Spec functions the kernel dispatches on, by index (the kernel's if-chain follows this order).
SPECS = (ggx_spec, beckmann_spec, cook_torrance_spec, gtr_spec, abc_spec)
#: Most shape parameters of a spec function.
MAX_PARAMS = 3
#: ``backend="auto"`` uses the compiled loop from this many pairs on (below, the call overhead of
#: either path dominates and NumPy avoids importing numba).
MIN_PAIRS = 512
_TINY = float(np.finfo(np.float64).tiny)


@functools.lru_cache(maxsize=None)
def available() -> bool:
    """numba is installed (the ``fast`` extra)."""
    return importlib.util.find_spec("numba") is not None


def _pack(model):
    """Arrays the kernel takes for ``model`` (cached on the immutable model), or None without a compiled form."""
    cached = model.__dict__.get("_compiled_pack", False)
    if cached is not False:
        return cached
    pack = None
    desc = model._lobes()
    if desc is not None and all(lobe.spec in SPECS for lobe in desc[1]):
        const, lobes = desc
        n = len(lobes)
        kinds = tuple(SPECS.index(lobe.spec) for lobe in lobes)
        params = np.zeros((n, MAX_PARAMS))
        w, f0 = np.zeros((n, 3)), np.ones((n, 3))
        for j, lobe in enumerate(lobes):
            params[j, :len(lobe.params)] = lobe.params
            w[j] = lobe.weight
            if lobe.f0 is not None:
                f0[j] = lobe.f0
        pack = (kinds, params, w, f0, np.broadcast_to(np.asarray(const, dtype=np.float64), (3,)).copy())
    object.__setattr__(model, "_compiled_pack", pack)
    return pack


def supports(model) -> bool:
    """``model`` has a compiled form (whether or not numba is installed)."""
    return _pack(model) is not None


def wanted(model, wi, dtype, backend: str) -> bool:
    """Whether :meth:`~gonio.brdf.base.BRDF.eval` with ``backend`` should use the compiled loop."""
    if backend == "compiled":
        if dtype != np.float64:
            raise ValueError("the compiled BRDF path is float64 only")
        if not available():
            raise ValueError("the compiled BRDF path needs numba: pip install 'gonio[fast]'")
        if not supports(model):
            raise ValueError(f"model {model.name!r} has no compiled form")
        return True
    if dtype != np.float64 or wi.size < 3 * MIN_PAIRS or os.environ.get("GONIO_BRDF_BACKEND", "auto") == "numpy":
        return False
    return available() and supports(model)


def evaluate(model, wi, wo) -> np.ndarray:
    """f(wi, wo) of ``model`` by the compiled loop; ``wi``, ``wo`` float64 arrays of one shape ``(..., 3)``."""
    shape = wi.shape[:-1]
    a = np.ascontiguousarray(wi.reshape(-1, 3))
    b = np.ascontiguousarray(wo.reshape(-1, 3))
    out = np.empty((a.shape[0], 3))
    kinds, *arrays = _pack(model)
    _kernel(kinds)(a, b, *arrays, out)
    return out.reshape(shape + (3,))


@functools.lru_cache(maxsize=None)
def _register():
    """Register the jitable functions (and the scalar :func:`gonio._jit.select`) with numba, once."""
    import numba
    from numba.extending import overload, register_jitable

    from gonio import _jit

    @overload(_jit.select)
    def _select(cond, a, b):
        if isinstance(cond, numba.types.Boolean):
            return lambda cond, a, b: a if cond else b
        return None

    for fn in _jit.JITABLE:
        register_jitable(fn)
    return numba


_LOOP = """
def loop(wi, wo, params, w, f0, const, out):
    for i in range(wi.shape[0]):
        ix, iy, iz = wi[i, 0], wi[i, 1], wi[i, 2]
        ox, oy, oz = wo[i, 0], wo[i, 1], wo[i, 2]
        if not (iz > 0.0 and oz > 0.0):
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            out[i, 2] = 0.0
            continue
        p = pair_geometry(ix, iy, iz, ox, oy, oz, TINY)
        r0, r1, r2 = const[0], const[1], const[2]
{lobes}
        out[i, 0] = r0
        out[i, 1] = r1
        out[i, 2] = r2
"""
_LOBE = """
        s = {spec}(p, {params})
        r0 += w[{j}, 0] * (s * schlick_m(f0[{j}, 0], p.m))
        r1 += w[{j}, 1] * (s * schlick_m(f0[{j}, 1], p.m))
        r2 += w[{j}, 2] * (s * schlick_m(f0[{j}, 2], p.m))"""


@functools.lru_cache(maxsize=None)
def _kernel(kinds: tuple):
    """The loop for lobes of spec functions ``SPECS[k] for k in kinds``, compiled on first use (per process).

    Generated from :data:`_LOOP`: one block per lobe, so each sum's loop is straight-line code (no dispatch
    per pair). Schlick's factor is applied to every lobe (f0 = 1 for lobes without one gives F = 1 exactly).
    """
    numba = _register()
    names = {f"spec{k}": SPECS[k] for k in set(kinds)}
    blocks = []
    for j, k in enumerate(kinds):
        nparam = SPECS[k].__code__.co_argcount - 1
        args = ", ".join(f"params[{j}, {q}]" for q in range(nparam))
        blocks.append(_LOBE.format(spec=f"spec{k}", params=args, j=j))
    namespace = {"pair_geometry": pair_geometry, "schlick_m": schlick_m, "TINY": _TINY, **names}
    exec(_LOOP.format(lobes="".join(blocks)), namespace)
    return numba.njit(nogil=True)(namespace["loop"])
