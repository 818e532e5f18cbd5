"""The simulated sensor's per-pixel chain: electron rates → mean electrons → shot and read noise → full well →
digital numbers.

:class:`sim.camera.SimCamera` hands a frame's electron rates to :func:`expose_compiled` (numba: two passes over
memory instead of ~20 whole-array operations; used when numba, the ``fast`` extra, is installed) or to its
reference :func:`expose_numpy` (whole-array NumPy operations). Both draw the frame's random numbers with NumPy in
one fixed order (:func:`draw`: the normal table's indices, then one uniform per Poisson value) and then do the same
IEEE operations in the same order and precision on them, so they give the same frame bit for bit
(tests/pipeline/test_fast_paths_exact.py), and a seed gives the same samples with or without numba.

Noise model (EMVA Standard 1288 R4.0, 2021, §2: shot noise Poisson in the electrons, read noise Gaussian):

* a pixel whose mean μ is at least ``below`` electrons: ``μ + √(μ + σ_r²) z`` with one standard normal
  ``z`` (the normal approximation N(μ, μ) of the Poisson law plus the read noise in one draw);
* below it: ``k + σ_r z`` with ``k`` Poisson(μ) drawn exactly by inversion, the sequential search of
  Devroye, *Non-Uniform Random Variate Generation*, 1986, §X.3.3: with one uniform ``u``, the smallest
  ``k`` with ``u ≤ Σ_{j≤k} e^{−μ} μʲ/j!``, the terms by the recurrence ``p_j = p_{j−1} · (μ · (1/j))`` (one
  multiplication on the chain of dependent operations instead of a division: a step is ~4 cycles). The search
  stops when a term no longer changes the float64 partial sum (the tail beyond it is below 2⁻⁵³ of the sum),
  so the law is exact up to the rounding of the partial sums; it costs ~μ + 1 steps, cheap where it is used
  (μ < 30, most pixels μ < 5).

``z`` comes from :func:`sim.camera.normal_table` indexed by 16-bit uniform integers (inverse transform
sampling, Devroye §II.2). Then the full well clips the electrons, the system gain and the black level turn
them into DN, rounded half to even and clipped to the sensor's range.
"""

from __future__ import annotations

import functools
import importlib.util

import numpy as np

__all__ = ["draw", "frame_numpy", "means_numpy", "expose_numpy", "expose_compiled", "compiled_available"]

#: 2²³ in float32: float32 numbers at or above it are integers, and ``(x + 2²³) − 2²³`` rounds 0 ≤ x < 2²³ to an
#: integer, half to even (IEEE 754 round-to-nearest on the sum; Goldberg, "What every computer scientist should
#: know about floating-point arithmetic", 1991, §"Exactly rounded operations")
TWO23 = np.float32(1 << 23)


def draw(rng: np.random.Generator, normal_indices, mean_e: np.ndarray, below: float):
    """The random numbers of one frame, in a fixed order: the normal table's indices (``normal_indices(shape)``,
    one per value) first, then one uniform on [0, 1) per value whose mean is below ``below`` electrons (C order).

    Returns ``(idx, low, lam, p0, u)``: ``low`` the boolean mask of those values, ``lam`` their means
    (float64, floored at 0), ``p0 = exp(−lam)`` (the Poisson law's P(0), computed here by NumPy for both
    implementations) and ``u`` their uniforms."""
    idx = normal_indices(mean_e.shape)
    low = mean_e < below
    lam = mean_e[low].astype(np.float64)
    np.maximum(lam, 0.0, out=lam)
    p0 = np.exp(-lam)
    u = rng.random(lam.size)
    return idx, low, lam, p0, u


