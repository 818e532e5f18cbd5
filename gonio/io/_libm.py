"""The C library's ``cos``, ``sin``, ``acos`` and ``atan2`` over float64 arrays in a compiled loop (numba), for
:mod:`gonio.io.merl_index`'s exact pass: the functions the MERL reference reader calls.

numba lowers ``math.cos`` & co. in a scalar loop to calls of the C library's functions — the ones Python's
:mod:`math` wraps, one Python call per value (~0.7 µs) where the loop takes ~25 ns — with C's semantics where
:mod:`math` raises (``acos(1 + ε)``, ``cos(inf)``: NaN). Two things could make it differ: Intel's SVML (numba
vectorizes such loops with it when ``icc_rt`` is installed, and its results may differ in the last bit), and a
platform whose numba links another library; :func:`exact` checks both (``numba.config.USING_SVML``, and every
function against :mod:`math` on :data:`CHECK` values: ordinary, tiny, huge, signed zeros, ±1 ± ε, inf and NaN)
before :mod:`gonio.io.merl_index` uses the loop.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["FUNCTIONS", "exact"]


#: The functions' codes in :func:`_apply`.
CODES = {"cos": 0, "sin": 1, "acos": 2, "atan2": 3}


@numba.njit(cache=True)
def _apply(code, y, x):
    """``f(y[i])`` (``atan2``: ``f(y[i], x[i])``) for the function ``code`` names, into a new array (one compiled
    function for the four: the process loads one loop from numba's cache, not four)."""
    out = np.empty_like(y)
    for i in range(y.size):
        if code == 0:
            out[i] = math.cos(y[i])
        elif code == 1:
            out[i] = math.sin(y[i])
        elif code == 2:
            out[i] = math.acos(y[i])
        else:
            out[i] = math.atan2(y[i], x[i])
    return out


def _loop(name):
    code = CODES[name]

    def run(y, x=None):
        return _apply(code, y, y if x is None else x)

    run.__name__ = name
    return run


#: The loops by name (1-D contiguous float64 arrays in, a new array out).
FUNCTIONS = {name: _loop(name) for name in CODES}

#: Values :func:`exact` compares the loops on (with :mod:`math`, NaN where it raises).
CHECK = np.array([0.0, -0.0, 1.0, -1.0, 1.0 + 2.0**-52, -1.0 - 2.0**-52, 1.0 - 2.0**-53, 0.5, -0.5, 1e-300, -1e-310,
                  5e-324, 1e-8, 0.7853981633974483, 1.5707963267948966, 3.141592653589793, -3.141592653589793,
                  2.0, 10.0, 1e6, 1e22, 1e300, math.inf, -math.inf, math.nan, 0.1, 0.3, 0.9999999999999999,
                  -0.9999999999999999, 2.356194490192345, 1e-16, 123.456])


def _math(f, *args) -> float:
    try:
        return f(*args)
    except ValueError:
        return math.nan


def exact() -> bool:
    """The loops give :mod:`math`'s results bit for bit (NaN where it raises) on :data:`CHECK` (each value and,
    for ``atan2``, each pair), and numba does not vectorize them with SVML."""
    if getattr(numba.config, "USING_SVML", False):
        return False
    x = CHECK
    y, z = np.repeat(x, x.size), np.tile(x, x.size)
    pairs = (("cos", math.cos, (x,)), ("sin", math.sin, (x,)), ("acos", math.acos, (x,)),
             ("atan2", math.atan2, (y, z)))
    for name, f, args in pairs:
        got = FUNCTIONS[name](*args)
        want = np.array([_math(f, *a) for a in zip(*args)], dtype=np.float64)
        same = (got.view(np.int64) == want.view(np.int64)) | (np.isnan(got) & np.isnan(want))
        if not same.all():
            return False
    return True
