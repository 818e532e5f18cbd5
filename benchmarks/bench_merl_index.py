"""MERL cell index: the reference-exact lookup (gonio.io.merl_index, the cell BRDFRead.cpp reads) against
a scalar per-pair port of the reference in Python (baseline, exact by construction) and against the
plain NumPy index from gonio.geometry's angles (what gonio did before: fast, not the reference's cell)."""

from __future__ import annotations

import math

import numpy as np

from benchmarks.common import Table, time_call
from gonio.geometry import half_diff_from_dirs
from gonio.io.merl_index import directions_from_angles, reference_index


def _rotate(v, axis, angle):
    """rotate_vector of BRDFRead.cpp, term for term."""
    c, s = math.cos(angle), math.sin(angle)
    out = [v[0] * c, v[1] * c, v[2] * c]
    temp = (axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2]) * (1.0 - c)
    out = [out[0] + axis[0] * temp, out[1] + axis[1] * temp, out[2] + axis[2] * temp]
    cross = [axis[1] * v[2] - axis[2] * v[1], axis[2] * v[0] - axis[0] * v[2], axis[0] * v[1] - axis[1] * v[0]]
    return [out[0] + cross[0] * s, out[1] + cross[1] * s, out[2] + cross[2] * s]


def _acos(x):
    return math.acos(x) if -1.0 <= x <= 1.0 else math.nan


def _trunc(x):
    return -(2 ** 31) if math.isnan(x) else int(x)


def _scalar_reference(wi, wo) -> np.ndarray:
    """Baseline: BRDFRead.cpp's std_coords_to_half_diff_coords + index functions, one pair at a time."""
    out = np.empty(len(wi), dtype=np.int64)
    for n, (a, b) in enumerate(zip(wi.tolist(), wo.tolist())):
        ln = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
        i = [a[0] / ln, a[1] / ln, a[2] / ln]
        h = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0, (a[2] + b[2]) / 2.0]
        ln = math.sqrt(h[0] * h[0] + h[1] * h[1] + h[2] * h[2])
        h = [h[0] / ln, h[1] / ln, h[2] / ln]
        th, ph = _acos(h[2]), math.atan2(h[1], h[0])
        d = _rotate(_rotate(i, (0.0, 0.0, 1.0), -ph), (0.0, 1.0, 0.0), -th)
        td, pd = _acos(d[2]), math.atan2(d[1], d[0])
        ih = 0 if th <= 0 else min(max(_trunc(math.sqrt(th / (math.pi / 2.0) * 90 * 90)), 0), 89)
        idd = min(max(_trunc(td / (math.pi * 0.5) * 90), 0), 89)
        pd = pd + math.pi if pd < 0.0 else pd
        ip = min(max(_trunc(pd / math.pi * 360 / 2), 0), 179)
        out[n] = ip + 180 * (idd + 90 * ih)
    return out


def _numpy_geometry(wi, wo) -> np.ndarray:
    """gonio before: geometry's angles, sqrt mapping written differently, φd folded by mod π."""
    th, _, td, pd = half_diff_from_dirs(wi, wo)
    ih = np.clip(np.floor(np.sqrt(th / (np.pi / 2)) * 90), 0, 89)
    idd = np.clip(np.floor(td / (np.pi / 2) * 90), 0, 89)
    ip = np.clip(np.floor(np.mod(pd, np.pi) / np.pi * 180), 0, 179)
    return (ip + 180 * (idd + 90 * ih)).astype(np.int64)


def _exact(wi, wo) -> np.ndarray:
    ih, idd, ip = reference_index(wi, wo)
    return ip + 180 * (idd + 90 * ih)


def _inputs(quick: bool):
    rng = np.random.default_rng(0)
    n = 100_000 if quick else 1_000_000
    v = rng.normal(size=(2, n, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    k = 8 if quick else 16  # BRDFRead.cpp's printed grid: k × 4k × k × 4k
    i, j, l, m = np.meshgrid(np.arange(k), np.arange(4 * k), np.arange(k), np.arange(4 * k), indexing="ij")
    g = directions_from_angles(i * 0.5 * math.pi / k, j * 2.0 * math.pi / (4 * k), l * 0.5 * math.pi / k,
                               m * 2.0 * math.pi / (4 * k))
    return [("random pairs", v[0], v[1]), (f"printed grid {k}x{4 * k}x{k}x{4 * k}", g[0].reshape(-1, 3),
                                           g[1].reshape(-1, 3))]


def run(quick: bool = False) -> list[Table]:
    t = Table("MERL cell index of direction pairs: the reference reader's cell, bit for bit",
              ["input", "method", "Mpairs/s", "× baseline", "cells differing from the reference"])
    for name, wi, wo in _inputs(quick):
        sub = slice(0, 20_000)
        base = time_call(lambda: _scalar_reference(wi[sub], wo[sub]), min_time=0.1, repeat=1) / len(wi[sub])
        ref = _exact(wi, wo)
        sample = _scalar_reference(wi[sub], wo[sub])
        t.add(name, "scalar port of BRDFRead.cpp (baseline)", 1e-6 / base, 1.0,
              f"{np.count_nonzero(sample != ref[sub])} of {len(sample):,}")
        for label, fn in (("gonio (NumPy + C-library recheck near boundaries)", _exact),
                          ("NumPy on geometry angles (gonio before)", _numpy_geometry)):
            sec = time_call(lambda: fn(wi, wo), min_time=0.2, repeat=2) / len(wi)
            diff = np.count_nonzero(fn(wi, wo) != ref)
            t.add(name, label, 1e-6 / sec, base / sec, f"{diff:,} of {len(wi):,} ({100 * diff / len(wi):.2f} %)")
    t.baseline = 0
    t.notes.append("baseline: the reference's arithmetic per pair in Python (math = the C library), on 20,000 "
                   "pairs; its cells agree with gonio's exact index (first rows), checked in tests/io/"
                   "test_merl_reference.py against a separate port on the full printed grid")
    return [t]
