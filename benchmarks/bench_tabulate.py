"""Tabulation of scattered samples onto the MERL grid, and MERL write/read throughput."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import Table, time_call
from gonio.brdf import make
from gonio.geometry import from_spherical
from gonio.io.merl import FILE_SIZE, N_CELLS, flat_index, read_merl, write_merl
from gonio.samples import SampleSet
from gonio.tabulate import DEFAULT_FILL_DEG, tabulate


def _samples(n: int, seed: int = 0) -> SampleSet:
    rng = np.random.default_rng(seed)
    wi = from_spherical(np.arccos(rng.random(n)), 2 * np.pi * rng.random(n))
    wo = from_spherical(np.arccos(rng.random(n)), 2 * np.pi * rng.random(n))
    f = make("microfacet", kd=0.2, alpha=0.2).eval(wi, wo)
    sigma = 0.02 * f + 1e-4
    return SampleSet(wi, wo, f + rng.normal(size=f.shape) * sigma, sigma)


def _python_loop_means(s: SampleSet) -> dict:
    """Baseline: the obvious per-sample Python loop (weighted sums in a dict)."""
    idx = flat_index(s.wi, s.wo)
    acc: dict[int, list[float]] = {}
    for k, f, sg in zip(idx.tolist(), s.f.tolist(), s.sigma.tolist()):
        a = acc.setdefault(k, [0.0] * 7)
        for c in range(3):
            w = 1.0 / sg[c] ** 2
            a[c] += w * f[c]
            a[3 + c] += w
        a[6] += 1
    return acc


def _bincount_means(s: SampleSet) -> tuple:
    """The same accumulation as the baseline, vectorized (what :func:`gonio.tabulate.tabulate` does)."""
    idx = flat_index(s.wi, s.wo)
    w = 1.0 / s.sigma**2
    sums = [np.bincount(idx, w[:, c] * s.f[:, c], minlength=N_CELLS) for c in range(3)]
    return sums, [np.bincount(idx, w[:, c], minlength=N_CELLS) for c in range(3)], np.bincount(idx, minlength=N_CELLS)


def _once(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def run(quick: bool = False) -> list[Table]:
    sizes = [10_000, 100_000] if quick else [10_000, 100_000, 1_000_000]
    t1 = Table("Tabulating N scattered samples (microfacet, random direction pairs)",
               ["N samples", "fill (deg)", "seconds", "samples/s", "× baseline"])
    base_n = 10_000
    s = _samples(base_n)
    base = time_call(lambda: _python_loop_means(s), min_time=0.1, repeat=2)
    t1.add(base_n, "-", base, base_n / base, 1.0)
    t1.baseline = 0
    t1.notes.append("baseline: per-sample Python loop accumulating weighted sums in a dict (no isotropy "
                    "check, no filling)")
    for n in sizes:
        s = _samples(n)
        sec = _once(lambda: _bincount_means(s))
        t1.add(n, "accumulation only", sec, n / sec, (n / sec) / (base_n / base))
        for fill in (0.0, DEFAULT_FILL_DEG):
            sec = _once(lambda: tabulate(s, fill_deg=fill))
            t1.add(n, fill, sec, n / sec, (n / sec) / (base_n / base))
            if n == sizes[-1] and fill == DEFAULT_FILL_DEG:
                t1.default = len(t1.rows) - 1
    t1.why_default = "gonio's default hole filling (2°) at the largest N; includes the isotropy check"
    t1.notes.append("one run each (not best-of); wall time depends on the machine's load")

    t2 = Table("MERL binary write/read (34,992,012 bytes)", ["operation", "seconds", "MB/s", "× baseline"])
    rng = np.random.default_rng(1)
    from gonio.io.merl import MerlTable

    values = rng.uniform(0, 10, (90, 90, 180, 3))
    values[rng.random((90, 90, 180)) < 0.25] = np.nan
    table = MerlTable(values)
    mb = FILE_SIZE / 1e6
    with tempfile.TemporaryDirectory() as tmp:
        raw, path = Path(tmp) / "raw.bin", Path(tmp) / "t.binary"
        arr = np.ascontiguousarray(np.moveaxis(values, -1, 0))
        w0 = time_call(lambda: raw.write_bytes(arr.tobytes()), min_time=0.2, repeat=2)
        r0 = time_call(lambda: np.fromfile(raw, dtype="<f8"), min_time=0.2, repeat=2)
        w = time_call(lambda: write_merl(path, table), min_time=0.2, repeat=2)
        r = time_call(lambda: read_merl(path), min_time=0.2, repeat=2)
    t2.add("raw write of the float64 array", w0, mb / w0, 1.0)
    t2.add("write_merl", w, mb / w, w0 / w)
    t2.add("raw np.fromfile", r0, mb / r0, 1.0)
    t2.add("read_merl (validate, scale, NaN)", r, mb / r, r0 / r)
    t2.baseline = 0
    t2.default = 1
    t2.why_default = "the functions gonio uses; ratios against raw I/O of the same bytes (write vs raw write, read vs raw read)"
    t2.notes.append(f"{N_CELLS:,} cells × 3 channels; 25 % not measured")
    return [t1, t2]
