"""The simulated sensor's per-pixel chain: electron rates → mean electrons → shot and read noise → full well →
digital numbers.

:class:`sim.camera.SimCamera` hands a frame's electron rates to :func:`expose_compiled` (numba, used when numba,
the ``fast`` extra, is installed and pays in the process, :mod:`sim.compiled`: one vectorized pass over every value
by the normal approximation, which also gathers the values below the Poisson threshold, then a pass over those
alone, instead of ~20 whole-array operations) or to its reference :func:`expose_numpy` (whole-array NumPy operations).
Both draw the frame's random numbers with NumPy in one fixed order (:func:`draw`: the normal table's indices, then
one uniform per Poisson value) and then do the same IEEE operations in the same order and precision on them, so they
give the same frame bit for bit (tests/pipeline/test_fast_paths_exact.py), and a seed gives the same samples with or
without numba.

Noise model (EMVA Standard 1288 R4.0, 2021, §2: shot noise Poisson in the electrons, read noise Gaussian):

* a pixel whose mean μ is at least ``below`` electrons: ``μ + √(μ + σ_r²) z`` with one standard normal
  ``z`` (the normal approximation N(μ, μ) of the Poisson law plus the read noise in one draw);
* below it: ``k + σ_r z`` with ``k`` Poisson(μ) drawn exactly by inversion, the sequential search of
  Devroye, *Non-Uniform Random Variate Generation*, 1986, §X.3.3: with one uniform ``u``, the smallest
  ``k`` with ``u ≤ Σ_{j≤k} e^{−μ} μʲ/j!``, the terms by the recurrence ``p_j = p_{j−1} · (μ · (1/j))`` (one
  multiplication on the chain of dependent operations instead of a division: a step is ~4 cycles; the compiled
  search loads ``1/j`` from a table, :data:`RECIPROCALS`, instead of dividing). The search
  stops when a term no longer changes the float64 partial sum (the tail beyond it is below 2⁻⁵³ of the sum),
  so the law is exact up to the rounding of the partial sums; it costs ~μ + 1 steps, cheap where it is used
  (μ < 30, most pixels μ < 5).

``z`` comes from :func:`sim.camera.normal_table` indexed by 16-bit uniform integers (inverse transform
sampling, Devroye §II.2). Then the full well clips the electrons, the system gain and the black level turn
them into DN, rounded half to even and clipped to the sensor's range.
"""

from __future__ import annotations

import functools

import numpy as np

from gonio.brdf.compiled import available as compiled_available  # numba installed (re-exported)

