"""Per-sample CSV export: one row per sample, a header row, BRDF in 1/sr (not × cos θ), angles in degrees.

Columns: ``theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg, r, g, b, sigma_r, sigma_g, sigma_b,
flags, n_pixels, pose`` (flags: the bit mask of :mod:`gonio.samples`; n_pixels: pixels averaged;
pose: the plan pose index). Floats are written with 17 significant digits, so values read back
exactly.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from gonio.errors import DataError
from gonio.io.outputs import written_atomically
from gonio.samples import SampleSet

__all__ = ["COLUMNS", "write_csv", "read_csv"]

COLUMNS = ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b",
           "sigma_r", "sigma_g", "sigma_b", "flags", "n_pixels", "pose")


def write_csv(path, samples: SampleSet) -> Path:
    """Write ``samples`` as CSV (columns in :data:`COLUMNS`); returns the path."""
    path = Path(path)
    ti, pi_, to, po = (np.degrees(a) for a in samples.angles())
    table = np.column_stack([ti, pi_, to, po, samples.f, samples.sigma,
                             samples.flags, samples.n_pixels, samples.pose])
    try:
        with written_atomically(path, "w", encoding="utf-8", newline="") as fh:
            np.savetxt(fh, table, fmt=["%.17g"] * 10 + ["%d"] * 3, delimiter=",",
                       header=",".join(COLUMNS), comments="")
    except OSError as exc:
        raise DataError(f"{path}: cannot write CSV ({exc.strerror or exc})") from None
    return path


def read_csv(path) -> SampleSet:
    """Read a CSV written by :func:`write_csv` back into a :class:`SampleSet`.

    Raises :class:`DataError` naming the file (and the column or line) when the header or a row is bad.
    """
    path = Path(path)
    try:
        with open(path, encoding="utf-8") as fh:
            header = fh.readline().strip().split(",")
            missing = [c for c in COLUMNS if c not in header]
            if missing:
                raise DataError(f"{path}: CSV header lacks column {missing[0]!r}")
            with warnings.catch_warnings():  # a header without rows is an empty set, said by the caller
                warnings.filterwarnings("ignore", message="loadtxt: input contained no data")
                data = np.loadtxt(fh, delimiter=",", ndmin=2, usecols=[header.index(c) for c in COLUMNS])
    except OSError as exc:
        raise DataError(f"{path}: cannot read CSV ({exc.strerror or exc})") from None
    except ValueError as exc:
        raise DataError(f"{path}: bad CSV row ({str(exc).splitlines()[0]})") from None
    if data.size == 0:
        data = np.zeros((0, len(COLUMNS)))
    _check_integer_columns(path, data)
    t = np.radians(data[:, :4])
    return SampleSet.from_dict(
        {**dict(zip(("wi", "wo"), _dirs(t))), "f": data[:, 4:7], "sigma": data[:, 7:10],
         "flags": data[:, 10].astype(np.int64), "n_pixels": data[:, 11].astype(np.int64),
         "pose": data[:, 12].astype(np.int64)},
        source=str(path),
    )


def _integer_columns():
    """The integer columns (index into COLUMNS) and their ranges: a flag bit mask, pixels averaged, the plan pose
    (−1: none; up to :data:`gonio.store.records.MAX_POSE`, the largest a record holds)."""
    from gonio.store.records import MAX_POSE

    return ((10, 0, 2**31 - 1), (11, 0, 10**9), (12, -1, MAX_POSE))


def _check_integer_columns(path, data) -> None:
    """``flags``, ``n_pixels`` and ``pose`` hold integers within their ranges; else a DataError naming the file,
    the line and the value (``flags`` 1.5 was read as 1, 1e30 as INT64_MIN, a negative pixel count as given)."""
    for col, lo, hi in _integer_columns():
        v = data[:, col]
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(~((v == np.round(v)) & (v >= lo) & (v <= hi)))
        if bad.size:
            k = int(bad[0])
            raise DataError(f"{path}: line {k + 2}: {COLUMNS[col]} = {float(v[k])!r}: must be an integer in [{lo}, {hi}]")


def _dirs(t):
    from gonio.geometry import dirs_from_angles

    return dirs_from_angles(t[:, 0], t[:, 1], t[:, 2], t[:, 3])
