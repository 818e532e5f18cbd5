"""The host side's fast paths give exactly what the plain formulations give (issue 17: faster, the same samples
bit for bit): the pipeline's pixel gathers, the tiles' sums, the compact merge's samples, the local gradient, the
frame checks' integer comparisons, normalize, the metering percentiles, a record's meta encoding."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.pipeline.acquire import _take, _used_index
from gonio.pipeline.hdr import HdrImage
from gonio.pipeline.reflectance import _tile_sums, build_roi, reflectance_samples, used_pixel_samples
from gonio.pipeline.uncertainty import local_h_gradient


def _same(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("nt, m, n", [(25, 6, 3000), (1, 3, 7), (64, 9, 0), (16, 12, 500)])
def test_tile_sums_are_the_per_column_bincounts_bit_for_bit(nt, m, n):
    rng = np.random.default_rng(nt * m + n)
    lab = rng.integers(0, nt, n)
    vals = rng.standard_normal((n, m)) * 10.0 ** rng.integers(-8, 8, (n, m))  # sums that round
    if n:
        vals[rng.integers(0, n, 3), rng.integers(0, m, 3)] = [np.nan, np.inf, -0.0]
    got = _tile_sums(lab, vals, nt)
    want = np.stack([np.bincount(lab, vals[:, k], minlength=nt) for k in range(m)], axis=-1)
    assert _same(got, want)


def _pose_roi(bench_factory, lambert, view=(35, 20, 45, 200)):
    bench = bench_factory(lambert)
    pose, light = bench.place(*view)
    roi = build_roi(pose, bench.calib, bench.layout, light)
    return bench, pose, light, roi


def test_pipeline_gathers_are_the_masked_box(bench_factory, lambert):
    bench, _, _, roi = _pose_roi(bench_factory, lambert)
    used = (roi.label >= 0) | roi.white
    index = _used_index(roi, used, bench.calib.width)
    rng = np.random.default_rng(2)
    for img in (rng.integers(0, 4096, (bench.calib.height, bench.calib.width, 3)).astype(np.uint16),
                rng.random((bench.calib.height, bench.calib.width, 1)).astype(np.float32)):
        assert _same(_take(img, index), img[roi.region][used])


@pytest.mark.parametrize("light_weight", [True, False])
def test_compact_merge_gives_the_samples_of_the_box(bench_factory, lambert, light_weight):
    """used_pixel_samples on the merge of the used pixels alone (what Pipeline.measure passes) gives bit for bit the
    samples reflectance_samples gives for the same values scattered on the ROI's box (NaN elsewhere)."""
    bench, pose, light, roi = _pose_roi(bench_factory, lambert)
    used = (roi.label >= 0) | roi.white
    n, K = int(used.sum()), 3
    rng = np.random.default_rng(4)
    rate = rng.uniform(50, 500, (n, 1, 3))
    var = rate * rng.uniform(0.01, 0.1, (n, 1, 3))
    sat = rng.random((n, 1, 3)) < 0.01
    rate[sat], var[sat] = np.nan, np.nan
    lw = rng.dirichlet(np.ones(K), (n, 1, 3)).transpose(3, 0, 1, 2).copy() if light_weight else None
    compact = HdrImage(rate=rate, var=var, saturated=sat, used=np.full((n, 1, 3), K),
                       light_weight=lw, light_rel_var=np.array([1e-6, 4e-6, 2e-6]))

    def box(values, fill, lead=()):
        out = np.full(lead + used.shape + values.shape[-1:], fill, dtype=values.dtype)
        out[(slice(None),) * len(lead) + (used,)] = values.reshape(lead + (n, values.shape[-1]))
        return out

    scattered = HdrImage(rate=box(rate, np.nan), var=box(var, np.nan), saturated=box(sat, False),
                         used=box(compact.used, 0), light_weight=None if lw is None else box(lw, np.nan, (K,)),
                         light_rel_var=compact.light_rel_var)
    perturbed = [type(pose)(pose.R, pose.t + d) for d in (np.array([1e-4, 0, 0]), np.array([0, -2e-4, 1e-4]))]
    kw = dict(pose_index=3, flags=4, pose_perturbations=perturbed, light_sigma=4e-4)
    got = used_pixel_samples(compact, roi, pose, light, bench.layout, **kw)
    want = reflectance_samples(scattered, roi, pose, light, bench.layout, **kw)
    assert len(got) == len(want) > 4
    for k, v in want.to_dict().items():
        assert _same(getattr(got, k), v), k