__all__ = ["draw", "frame_numpy", "means_numpy", "expose_numpy", "expose_compiled", "compiled_available",
           "LowValues"]

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
    Devroye 1986 §X.3.3), the searches side by side as :func:`_search_lanes` runs them compiled: at step ``j`` every
    value whose search goes on advances with the same operations in the same order (so each gets its own search's
    ``k``), by whole-array operations; the values whose search ended are dropped once they are half of those left."""
    out = np.zeros(lam.size, dtype=np.int64)
    idx = np.flatnonzero(u > p0)  # the values whose search takes a first step
    lam, p, u = lam[idx], p0[idx], u[idx]
    cdf = p.copy()
    k = np.zeros(idx.size, dtype=np.int64)
    alive = np.ones(idx.size, dtype=bool)
    live, j = idx.size, 0
    while live:
        j += 1
        act = u > cdf
        act &= alive  # the search's loop condition: step j is taken, k = j
        k += act
        pn = lam * (1.0 / j)
        pn *= p
        cn = cdf + pn
        np.not_equal(cn, cdf, out=alive)
        alive &= act  # the term changed the sum: the next step's condition decides
        p, cdf = pn, cn
        live = np.count_nonzero(alive)
        if live and live < alive.size // 2:
            out[idx] = k
            keep = np.flatnonzero(alive)
            idx, lam, p, cdf, u, k = idx[keep], lam[keep], p[keep], cdf[keep], u[keep], k[keep]
            alive = np.ones(idx.size, dtype=bool)
    out[idx] = k
    return out


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


#: 1/k for k = 1 … 256, float64: the factors of the Poisson search's steps, loaded instead of divided (IEEE 754
#: division is correctly rounded, so these are the quotients ``1.0 / k`` the search computed; the division was the
#: slowest operation of a step). The search divides beyond k = 256 (λ < 30 ends it long before).
RECIPROCALS = 1.0 / np.arange(1, 257, dtype=np.float64)


def _dn(e, full_well, gain_k, black, saturation):
    """Electrons ``e`` (float32) to DN as :func:`frame_numpy` does: clipped at ``full_well``, times ``gain_k`` plus
    ``black``, ``np.rint`` then clipped to [0, ``saturation``] (compiled; branch-free, so that loops calling it
    vectorize).

    x ≤ 0 rounds to a value ≤ 0, clipped to 0; 0 < x < 2²³ rounds half to even as (x + 2²³) − 2²³ does in float32
    (the sum's rounding is the rounding to an integer; exact for these x, and vectorizable where the rint call is
    not); saturation < 2²³ clips everything larger, and NaN, whose comparisons are false, to ``saturation``."""
    if e > full_well:
        e = full_well
    x = e * gain_k + black
    d = (x + TWO23) - TWO23
    if x <= 0:
        d = np.float32(0.0)
    if not d <= saturation:
        d = saturation
    return d


def _block(rate, pattern, scale, dark_e, has_pattern, idx, table, z, below, rn2, full_well, gain_k, black,
           saturation, out):
    """One block of values (slices): every value by the normal approximation (the means as :func:`means_numpy`
    computes them, the module docstring's ``μ + √(μ + σ_r²) z``, :func:`_dn`) into ``out``; returns whether any
    mean is below ``below`` (compiled). The table lookups go first into ``z``: the loop that follows, without an
    indirect load, vectorizes."""
    for k in range(rate.size):
        z[k] = table[idx[k]]
    low = False
    for k in range(rate.size):
        if has_pattern:
            m = rate[k] * scale + pattern[k] * dark_e
        else:
            m = rate[k] * scale + dark_e
        out[k] = _dn(np.sqrt(m + rn2) * z[k] + m, full_well, gain_k, black, saturation)
        low |= m < below
    return low


def _gather(rate, pattern, scale, dark_e, has_pattern, below, a, b, j, pos, lam):
    """The values among ``a … b−1`` whose mean is below ``below``: their indices into ``pos`` and their means floored
    at 0, as float64 (what :func:`draw` gathers), into ``lam``, from ``j`` on; returns the next ``j`` (compiled)."""
    for i in range(a, b):
        if has_pattern:
            m = rate[i] * scale + pattern[i] * dark_e
        else:
            m = rate[i] * scale + dark_e
        if m < below:
            pos[j] = i
            lm = np.float64(m)
            lam[j] = lm if lm > 0.0 else 0.0
            j += 1
    return j


#: values per block of the first pass (blocks without a mean below the threshold skip the gathering)
BLOCK = 1024


def _pass1(rate, pattern, scale, dark_e, has_pattern, idx, table, below, rn2, full_well, gain_k, black, saturation,
           out, pos, lam):
    """Every value by the normal approximation, block by block (:func:`_block`), and the values below ``below``
    gathered in C order (:func:`_gather`); returns their count (compiled)."""
    size = rate.size
    z = np.empty(BLOCK, dtype=np.float32)
    j = 0
    for a in range(0, size, BLOCK):
        b = min(size, a + BLOCK)
        if _block(rate[a:b], pattern[a:b], scale, dark_e, has_pattern, idx[a:b], table, z, below, rn2, full_well,
                  gain_k, black, saturation, out[a:b]):
            j = _gather(rate, pattern, scale, dark_e, has_pattern, below, a, b, j, pos, lam)
    return j


def _poisson_dn(k, rn, z, full_well, gain_k, black, saturation):
    """A Poisson value's DN: ``k + σ_r z`` (int64 + float32 in float64, stored as float32, as
    :func:`electrons_numpy` does), then :func:`_dn` (compiled)."""
    return _dn(np.float32(np.float64(k) + np.float64(rn * z)), full_well, gain_k, black, saturation)


def _pass2(pos, idx, table, lam, p0, u, recip, rn, full_well, gain_k, black, saturation, out):
    """The values gathered by :func:`_pass1` (means below the threshold): ``k + σ_r z`` with ``k`` Poisson by
    inversion (:func:`poisson_inversion`'s operations for one value, with ``recip`` = :data:`RECIPROCALS`;
    int64 + float32 in float64, stored as float32, as :func:`electrons_numpy` does), to DN over what the first pass
    wrote (compiled)."""
    nr = recip.size
    for j in range(lam.size):
        lm = lam[j]
        p = p0[j]
        cdf = p
        uj = u[j]
        k = 0
        while uj > cdf:
            k += 1
            p = p * (lm * (recip[k - 1] if k <= nr else 1.0 / k))
            cn = cdf + p
            if cn == cdf:
                break
            cdf = cn
        i = pos[j]
        out[i] = _poisson_dn(k, rn, table[idx[i]], full_well, gain_k, black, saturation)


#: Values per block of :func:`_pass2_lanes`, and the largest mean below which :func:`expose_compiled` takes
#: :func:`_pass2` instead (its searches end in a step or two; the lanes' block runs as long as its longest search)
LANES, LANES_FROM = 256, 0.5


def _search_lanes(lam, p0, u, recip, k, p, cdf, alive):
    """:func:`_pass2`'s searches of the block ``lam``, ``p0``, ``u`` side by side, step after step, into ``k``: at
    step ``j`` every value whose search goes on (``alive``) advances as that search does, with the same operations
    in the same order, and the block stops when none goes on. Without a branch per value the steps vectorize; a
    value's last steps are done for nothing when its neighbours' searches are longer (compiled)."""
    m = lam.size
    for i in range(m):
        p[i] = p0[i]
        cdf[i] = p0[i]
        k[i] = 0
        alive[i] = 1
    nr = recip.size
    j = 0
    while True:
        j += 1
        r = recip[j - 1] if j <= nr else 1.0 / j
        going = 0
        for i in range(m):
            act = alive[i] & (u[i] > cdf[i])  # the search's loop condition: step j is taken, k = j
            k[i] += act
            pn = p[i] * (lam[i] * r)
            cn = cdf[i] + pn
            p[i] = pn
            alive[i] = act & (cn != cdf[i])  # the term changed the sum: the next step's condition decides
            cdf[i] = cn
            going |= alive[i]
        if going == 0:
            return


def _pass2_lanes(pos, idx, table, lam, p0, u, recip, rn, full_well, gain_k, black, saturation, out):
    """:func:`_pass2` with the searches of each block of :data:`LANES` values side by side (:func:`_search_lanes`):
    the same ``k`` for each value, ~2× faster when the means are a few electrons or more (compiled)."""
    k = np.empty(LANES, dtype=np.int64)
    alive = np.empty(LANES, dtype=np.int64)
    p, cdf = np.empty(LANES), np.empty(LANES)
    n = lam.size
    for a in range(0, n, LANES):
        b = min(n, a + LANES)
        _search_lanes(lam[a:b], p0[a:b], u[a:b], recip, k, p, cdf, alive)
        for j in range(b - a):
            i = pos[a + j]
            out[i] = _poisson_dn(k[j], rn, table[idx[i]], full_well, gain_k, black, saturation)


#: A frame whose values below the Poisson threshold all have one mean of at least this (a dark frame: the dark signal
#: of a long exposure) takes :func:`_pass2_one_mean`; below it the search ends in one or two steps
ONE_MEAN_FROM = 1.0
#: The partial sums :func:`_pass2_one_mean` tabulates at most (a mean below the threshold, 30, needs ~100) and the
#: buckets of their guide (Chen & Asau, "On generating random variates from an empirical distribution", AIIE
#: Transactions 6(2), 1974)
ONE_MEAN_TABLE, ONE_MEAN_GUIDE = 512, 64


def _pass2_one_mean(pos, idx, table, lm, p0, u, recip, rn, full_well, gain_k, black, saturation, out, cdfs, guide):
    """:func:`_pass2` for values that all have the mean ``lm`` (``p0`` = e^−lm, as :func:`draw` computes it): the
    partial sums its search computes — the same operations in the same order — are tabulated once in ``cdfs``, and
    each value's ``k`` (the first with ``u ≤ cdf_k``, or the step at which a term no longer changed the sum) is
    found from the guide's bucket of ``u`` by two exact scans: the same ``k`` in one or two steps instead of ~λ.
    Returns False, having written nothing, when the sums do not end within ``cdfs`` (compiled)."""
    nr = recip.size
    p = p0
    cdf = p
    cdfs[0] = cdf
    n = 0
    while True:
        n += 1
        p = p * (lm * (recip[n - 1] if n <= nr else 1.0 / n))
        cn = cdf + p
        if cn == cdf:
            break
        if n >= cdfs.size:
            return False
        cdfs[n] = cn
        cdf = cn
    ng = guide.size
    k = 0
    for g in range(ng):
        while k < n and cdfs[k] < g / ng:
            k += 1
        guide[g] = k
    for j in range(u.size):
        uj = u[j]
        g = int(uj * ng)
        k = guide[g if g < ng else ng - 1]
        while k > 0 and uj <= cdfs[k - 1]:
            k -= 1
        while k < n and uj > cdfs[k]:
            k += 1
        i = pos[j]
        out[i] = _poisson_dn(k, rn, table[idx[i]], full_well, gain_k, black, saturation)
    return True


@functools.lru_cache(maxsize=1)
def _compiled():
    import numba
    from numba.extending import register_jitable

    for f in (_dn, _poisson_dn, _block, _gather, _search_lanes):
        register_jitable(f)
    from sim.compile_lock import serialized

    jit = numba.njit(cache=True, nogil=True)
    return tuple(serialized(jit(f)) for f in (_pass1, _pass2, _pass2_one_mean, _pass2_lanes))


def _all_below(pattern, dark_e, below) -> bool:
    """Every mean ``fl(p · dark_e)`` (``dark_e`` without a pattern) of a zero-rate frame is below ``below``, in
    float32 as :func:`_pass1` compares them."""
    top = np.float32(dark_e) if pattern is None else np.float32(np.max(pattern)) * np.float32(dark_e)
    return bool(top < np.float32(below))


@functools.lru_cache(maxsize=4)
def _positions(n: int) -> np.ndarray:
    """``0 … n − 1`` (intp, read-only): the positions of a frame whose every value is a Poisson value."""
    pos = np.arange(n, dtype=np.intp)
    pos.flags.writeable = False
    return pos


class LowValues:
    """The values below the Poisson threshold of the last frame :func:`expose_compiled` exposed under a ``key``: their
    indices (C order), their means floored at 0 (float64), ``e^−mean`` and whether they are every value of the frame
    (a dark frame's, at exposures whose dark signal stays below the threshold). A caller that knows two frames have the
    same means (a dark set: several light-off frames at one exposure, whose means are the dark signal alone) passes the
    same key, and the second frame reuses them instead of gathering them and computing the exponentials again (and
    skips the first pass when they are every value: the second pass writes each one). One key at a time: a dark set
    takes its exposures one after the other."""

    __slots__ = ("key", "pos", "lam", "p0", "every")

    def __init__(self):
        self.key = self.pos = self.lam = self.p0 = None
        self.every = False


def expose_compiled(rate, scale, pattern, dark_e, rng, normal_indices, table, below, *, read_noise, full_well, gain_k,
                    black, saturation, dtype=np.uint16, memo: LowValues | None = None, key=None,
                    dark: bool = False) -> np.ndarray:
    """:func:`expose_numpy` in two numba passes: every value by the normal approximation, block by block, and the
    means below ``below`` gathered (:func:`_pass1`); then, with the uniforms drawn for those, their Poisson values
    written over the first pass's (:func:`_pass2`; :func:`_pass2_lanes` when some mean is :data:`LANES_FROM` or
    more; :func:`_pass2_one_mean` when they all have one mean, as a dark frame's do without a DSNU pattern). The
    same random numbers drawn in the same order and the same operations on each value: the same frame bit for bit.

    ``memo`` and ``key``: the caller's promise that frames exposed under one ``key`` have the same means (the same
    ``rate · scale + pattern · dark_e`` and ``below``); their values below the threshold are gathered once
    (:class:`LowValues`). Still the same frame bit for bit: the same numbers are drawn and the same operations done
    on each value.

    ``dark``: the caller's promise that ``rate`` is zero everywhere (a light-off frame; the means are
    ``pattern · dark_e`` in float32, ``dark_e`` without a pattern). When even the largest is below ``below``
    (float32 rounding is monotonic: ``fl(p · d) ≤ fl(max(p) · d)``) every value is a Poisson value: their means
    are made by one NumPy product instead of the first pass, whose values the second pass would all overwrite."""
    f32 = np.float32
    pass1, pass2, pass2_one_mean, pass2_lanes = _compiled()
    idx = np.ascontiguousarray(normal_indices(rate.shape)).reshape(-1)
    out = np.empty(rate.shape, dtype=dtype)
    out1 = out.reshape(-1)
    conv = (f32(full_well), f32(gain_k), f32(black), f32(saturation))
    known = memo is not None and key is not None and memo.key == key
    if not known and dark and _all_below(pattern, dark_e, below):  # every value's mean, as pass1 makes it
        lam = (np.full(rate.size, f32(dark_e)) if pattern is None else
               np.multiply(np.ascontiguousarray(pattern, dtype=f32).reshape(-1), f32(dark_e))).astype(np.float64)
        np.maximum(lam, 0.0, out=lam)  # as _gather floors them (no NaN: a finite pattern and dark signal)
        pos, n = _positions(lam.size), lam.size
    elif not (known and memo.every):  # every value by the normal approximation, the low ones gathered
        rate1 = np.ascontiguousarray(rate, dtype=f32).reshape(-1)
        pat1 = rate1 if pattern is None else np.ascontiguousarray(pattern, dtype=f32).reshape(-1)
        pos = np.empty(rate1.size, dtype=np.intp)
        lam = np.empty(rate1.size, dtype=np.float64)
        n = pass1(rate1, pat1, f32(scale), f32(dark_e), pattern is not None, idx, table, f32(below),
                  f32(read_noise ** 2), *conv, out1, pos, lam)
        if known:
            assert n == memo.lam.size, "sensor_noise: frames exposed under one key must have the same means"
    if known:
        pos, lam, p0 = memo.pos, memo.lam, memo.p0
        n = lam.size
    elif n:
        lam = lam[:n]
        p0 = np.negative(lam)
        np.exp(p0, out=p0)  # np.exp(-lam) in one array instead of two (fresh pages cost more than the exp)
        if memo is not None and key is not None:
            memo.key, memo.pos, memo.lam, memo.p0, memo.every = key, pos[:n], lam, p0, n == out1.size
    if n:
        u = rng.random(n)
        top = lam.max()
        one = n > 1 and lam[0] >= ONE_MEAN_FROM and lam.min() == top and p0.min() == p0.max()
        if not (one and pass2_one_mean(pos, idx, table, lam[0], p0[0], u, RECIPROCALS, f32(read_noise), *conv, out1,
                                       np.empty(ONE_MEAN_TABLE), np.empty(ONE_MEAN_GUIDE, dtype=np.int64))):
            search = pass2_lanes if top >= LANES_FROM else pass2
            search(pos, idx, table, lam, p0, u, RECIPROCALS, f32(read_noise), *conv, out1)
    return out


expose_compiled.kernels = _compiled  # the numba kernels it calls (for sim.compiled.pick)
