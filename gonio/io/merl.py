"""The MERL isotropic BRDF binary format (Matusik, Pfister, Brand, McMillan, "A Data-Driven Reflectance
Model", SIGGRAPH 2003; layout as in the reference reader ``BRDFRead.cpp`` and docs/architecture.md §3).

Layout
------
Three little-endian int32 dims ``(90, 90, 180)`` for ``(θh, θd, φd)``, then 3 × 1,458,000
little-endian float64: all red, then all green, then all blue. ``value = stored × scale`` with
``scale = (1/1500, 1.15/1500, 1.66/1500)`` for R, G, B. Cell indices::

    iθh = floor(sqrt(θh / (π/2)) · 90)      (the sqrt mapping: dense near the specular peak)
    iθd = floor(θd / (π/2) · 90)
    iφd = floor(φd / π · 180)              φd folded to [0, π) by reciprocity (φd ≡ φd + π)

each clamped to its range; flat index = iφd + 180·(iθd + 90·iθh). Negative stored values mark
cells that were not measured; in memory they are NaN.

Angles are the Rusinkiewicz (1998) half/difference angles as the reference reader computes them
(:mod:`gonio.io.merl_index`: the cell of a direction pair is the one ``BRDFRead.cpp`` reads, bit for
bit); φh is ignored, so a table holds an *isotropic* BRDF.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.errors import DataError
from gonio.io.merl_index import directions_from_angles, half_diff_index, reference_half_diff, reference_index
from gonio.io.outputs import written_atomically
from gonio.samples import SampleSet, all_channels

__all__ = [
    "N_THETA_H",
    "N_THETA_D",
    "N_PHI_D",
    "SHAPE",
    "SCALE",
    "FILE_SIZE",
    "grid_coords",
    "grid_index",
    "flat_index",
    "cell_centres",
    "cell_directions",
    "MerlTable",
    "trilinear",
    "read_merl",
    "write_merl",
]

N_THETA_H, N_THETA_D, N_PHI_D = 90, 90, 180
#: Grid shape ``(θh, θd, φd)``.
SHAPE = (N_THETA_H, N_THETA_D, N_PHI_D)
N_CELLS = N_THETA_H * N_THETA_D * N_PHI_D  # 1,458,000
#: Stored-to-1/sr scale factors of the R, G, B channels (Matusik et al. 2003, BRDFRead.cpp).
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
_HEADER = np.array(SHAPE, dtype="<i4")
#: Size in bytes of a MERL binary: 12-byte header + 3 · 1,458,000 float64.
FILE_SIZE = _HEADER.nbytes + 3 * N_CELLS * 8  # 34,992,012
_CHANNELS = "RGB"


def grid_coords(theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous grid coordinates of half/difference angles (radians): cell ``i`` covers ``[i, i+1)``.

    ``uθh = sqrt(θh / (π/2)) · 90``, ``uθd = θd / (π/2) · 90``, ``uφd = (φd mod π) / π · 180``
    (docs/architecture.md §3; Matusik et al. 2003). Not clamped; φd is folded by reciprocity.
    """
    th = np.asarray(theta_h, dtype=np.float64)
    td = np.asarray(theta_d, dtype=np.float64)
    pd = np.asarray(phi_d, dtype=np.float64)
    u_h = np.sqrt(np.clip(th, 0.0, None) / (np.pi / 2)) * N_THETA_H
    u_d = td / (np.pi / 2) * N_THETA_D
    u_p = np.mod(pd, np.pi) / np.pi * N_PHI_D
    return u_h, u_d, u_p