def _plain_local_h_gradient(f, h, n):
    """local_h_gradient as one neighbour at a time (the formulation the stacked one replaced)."""
    nt, chans = f.shape
    ok = np.isfinite(f).all(axis=1) & np.isfinite(h[:, :2]).all(axis=1)
    hxy = np.where(ok[:, None], h[:, :2], 0.0)
    f = np.where(ok[:, None], f, 0.0)
    iy, ix = np.divmod(np.arange(nt), n)
    A = np.zeros((nt, 2, 2))
    b = np.zeros((nt, chans, 2))
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx == 0 and dy == 0:
                continue
            jx, jy = ix + dx, iy + dy
            inside = (jx >= 0) & (jx < n) & (jy >= 0) & (jy < n)
            j = np.where(inside, jy * n + jx, 0)
            use = inside & ok & ok[j]
            dh = np.where(use[:, None], hxy[j] - hxy, 0.0)
            df = np.where(use[:, None], f[j] - f, 0.0)
            A += dh[:, :, None] * dh[:, None, :]
            b += df[:, :, None] * dh[:, None, :]
    G = np.einsum("tcj,tij->tci", b, np.linalg.pinv(A, rcond=1e-9, hermitian=True))
    G[~ok] = 0.0
    return G


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
def test_local_gradient_stacked_is_one_neighbour_at_a_time_bit_for_bit(n):
    rng = np.random.default_rng(n)
    h = np.column_stack([rng.normal(0, 0.05, (n * n, 2)), np.ones(n * n)])
    f = rng.uniform(0.05, 2.0, (n * n, 3))
    if n > 2:
        f[rng.integers(0, n * n)] = np.nan  # a tile without a value
        h[rng.integers(0, n * n), 0] = np.inf
        h[rng.integers(0, n * n), :2] = h[0, :2]  # a neighbour at the same h: a zero step
    assert _same(local_h_gradient(f, h, n), _plain_local_h_gradient(f, h, n))


@pytest.mark.parametrize("shape, dtype", [((48, 64, 3), np.uint16), ((47, 63, 3), np.uint16), ((48, 64, 1), np.uint8),
                                          ((9, 7, 3), np.uint8)])
def test_signal_checks_integer_comparisons_are_the_float_ones(shape, dtype):
    """SignalCheck's whole-frame integer comparisons decide exactly as the quarter's float comparisons: values at
    ⌊a⌋ and ⌊a⌋ + 1 of every threshold, thresholds below 0, above the dtype's range, NaN; limits between
    integers, on them, at 0 and below, beyond the range, infinite and NaN."""
    from gonio.pipeline.signal import SignalCheck

    rng = np.random.default_rng(shape[0] * shape[1])
    top = np.iinfo(dtype).max
    sub_shape = np.zeros(shape)[::2, ::2].shape
    above = rng.uniform(-2, top + 2, sub_shape)
    above[rng.random(sub_shape) < 0.1] = np.nan
    integral = rng.random(sub_shape) < 0.3
    above[integral] = np.floor(above[integral])  # thresholds on an integer
    check = SignalCheck(None, None)
    for case in range(40):
        px = rng.integers(0, top + 1, shape).astype(dtype)
        if case % 2:  # every quarter pixel at its threshold's floor or one above: the decision is at the edge
            edge = np.clip(np.nan_to_num(np.floor(above), nan=0) + rng.integers(0, 2, sub_shape), 0, top)
            px[::2, ::2] = edge.astype(dtype)
        a = above if case % 3 else np.where(above < 0, 0.5, above)  # some with no threshold below 0
        ints = {}
        for _ in range(2):  # the integer image built, then kept
            assert SignalCheck._surely_above(px, a, ints) == bool(np.any(px[::2, ::2] > a))
        for limit in (0.0, -3.0, 0.5, 1.0, 17.0, 17.25, top - 0.5, float(top), top + 1.0, np.inf, np.nan,
                      float(px[::2, ::2].max()), float(px.max()), float(np.median(px))):
            assert check._count_at_or_above(px, limit) == int(np.count_nonzero(px[::2, ::2] >= limit)), limit