def poisson_inversion(lam: np.ndarray, p0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Poisson(``lam``) by sequential-search inversion of the uniforms ``u`` (see the module docstring;
    Devroye 1986 §X.3.3), vectorized: each step advances the values whose search has not ended."""
    k = np.zeros(lam.size, dtype=np.int64)
    p, cdf = p0.copy(), p0.copy()
    act = np.flatnonzero(u > cdf)
    j = 0
    while act.size:
        j += 1
        k[act] = j
        pa = p[act] * (lam[act] * (1.0 / j))
        ca = cdf[act]
        cn = ca + pa
        p[act], cdf[act] = pa, cn
        act = act[(cn != ca) & (u[act] > cn)]
    return k


def electrons_numpy(mean_e, table, idx, low, lam, p0, u, *, read_noise) -> np.ndarray:
    """Electrons after shot and read noise (float32; module docstring), from the frame's means and random numbers."""
    z = np.take(table, idx)
    e = mean_e + np.float32(read_noise ** 2)
    np.sqrt(e, out=e)
    e *= z
    e += mean_e
    if lam.size:
        z_low = z[low]
        z_low *= np.float32(read_noise)
        e[low] = poisson_inversion(lam, p0, u) + z_low  # int64 + float32: float64, then stored as float32
    return e


def frame_numpy(mean_e, table, idx, low, lam, p0, u, *, read_noise, full_well, gain_k, black, saturation,
                dtype=np.uint16) -> np.ndarray:
    """The frame's values with whole-array NumPy operations (the reference): :func:`electrons_numpy`, clipped
    at ``full_well``, times ``gain_k`` (DN per electron) plus ``black``, rounded half to even and clipped to
    [0, ``saturation``]."""
    e = electrons_numpy(mean_e, table, idx, low, lam, p0, u, read_noise=read_noise)
    np.minimum(e, np.float32(full_well), out=e)
    e *= np.float32(gain_k)
    e += np.float32(black)
    np.rint(e, out=e)
    np.clip(e, 0, saturation, out=e)
    return e.astype(dtype)


@functools.lru_cache(maxsize=1)
def compiled_available() -> bool:
    """numba is installed (the ``fast`` extra)."""
    return importlib.util.find_spec("numba") is not None


def means_numpy(rate, scale, pattern, dark_e) -> np.ndarray:
    """Mean electrons of a frame: ``rate · scale + pattern · dark_e`` (``+ dark_e`` without a dark pattern),
    float32 (the reference; :func:`expose_compiled` computes the same in its first pass)."""
    mean_e = np.multiply(rate, np.float32(scale))
    if pattern is None:
        mean_e += np.float32(dark_e)
    else:
        mean_e += np.multiply(pattern, np.float32(dark_e))
    return mean_e


def expose_numpy(rate, scale, pattern, dark_e, rng, normal_indices, table, below, **kw) -> np.ndarray:
    """A frame from its electron rates (:func:`means_numpy`, :func:`draw`, :func:`frame_numpy`): the reference
    of :func:`expose_compiled`."""
    mean_e = means_numpy(rate, scale, pattern, dark_e)
    return frame_numpy(mean_e, table, *draw(rng, normal_indices, mean_e, below), **kw)


def _means(rate, scale, pattern, dark_e, has_pattern, below, mean, lam):
    """:func:`means_numpy` per value (compiled), and the means below ``below`` floored at 0 as float64, in C order
    (what :func:`draw` gathers), into ``lam``; returns their count."""
    j = 0
    for i in range(rate.size):
        if has_pattern:
            m = rate[i] * scale + pattern[i] * dark_e
        else:
            m = rate[i] * scale + dark_e
        mean[i] = m
        if m < below:
            lm = np.float64(m)
            lam[j] = lm if lm > 0.0 else 0.0
            j += 1
    return j


def _loop(mean, idx, table, below, lam, p0, u, rn2, rn, full_well, gain_k, black, saturation, out):
    """:func:`frame_numpy`'s arithmetic per value (compiled by numba; the same operations, types and order)."""
    j = 0
    for i in range(mean.size):
        m = mean[i]
        z = table[idx[i]]
        if m < below:
            lm = lam[j]
            p = p0[j]
            cdf = p
            uj = u[j]
            k = 0
            while uj > cdf:
                k += 1
                p = p * (lm * (1.0 / k))
                cn = cdf + p
                if cn == cdf:
                    break
                cdf = cn
            e = np.float32(np.float64(k) + np.float64(rn * z))
            j += 1
        else:
            e = np.sqrt(m + rn2) * z + m
        if e > full_well:
            e = full_well
        x = e * gain_k + black
        # np.rint(x) then clipped to [0, saturation]: x ≤ 0 rounds to a value ≤ 0, clipped to 0; 0 < x < 2²³ rounds
        # half to even as (x + 2²³) − 2²³ does in float32 (the sum's rounding is the rounding to an integer; exact
        # for these x, and vectorizable where the rint call is not); saturation < 2²³ clips everything larger
        if x <= 0:
            d = np.float32(0.0)
        elif x < TWO23:
            d = (x + TWO23) - TWO23
            if d > saturation:
                d = saturation
        else:
            d = saturation
        out[i] = d


@functools.lru_cache(maxsize=1)
def _compiled():
    import numba

    jit = numba.njit(cache=True, nogil=True)
    return jit(_means), jit(_loop)


def expose_compiled(rate, scale, pattern, dark_e, rng, normal_indices, table, below, *, read_noise, full_well, gain_k,
                    black, saturation, dtype=np.uint16) -> np.ndarray:
    """:func:`expose_numpy` in two numba passes over the values (the means and the Poisson means' gathering, then
    the noise and the conversion to DN), with the same random numbers drawn in the same order: the same frame bit
    for bit."""
    f32 = np.float32
    means, loop = _compiled()
    idx = normal_indices(rate.shape)
    rate1 = np.ascontiguousarray(rate, dtype=f32).reshape(-1)
    pat1 = rate1 if pattern is None else np.ascontiguousarray(pattern, dtype=f32).reshape(-1)
    mean = np.empty(rate1.size, dtype=f32)
    lam = np.empty(rate1.size, dtype=np.float64)
    n = means(rate1, f32(scale), pat1, f32(dark_e), pattern is not None, f32(below), mean, lam)
    lam = lam[:n]
    p0 = np.exp(-lam)
    u = rng.random(n)
    out = np.empty(rate.shape, dtype=dtype)
    loop(mean, np.ascontiguousarray(idx).reshape(-1), table, f32(below), lam, p0, u, f32(read_noise ** 2),
         f32(read_noise), f32(full_well), f32(gain_k), f32(black), f32(saturation), out.reshape(-1))
    return out