def grid_index(theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clamped integer cell indices ``(iθh, iθd, iφd)`` of half/difference angles (radians), computed
    exactly as the reference reader computes them (:func:`gonio.io.merl_index.half_diff_index`)."""
    return half_diff_index(theta_h, theta_d, phi_d)


def flat_index(wi, wo) -> np.ndarray:
    """Flat MERL cell index ``iφd + 180·(iθd + 90·iθh)`` of direction pairs (any shape ``(..., 3)``):
    the cell the reference reader ``BRDFRead.cpp`` reads (:func:`gonio.io.merl_index.reference_index`)."""
    i_h, i_d, i_p = reference_index(wi, wo)
    return i_p + N_PHI_D * (i_d + N_THETA_D * i_h)


def cell_centres() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Angles (radians) of the cell centres in index space: 1-D arrays ``θh (90,), θd (90,), φd (180,)``.

    ``θh = ((i + ½)/90)² · π/2`` (inverse of the sqrt mapping), ``θd = (j + ½)/90 · π/2``,
    ``φd = (k + ½)/180 · π``.
    """
    th = ((np.arange(N_THETA_H) + 0.5) / N_THETA_H) ** 2 * (np.pi / 2)
    td = (np.arange(N_THETA_D) + 0.5) / N_THETA_D * (np.pi / 2)
    pd = (np.arange(N_PHI_D) + 0.5) / N_PHI_D * np.pi
    return th, td, pd


def cell_directions(phi_h: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directions of every cell centre at azimuth ``phi_h`` of the half vector.

    Returns ``(wi, wo, above)``: ``wi``, ``wo`` of shape ``(90, 90, 180, 3)`` as
    :func:`gonio.geometry.dirs_from_half_diff` gives them, and ``above`` (90, 90, 180) bool, True where both
    are above the horizon (independent of ``phi_h``: a rotation about z keeps cos θ).

    The grid is separable, so each component is a product of per-axis factors broadcast over the grid (what
    :func:`gonio.geometry.dirs_from_half_diff` computes, without its (90, 90, 180)-sized intermediates): with
    d = (sin θd cos φd, sin θd sin φd, cos θd) and h = (sin θh, 0, cos θh) at φh = 0, wi = R_y(θh) d and
    wo = 2 (wi·h) h − wi with wi·h = cos θd (Rusinkiewicz 1998); then both are turned by φh about z.

    The arrays at φh = 0 (the default, and where every other φh starts from) are a fixed function of the fixed
    grid: they are computed once per process and shared, read-only (``writeable`` False; copy to change them).
    """
    wi0, wo0, above = _cell_directions_at_zero()
    if not phi_h:
        return wi0, wo0, above
    c, s = np.cos(phi_h), np.sin(phi_h)
    out = []
    for v0 in (wi0, wo0):
        v = v0.copy()
        v[..., 0] = c * v0[..., 0] - s * v0[..., 1]
        v[..., 1] = s * v0[..., 0] + c * v0[..., 1]
        out.append(v)
    return out[0], out[1], above


@functools.lru_cache(maxsize=1)
def _cell_directions_at_zero() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cell_directions` at φh = 0, computed once (read-only arrays: 2 × 35 MB and 1.5 MB)."""
    th, td, pd = cell_centres()
    ct, st = np.cos(th)[:, None, None], np.sin(th)[:, None, None]
    cd, sd = np.cos(td)[None, :, None], np.sin(td)[None, :, None]
    dx, dy = sd * np.cos(pd)[None, None, :], sd * np.sin(pd)[None, None, :]
    wi = np.empty(SHAPE + (3,))
    wo = np.empty(SHAPE + (3,))
    # each full-size product and sum straight into its component (out=): no (90, 90, 180) temporaries, which
    # halved the page faults (4,355 -> 2,075) of this first use in a process; the same operations in the same order
    wi_x, wi_z = wi[..., 0], wi[..., 2]
    np.multiply(ct, dx, out=wi_x)
    wi_x += st * cd  # wi_x = ct·dx + st·cd
    wi[..., 1] = dy
    np.multiply(st, dx, out=wi_z)
    np.subtract(ct * cd, wi_z, out=wi_z)  # wi_z = ct·cd − st·dx
    np.subtract(2.0 * cd * st, wi_x, out=wo[..., 0])
    np.negative(dy, out=wo[..., 1])
    np.subtract(2.0 * cd * ct, wi_z, out=wo[..., 2])
    above = wi_z > 0.0
    above &= wo[..., 2] > 0.0
    for a in (wi, wo, above):
        a.flags.writeable = False
    return wi, wo, above


def _as_grid(name: str, a, trailing: tuple[int, ...], dtype) -> np.ndarray | None:
    if a is None:
        return None
    arr = np.asarray(a, dtype=dtype)
    want = SHAPE + trailing
    if arr.shape != want:
        raise DataError(f"MERL table: {name} has shape {arr.shape}, expected {want}")
    return arr


@dataclass(frozen=True)
class MerlTable:
    """An isotropic BRDF tabulated on the MERL 90 × 90 × 180 half/difference grid.

    Attributes
    ----------
    values : ndarray (90, 90, 180, 3) float64
        BRDF in 1/sr (not × cos θ), axes ``(θh, θd, φd, RGB)``; NaN = not measured.
    sigma : ndarray (90, 90, 180, 3) or None
        Standard uncertainty of ``values`` (tabulation fills it; a MERL file does not hold it).
    count : ndarray (90, 90, 180) int or None
        Samples averaged into each cell; 0 for holes (filled by interpolation or not measured).
    """

    values: np.ndarray
    sigma: np.ndarray | None = field(default=None)
    count: np.ndarray | None = field(default=None)

    def __post_init__(self):
        object.__setattr__(self, "values", _as_grid("values", self.values, (3,), np.float64))
        object.__setattr__(self, "sigma", _as_grid("sigma", self.sigma, (3,), np.float64))
        object.__setattr__(self, "count", _as_grid("count", self.count, (), np.int64))

    @classmethod
    def empty(cls) -> "MerlTable":
        """A table with no measured cell."""
        return cls(np.full(SHAPE + (3,), np.nan))

    @classmethod
    def from_brdf(cls, brdf, phi_h: float = 0.0) -> "MerlTable":
        """``brdf.eval`` at every cell centre above the horizon (:func:`cell_directions` at ``phi_h``;
        NaN below it, as a MERL file marks those cells): a model or an isotropic material tabulated."""
        wi, wo, above = cell_directions(phi_h)
        values = np.full(SHAPE + (3,), np.nan)
        keep = np.flatnonzero(above)
        values.reshape(-1, 3)[keep] = brdf.eval(_rows(wi, keep), _rows(wo, keep))
        return cls(values)

    @property
    def measured(self) -> np.ndarray:
        """(90, 90, 180) bool: cells with a value in every channel."""
        return all_channels(np.isfinite(self.values))

    def lookup(self, wi, wo, method: str = "trilinear") -> np.ndarray:
        """BRDF (1/sr, RGB) at direction pairs ``wi``, ``wo`` of shape ``(..., 3)``.

        ``method="nearest"``: the value of the cell the MERL reference reader (``BRDFRead.cpp``,
        ``lookup_brdf_val``) reads for the pair, bit for bit, boundaries included
        (:mod:`gonio.io.merl_index`; e.g. an in-plane pair with φd = π is cell 179, with φd = 0 cell 0).
        ``method="trilinear"`` (default; benchmarks/report/REPORT.md "MERL lookup": ~16× less error than
        nearest for ~2.6× the time): trilinear interpolation between the 8 surrounding cell centres in
        index space ``(uθh − ½, uθd − ½, uφd − ½)`` (see :func:`grid_coords`), clamped at the θh/θd
        edges and periodic in φd (reciprocity: cell 179 neighbours cell 0). Not-measured corners
        are left out and the remaining weights renormalized.

        Not-measured cells give NaN; below the horizon the value is 0 (docs/architecture.md §3).
        """
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        wi, wo = np.broadcast_arrays(wi, wo)
        if method not in ("nearest", "trilinear"):
            raise ValueError(f"MerlTable.lookup: method = {method!r}: must be 'nearest' or 'trilinear'")
        if method == "trilinear":
            return trilinear(self.values, wi, wo)
        th, _, td, pd = reference_half_diff(wi, wo)
        i_h, i_d, i_p = half_diff_index(th, td, pd)
        above = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
        return np.where(above[..., None], self.values[i_h, i_d, i_p], 0.0)

    def lookup_angles(self, theta_i, phi_i, theta_o, phi_o, method: str = "trilinear") -> np.ndarray:
        """:meth:`lookup` at angles (radians), the directions built as the reference reader builds
        them, so ``method="nearest"`` returns exactly what ``lookup_brdf_val(θi, φi, θo, φo)`` returns."""
        wi, wo = directions_from_angles(theta_i, phi_i, theta_o, phi_o)
        return self.lookup(wi, wo, method=method)

    def to_samples(self, phi_h: float = 0.0, sigma_rel: float = 0.01) -> SampleSet:
        """The measured cells above the horizon as a :class:`SampleSet` at the cell-centre directions.

        ``sigma`` is the table's uncertainty where it has one, else ``sigma_rel · |f|`` (floored at
        ``1e-6 × max |f|``) so that fits weight cells by relative error.
        """
        wi, wo, above = cell_directions(phi_h)
        keep = np.flatnonzero(above & self.measured)  # rows taken by index: ~5x faster than a boolean mask here
        f = _rows(self.values, keep)
        sigma = _rows(self.sigma, keep) if self.sigma is not None else None
        if sigma is None or not np.all(np.isfinite(sigma)):
            floor = 1e-6 * (np.max(np.abs(f)) if f.size else 1.0) or 1e-12
            sigma = np.maximum(sigma_rel * np.abs(f), floor)
        n = _rows(self.count, keep) if self.count is not None else None
        return SampleSet(_rows(wi, keep), _rows(wo, keep), f, sigma, n_pixels=n)


def trilinear(values: np.ndarray, wi, wo) -> np.ndarray:
    """:meth:`MerlTable.lookup`'s ``"trilinear"`` on a grid ``values`` of shape ``(90, 90, 180, C)`` (any number of
    channels C, e.g. 1 for a single table of means), at broadcast direction pairs ``wi``, ``wo`` (float64); the
    method is in that docstring."""
    th, _, td, pd = reference_half_diff(wi, wo)
    # wi == wo: the reference's acos(wi · h) of a dot product rounded above 1 is NaN; θd is 0 there
    td = np.where(np.isnan(td) & np.isfinite(th), 0.0, td)
    out = _trilinear(values, *grid_coords(th, td, pd))
    above = (wi[..., 2] > 0.0) & (wo[..., 2] > 0.0)
    return np.where(above[..., None], out, 0.0)


def _trilinear(values: np.ndarray, u_h, u_d, u_p) -> np.ndarray:
    def edge(u, n):
        x = np.clip(u - 0.5, 0.0, n - 1)
        i0 = np.minimum(np.floor(x).astype(np.intp), n - 2)
        return i0, i0 + 1, x - i0

    h0, h1, th = edge(u_h, N_THETA_H)
    d0, d1, td = edge(u_d, N_THETA_D)
    x = u_p - 0.5
    f = np.floor(x)
    tp = x - f
    p0 = np.mod(f, N_PHI_D).astype(np.intp)
    p1 = np.mod(p0 + 1, N_PHI_D)
    acc = np.zeros(np.shape(u_h) + values.shape[3:])
    wsum = np.zeros(np.shape(u_h) + values.shape[3:])
    read = _cell_reader(values)
    for ih, wh in ((h0, 1 - th), (h1, th)):
        for id_, wd in ((d0, 1 - td), (d1, td)):
            whd = wh * wd  # the first product of wh · wd · wp, once for both φd corners
            row = (ih * N_THETA_D + id_) * N_PHI_D
            for ip, wp in ((p0, 1 - tp), (p1, tp)):
                v = values[ih, id_, ip] if read is None else read(row + ip)
                ok = np.isfinite(v)
                w = (whd * wp)[..., None] * ok
                acc += w * np.where(ok, v, 0.0)
                wsum += w
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(wsum > 1e-12, acc / np.where(wsum > 0, wsum, 1.0), np.nan)


def _cell_reader(values: np.ndarray):
    """``read(flat)``: ``values[ih, id, ip]`` of a grid ``values`` (90, 90, 180, C) at flat cell indices
    ``flat = (ih · 90 + id) · 180 + ip``, one ``np.take`` on a flat view (2.3x faster than indexing with three index
    arrays: 8 corners of 2e5 lookups 117 -> 48 ms) — for a C-ordered grid, or one laid out channels first (as
    :func:`read_merl` returns the file's); the same values. None for another layout (index it as the grid)."""
    C = values.shape[-1]
    if values.flags.c_contiguous:
        rows = values.reshape(-1, C)
        return lambda flat: np.take(rows, flat, axis=0)
    channels = np.moveaxis(values, -1, 0)
    if channels.flags.c_contiguous:
        planes = channels.reshape(C, -1)
        return lambda flat: np.moveaxis(np.take(planes, flat, axis=1), 0, -1)
    return None


def _rows(a: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """``a[mask]`` for a grid-shaped ``a`` ((90, 90, 180) or (90, 90, 180, k)) and ``flat = np.flatnonzero(mask)``:
    the same rows, taken by index."""
    return np.take(a.reshape((-1,) + a.shape[3:]), flat, axis=0)


def _read_error(path, what: str) -> DataError:
    return DataError(f"{path}: not a MERL BRDF binary: {what}")


def read_merl(path) -> MerlTable:
    """Read a MERL binary (layout in the module docstring).

    Raises
    ------
    DataError
        The file is missing or unreadable, has the wrong header dims, the wrong size (truncated or
        trailing bytes), or holds NaN/inf; the message names the file and the fault.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            raw = fh.read(12)
            if len(raw) < 12:
                raise _read_error(path, f"truncated header ({size} bytes, expected {FILE_SIZE})")
            header = np.frombuffer(raw, dtype="<i4")
            if tuple(header) != SHAPE:
                from gonio.io.sniff import describe

                raise _read_error(path, f"it looks like {describe(path)} (header dims "
                                        f"{tuple(int(x) for x in header)}, expected {SHAPE})")
            if size != FILE_SIZE:
                what = "truncated" if size < FILE_SIZE else "trailing data"
                raise _read_error(path, f"{what}: {size} bytes, expected {FILE_SIZE}")
            stored = np.fromfile(fh, dtype="<f8", count=3 * N_CELLS)
    except OSError as exc:
        raise DataError(f"{path}: cannot read MERL file ({exc.strerror or exc})") from None
    if stored.size != 3 * N_CELLS:  # the file shrank between stat and read
        raise _read_error(path, f"truncated: {12 + stored.size * 8} bytes, expected {FILE_SIZE}")
    stored = stored.reshape((3,) + SHAPE)
    if not np.isfinite(stored).all():
        bad = ~np.isfinite(stored)
        c, i, j, k = (int(x[0]) for x in np.nonzero(bad))
        raise _read_error(
            path, f"{int(bad.sum())} stored values are NaN or inf (first: channel {_CHANNELS[c]}, "
                  f"cell (θh {i}, θd {j}, φd {k}))")
    stored *= SCALE[:, None, None, None]  # in the array read (the values stored × scale, no copy)
    values = np.moveaxis(stored, 0, -1)
    values[values < 0] = np.nan
    return MerlTable(values)


def write_merl(path, table: MerlTable) -> Path:
    """Write ``table`` as a MERL binary; returns the path.

    Not-measured (NaN) values are stored as −1. Measured values below 0 (noise around zero) are
    stored as 0, since a negative stored value means "not measured". The file is written to a
    temporary name and renamed, so an existing file is never left half-written.

    Raises
    ------
    DataError
        ``table`` holds ±inf (a MERL file cannot), or the file cannot be written.
    """
    path = Path(path)
    values = table.values
    if np.isinf(values).any():
        raise DataError(f"{path}: cannot write MERL table: {int(np.isinf(values).sum())} values are infinite")
    # channel by channel into the file's layout (all R, all G, all B), in place: no copies of the 35 MB table
    stored = np.empty((3,) + SHAPE, dtype="<f8")
    for c in range(3):
        np.divide(values[..., c], SCALE[c], out=stored[c])
        np.maximum(stored[c], 0.0, out=stored[c])  # NaN stays NaN
        stored[c][np.isnan(values[..., c])] = -1.0
    try:
        with written_atomically(path, "wb") as fh:
            fh.write(_HEADER.tobytes())
            fh.write(memoryview(stored).cast("B"))
    except OSError as exc:
        raise DataError(f"{path}: cannot write MERL file ({exc.strerror or exc})") from None
    return path