def test_normalize_is_the_linalg_norm_formula_bit_for_bit():
    """gonio.geometry.normalize's length on the components is np.linalg.norm's (numpy sums a last axis of three
    left to right): random vectors over 400 decades, zero, sub-normal, infinite and NaN ones, every shape."""
    from gonio.geometry import Z, _vec, normalize

    def plain(v, fallback=Z):
        v = _vec(v)
        n = np.linalg.norm(v, axis=-1, keepdims=True)
        ok = n > 1e-300
        with np.errstate(invalid="ignore", divide="ignore"):
            u = v / np.where(ok, n, 1.0)
        return np.where(ok, u, np.broadcast_to(_vec(fallback), v.shape))

    rng = np.random.default_rng(0)
    cases = [rng.standard_normal((20000, 3)) * 10.0 ** rng.integers(-150, 150, (20000, 3)), rng.standard_normal(3),
             [1.0, 2, 3], np.zeros(3), np.zeros((0, 3)), rng.standard_normal((4, 5, 3)), np.array([1, 2, 2]),
             np.array([[0, 0, 0], [np.inf, 1, 0], [np.nan, 0, 0], [-0.0, 0, -0.0], [1e-310, 0, 0], [3e-160, 0, 0]]),
             np.array([[1, 2, 3]], np.float32)]
    for v in cases:
        for fallback in (Z, [1.0, 0.0, 0.0]):
            assert _same(normalize(v, fallback), plain(v, fallback))


def test_record_meta_encoding_is_unchanged_by_the_builtin_fast_path():
    """records._jsonable handles the built-in types of a pose's meta before its generic checks: the same JSON for
    nested dicts, lists, tuples, finite and non-finite floats, numpy scalars and arrays, objects with to_dict."""
    import json
    import math

    from gonio.session.records import _jsonable

    class Plan:
        def to_dict(self):
            return {"n": 2, "x": (1.5, float("inf"))}

    def plain(obj):  # the generic checks alone, in their order
        if hasattr(obj, "to_dict") and callable(obj.to_dict):
            return plain(obj.to_dict())
        if isinstance(obj, dict):
            return {str(k): plain(v) for k, v in obj.items()}
        if isinstance(obj, (list, tuple)):
            return [plain(v) for v in obj]
        if isinstance(obj, np.ndarray):
            return plain(obj.tolist())
        if isinstance(obj, np.generic):
            return obj.item()
        if isinstance(obj, float) and not math.isfinite(obj):
            return repr(obj)
        return obj

    meta = {"pose_rad": [0.1, -0.0, 2.5], 7: {"k": float("nan"), "u": None, "ok": True, "n": 3, "s": "x"},
            "t": (1, (2.0, float("-inf"))), "np": [np.float64(0.25), np.int64(4), np.arange(3), np.float32(1.5)],
            "plan": Plan(), "nested": [[{"a": [{"b": 1e-300}]}]]}
    assert json.dumps(_jsonable(meta), allow_nan=False) == json.dumps(plain(meta), allow_nan=False)


def test_metering_percentiles_in_one_call_are_the_separate_ones():
    """Pipeline._meter takes its two percentiles of float64 values in one np.percentile call: each is bit for bit
    the value of its own call (ties, distinct values, tiny and large samples)."""
    rng = np.random.default_rng(8)
    for n in (1, 2, 7, 600, 6001):
        for vals in (rng.integers(0, 50, (n, 3)).astype(np.float64) + 0.5, rng.lognormal(3, 2, (n, 3)) / 0.016):
            both = np.percentile(vals, [99.9, 2.0])
            assert _same(both[0], np.percentile(vals, 99.9)) and _same(both[1], np.percentile(vals, 2.0))
