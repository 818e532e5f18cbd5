"""Formulas written once for NumPy arrays *and* for a compiled loop (docs/architecture.md §6).

A function marked :func:`jitable` is plain Python over arrays-or-scalars: NumPy evaluates it on whole
arrays (the reference path), and :mod:`gonio.brdf.compiled` hands the very same function to numba
(``numba.extending.register_jitable``), which compiles it for one sample inside a loop. So a formula
has one hand-kept copy; the compiled path is generated from it.

Rules for a jitable function: arithmetic, ``np.sqrt/exp/log/log1p/expm1/maximum/minimum``, :func:`select` and
:func:`power` (for ``exp(e · log(b))``: compiled, it is :func:`gonio._vmath.vpower`, which LLVM vectorizes, where
``np.exp`` and ``np.log`` are libm calls that keep the whole loop scalar) (never ``np.where``, ``np.clip`` or axis reductions, which mean something else on a
scalar); it may call other jitable functions; anything dtype-dependent (the ``tiny`` guards) comes in
as an argument, so float32 arrays stay float32. Tuples a jitable function returns hold one type (floats: a
condition is stored as 1.0/0.0, as :data:`gonio.brdf.pairs.Pair`'s ``vis``): a bool among floats makes numba
build a mixed structure that keeps the compiled loop from being vectorized (3–7× slower).
"""

from __future__ import annotations

import numpy as np

__all__ = ["jitable", "select", "power", "JITABLE"]

#: Every function marked :func:`jitable`, in definition order (registered with numba on first use).
JITABLE: list = []


def jitable(fn):
    """Mark ``fn`` as usable both on NumPy arrays and inside a numba-compiled loop (returns ``fn``)."""
    JITABLE.append(fn)
    return fn


def select(cond, a, b):
    """``a`` where ``cond`` else ``b``: ``np.where`` on arrays; ``a if cond else b`` when compiled."""
    return np.where(cond, a, b)


def power(base, exponent):
    """``base ** exponent`` as exp(exponent · log(base)) for ``base`` > 0 (arrays or scalars): a large exponent
    of a small base underflows to 0 instead of overflowing an intermediate. On NumPy arrays ``np.exp`` and
    ``np.log``; compiled, :func:`gonio._vmath.vpower` (fdlibm's algorithms, within 1 ulp of these, in
    arithmetic LLVM vectorizes: a libm call would keep the whole loop scalar)."""
    return np.exp(exponent * np.log(base))
