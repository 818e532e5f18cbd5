"""gonio._vmath: fdlibm's exp and log in vectorizable arithmetic, within 1 ulp of NumPy's (glibc's) over every
range the BRDF formulas reach and beyond, with NumPy's special values; power() compiled is NumPy's power()."""

from __future__ import annotations

import numpy as np
import pytest

numba = pytest.importorskip("numba")  # the fast extra: installed by the README's test command

from gonio._jit import power  # noqa: E402
from gonio._vmath import vexp, vlog  # noqa: E402
from gonio.brdf.compiled import _register  # noqa: E402

_register()  # power() -> vpower in compiled code


@numba.njit(error_model="numpy")
def _exp_all(x, out):
    for i in range(x.size):
        out[i] = vexp(x[i])


@numba.njit(error_model="numpy")
def _log_all(x, out):
    for i in range(x.size):
        out[i] = vlog(x[i])


@numba.njit(error_model="numpy")
def _power_all(b, e, out):
    for i in range(b.size):
        out[i] = power(b[i], e[i])


def _ulps(a, b):
    """Units in the last place between finite doubles of one sign."""
    return np.abs(a.view(np.int64) - b.view(np.int64))


def _run(fn, x):
    out = np.empty_like(x)
    fn(x, out)
    return out


def test_exp_is_within_one_ulp_everywhere_and_keeps_the_special_values():
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.uniform(-760, 720, 400_000), rng.uniform(-1, 1, 100_000), rng.uniform(-1e-8, 1e-8, 10_000),
                        rng.uniform(-745.2, -708, 100_000),  # subnormal results
                        [0.0, -0.0, 1.0, -1.0, 709.782712893384, 709.79, -745.1332191019411, -745.14, 1e-300, -1e-300,
                         np.inf, -np.inf, np.nan, 1e308, -1e308]])
    got = _run(_exp_all, x)
    with np.errstate(over="ignore"):
        want = np.exp(x)
    fin = np.isfinite(want) & (want > 0)
    assert _ulps(got[fin], want[fin]).max() <= 1
    assert np.array_equal(got[~fin], want[~fin], equal_nan=True)  # 0 below the underflow, inf above, NaN


def test_log_is_within_one_ulp_everywhere_and_keeps_the_special_values():
    rng = np.random.default_rng(2)
    x = np.concatenate([np.exp(rng.uniform(-708, 709.7, 400_000)), rng.uniform(0.5, 2.0, 100_000),
                        1.0 + rng.uniform(-1e-10, 1e-10, 10_000), rng.uniform(0, 2.2e-308, 10_000),  # subnormal
                        [5e-324, 2.2250738585072014e-308, 1.0, 2.0, 0.5, np.sqrt(2.0), np.nextafter(np.sqrt(2.0), 0),
                         np.finfo(float).max, 0.0, -0.0, np.inf, -1.0, -np.inf, np.nan]])
    got = _run(_log_all, x)
    with np.errstate(divide="ignore", invalid="ignore"):
        want = np.log(x)
    fin = np.isfinite(want)
    pos, neg = fin & (want >= 0), fin & (want < 0)
    assert _ulps(got[pos], want[pos]).max() <= 1 and _ulps(got[neg], want[neg]).max() <= 1
    assert np.array_equal(got[~fin], want[~fin], equal_nan=True)


def test_compiled_power_agrees_with_numpy_power_over_the_formulas_ranges():
    """The bases and exponents of gtr (base ≥ α² ≥ 1e-8, exponent −γ ∈ [−10, −0.5]), ABC (base 1 + B x ≤ 1 + 4e8,
    exponent −C ∈ [−50, −1e-3]) and Ashikhmin–Shirley (base n·h ∈ [tiny, 1], exponent up to 1e6): each of the two
    is within (|exponent · log(base)| + 2) ε of the exact power (log's error times the exponent, then exp's and the
    product's roundings), so they differ by at most twice that."""
    rng = np.random.default_rng(3)
    n = 200_000
    b = np.concatenate([10 ** rng.uniform(-8, 0, n), 1 + 10 ** rng.uniform(-12, 8.6, n),
                        10 ** rng.uniform(-307, 0, n)])
    e = np.concatenate([-rng.uniform(0.5, 10, n), -10 ** rng.uniform(-3, np.log10(50), n), 10 ** rng.uniform(-6, 6, n)])
    got = np.empty_like(b)
    _power_all(b, e, got)
    want = power(b, e)
    nz = want > 1e-300
    bound = 2.0 * (np.abs(e * np.log(b)) + 2.0) * np.finfo(float).eps
    assert np.all(np.abs(got[nz] - want[nz]) <= bound[nz] * want[nz])
    assert np.all(got[~nz] <= 1e-290)  # where NumPy underflows, so does the compiled power
