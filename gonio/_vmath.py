"""``exp`` and ``log`` for compiled loops, in arithmetic LLVM can vectorize (numba only; imported by
:func:`gonio.brdf.compiled._register`).

A numba loop that calls ``np.exp`` or ``np.log`` calls libm's scalar functions, and one such call keeps the
whole loop scalar (pip's llvmlite has no vector math library). These are the algorithms of fdlibm (Sun
Microsystems 1993, the C library behind Java's ``StrictMath``), ``e_log.c`` and ``e_exp.c``, written without
branches: the argument's exponent and mantissa through bit casts, the reduced argument's polynomial, the result
scaled by 2ᵏ through the exponent bits. Both are within 1 ulp of the correctly rounded value, as fdlibm's are
(tests/brdf/test_vmath.py checks them against NumPy's over the ranges the BRDF formulas use).

Special values as NumPy's: :func:`vlog` of a subnormal (scaled by 2⁵⁴ first), 0 (−inf), +inf (+inf), a negative
number or NaN (NaN); :func:`vexp`: 0 below −745.13 (underflow; subnormal results above it, by a two-step scaling
that rounds once), +inf above 709.78, NaN for NaN.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic, register_jitable

__all__ = ["vexp", "vlog", "vpower"]


@intrinsic
def _bits(typingctx, x):
    """The IEEE 754 bits of a float64 as an int64 (LLVM ``bitcast``: no instruction)."""
    if x != types.float64:
        return None

    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


@intrinsic
def _float(typingctx, x):
    """The float64 whose IEEE 754 bits are the int64 ``x``."""
    if x != types.int64:
        return None

    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


# fdlibm e_log.c: ln 2 split in a high part with trailing zero bits and the rest; the minimax polynomial of
# R(z) ≈ (log(1 + f) − 2s)/s − ... in z = s², s = f / (2 + f) (its "Lg1 … Lg7")
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
_LG1 = 6.666666666666735130e-01
_LG2 = 3.999999999940941908e-01
_LG3 = 2.857142874366239149e-01
_LG4 = 2.222219843214978396e-01
_LG5 = 1.818357216161805012e-01
_LG6 = 1.531383769920937332e-01
_LG7 = 1.479819860511658591e-01
_SQRT2 = 1.4142135623730951
_TINY = 2.2250738585072014e-308  # the smallest normal float64
_TWO54 = 18014398509481984.0  # 2⁵⁴
#: 1.5 · 2⁵² and its bits: for an integer-valued float |k| < 2³¹, k + SHIFTER has k in its low mantissa bits, and
#: the float of the bits BITS + k is SHIFTER + k — integer ↔ float without conversion instructions, which AVX2
#: lacks for 64-bit integers (a conversion would keep the loop scalar)
_SHIFTER = 6755399441055744.0
_SHIFTER_BITS = 0x4338000000000000

# fdlibm e_exp.c: the thresholds, 1/ln 2 and the polynomial "P1 … P5" of the rational approximation of exp(r)
_EXP_MAX = 7.09782712893383973096e+02
_EXP_MIN = -7.45133219101941108420e+02
_INV_LN2 = 1.44269504088896338700e+00
_P1 = 1.66666666666666019037e-01
_P2 = -2.77777777770155933842e-03
_P3 = 6.61375632143793436117e-05
_P4 = -1.65339022054652515390e-06
_P5 = 4.13813679705723846039e-08


@register_jitable(error_model="numpy")
def vlog(x):
    """log(x) of a float64 (fdlibm ``__ieee754_log``, branch-free): x = 2ᵏ m with
    m ∈ [√2/2, √2), f = m − 1, s = f/(2 + f), log(1 + f) = f − (hfsq − s (hfsq + R(s²))) with hfsq = f²/2, and
    log x = k ln2_hi − ((hfsq − (s (hfsq + R) + k ln2_lo)) − f)."""
    sub = x < _TINY  # subnormal (or zero, negative, NaN: fixed at the end): scaled into the normal range first
    xs = x * _TWO54 if sub else x
    b = _bits(xs)
    k = ((b >> 52) & 0x7FF) - (1023 + 54 if sub else 1023)
    m = _float((b & 0x000FFFFFFFFFFFFF) | 0x3FF0000000000000)  # in [1, 2)
    big = m > _SQRT2
    m = m * 0.5 if big else m
    k = k + 1 if big else k
    f = m - 1.0
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (_LG2 + w * (_LG4 + w * _LG6))
    t2 = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7)))
    r = t2 + t1
    hfsq = 0.5 * f * f
    dk = _float(_SHIFTER_BITS + k) - _SHIFTER
    y = dk * _LN2_HI - ((hfsq - (s * (hfsq + r) + dk * _LN2_LO)) - f)
    y = np.inf if x == np.inf else y
    y = -np.inf if x == 0.0 else y
    return np.nan if not x >= 0.0 else y  # negative or NaN


@register_jitable(error_model="numpy")
def vexp(x):
    """exp(x) (fdlibm ``__ieee754_exp``, branch-free): k = round(x / ln 2), r = (x − k ln2_hi) − k ln2_lo,
    exp(r) = 1 − ((lo − r c / (2 − c)) − hi) with c = r − r² P(r²), times 2ᵏ in two exact steps (2^⌊k/2⌋ then
    2^(k − ⌊k/2⌋): one rounding where the result is subnormal)."""
    xc = min(max(x, _EXP_MIN - 1.0), _EXP_MAX + 1.0)  # keeps k in range; the selects below decide the ends
    dk = np.floor(xc * _INV_LN2 + 0.5)
    k = _bits(dk + _SHIFTER) - _SHIFTER_BITS
    hi = xc - dk * _LN2_HI
    lo = dk * _LN2_LO
    r = hi - lo
    t = r * r
    c = r - t * (_P1 + t * (_P2 + t * (_P3 + t * (_P4 + t * _P5))))
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    k1 = k >> 1
    y = y * _float((k1 + 1023) << 52) * _float((k - k1 + 1023) << 52)
    y = 0.0 if x < _EXP_MIN else y
    y = np.inf if x > _EXP_MAX else y
    return x if x != x else y  # NaN stays NaN


@register_jitable(error_model="numpy", inline="always")
def vpower(base, exponent):
    """base^exponent = exp(exponent · log(base)) (:func:`vexp`, :func:`vlog`), as :func:`gonio._jit.power` computes
    it on NumPy arrays."""
    return vexp(exponent * vlog(base))
