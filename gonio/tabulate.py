"""Scattered BRDF samples → the MERL 90 × 90 × 180 half/difference grid (:mod:`gonio.io.merl`).

Steps (all vectorized with ``np.bincount``; no Python loop over samples):

1. Keep unflagged samples above the horizon with finite values and uncertainties.
2. Map each to its cell by the Rusinkiewicz angles (:func:`gonio.geometry.half_diff_from_dirs`),
   folding φd by reciprocity (f(wi, wo) = f(wo, wi) ⇔ φd ≡ φd + π) and ignoring φh (isotropy).
3. Per cell, the inverse-variance weighted mean ``f̄ = Σ wₖ fₖ / Σ wₖ`` with ``wₖ = 1/σₖ²``, its
   standard uncertainty ``σ̄ = (Σ wₖ)^(-1/2)`` and the sample count (e.g. Taylor, *An Introduction
   to Error Analysis*, 2nd ed., §7.2; Bevington & Robinson, *Data Reduction and Error Analysis*, eq. 4.19).
4. Holes (cells above the horizon without samples) within ``fill_deg`` of measured cells are filled by
   inverse-distance-weighted scattered interpolation (Shepard, "A two-dimensional interpolation
   function for irregularly-spaced data", ACM National Conference 1968) over the nearest measured
   cells; the rest stay "not measured" (NaN).

The angular distance between two cells is the RMS of the angles between their ``wi`` and between their
``wo`` at the cell centres (φh = 0), measured as the chord ``|(wi, wo) − (wi', wo')| / √2``; the
reciprocal twin ``(wo, wi)`` of every measured cell is included, so cells across the φd seam are
neighbours.

Anisotropy: a MERL table cannot hold a BRDF that depends on φh. :func:`check_isotropy` bins samples of
each cell by φh sector and compares the sector means; if too many cells differ by more than
``isotropy_tol`` (and beyond 3 σ), :func:`tabulate` refuses with a :class:`DataError` that points to the
4-D exports (``gonio export --format npz|csv`` keep every sample), unless ``force_isotropic``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.errors import DataError
from gonio.geometry import half_diff_from_dirs
from gonio.io.merl import N_CELLS, N_PHI_D, N_THETA_D, SHAPE, MerlTable, cell_directions, trilinear
from gonio.io.merl_index import reference_index
from gonio.samples import SampleSet, all_channels

__all__ = ["IsotropyCheck", "Tabulation", "check_isotropy", "tabulate", "DEFAULT_FILL_DEG"]

#: Default maximum angular distance (degrees) over which holes are filled by interpolation.
DEFAULT_FILL_DEG = 2.0
_K_NEIGHBOURS = 8
_N_SECTORS = 8
_MAX_FRACTION = 0.1
_MIN_CELLS = 10


@dataclass(frozen=True)
class IsotropyCheck:
    """Outcome of :func:`check_isotropy`.

    Attributes
    ----------
    anisotropic : bool
        The data depend on φh beyond the tolerance in more than ``max_fraction`` of the tested cells.
    n_cells : int
        Cells with samples in at least two φh sectors (the only ones that can be tested).
    fraction : float
        Fraction of tested cells whose φh-sector means differ significantly by more than ``tol``.
    median_spread : float
        Median over tested cells of (max − min of sector means) / |cell mean|.
    tol, max_fraction : float
        The thresholds used.
    """

    anisotropic: bool
    n_cells: int
    fraction: float
    median_spread: float
    tol: float
    max_fraction: float

    def describe(self) -> str:
        if self.n_cells == 0:
            return "isotropy not testable (no cell has samples at two φh sectors)"
        return (f"φh dependence: {self.fraction:.0%} of {self.n_cells} testable cells differ by more than "
                f"{self.tol:.0%} between φh sectors (median spread {self.median_spread:.1%}; limit "
                f"{self.max_fraction:.0%} of cells)")


def _usable(samples: SampleSet, include_flagged: bool) -> tuple[np.ndarray, int, int]:
    """Mask of samples to tabulate; also the numbers excluded by flags and as invalid."""
    flagged = samples.flags != 0
    valid = (
        (samples.wi[:, 2] > 0) & (samples.wo[:, 2] > 0)
        & all_channels(np.isfinite(samples.f)) & all_channels(np.isfinite(samples.sigma))
        & all_channels(samples.sigma >= 0)
    )
    keep = valid if include_flagged else valid & ~flagged
    n_flagged = 0 if include_flagged else int(np.sum(flagged & valid))
    return keep, n_flagged, int(np.sum(~valid))


def _cells(cell: np.ndarray, count: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The flat indices of the cells that hold samples (sorted) and each sample's slot among them: per-cell sums
    are ``np.bincount(slot, x)`` — the same sums, in the same sample order, as ``np.bincount(cell, x,
    minlength=N_CELLS)[has]`` without its 1.46 M-long arrays. ``count``: ``np.bincount(cell, minlength=N_CELLS)``
    if known."""
    if count is None:
        count = np.bincount(cell, minlength=N_CELLS)
    has = np.flatnonzero(count)
    slot_of = np.empty(N_CELLS, dtype=np.intp)
    slot_of[has] = np.arange(has.size)
    return has, slot_of[cell]


def _weights(f: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Inverse-variance weights 1/σ², with σ floored at 1e-12 × max|f| (so σ = 0 data weigh equally)."""
    floor = 1e-12 * float(np.max(np.abs(f))) if f.size else 0.0
    floor = floor if floor > 0 else 1e-300
    return 1.0 / np.maximum(sigma, floor) ** 2


def check_isotropy(samples: SampleSet, *, tol: float = 0.1, max_fraction: float = _MAX_FRACTION,
                   min_cells: int = _MIN_CELLS, include_flagged: bool = False) -> IsotropyCheck:
    """Test whether the samples depend on φh (the azimuth of the half vector), cell by cell.

    Each sample's channel-averaged BRDF is divided by the isotropic estimate at its own position (the
    table of cell means, interpolated trilinearly), which removes most of the variation across a cell;
    each cell's ratios are split into 8 φh sectors of 45° and averaged (inverse-variance weights) per
    sector. A tested cell (≥ 2 sectors) counts as anisotropic
    when ``max − min`` of its sector means exceeds both ``tol × |cell mean|`` and 3 × the combined
    uncertainty of those two means. The data are anisotropic when at least ``min_cells`` cells were
    tested and more than ``max_fraction`` of them count as anisotropic.

    This is a heuristic, calibrated on 2·10⁵ random direction pairs: isotropic models give fractions
    ≤ 0.08 (GGX with α = 0.05, the sharpest lobe tried; 0.002 for α = 0.2), anisotropic Ward
    (αx, αy = 0.2, 0.3) gives 0.14 and stronger anisotropy more.
    """
    keep, _, _ = _usable(samples, include_flagged)
    s = samples.subset(keep)
    if len(s) < 2:
        return IsotropyCheck(False, 0, 0.0, 0.0, tol, max_fraction)
    th, ph, td, pd = half_diff_from_dirs(s.wi, s.wo)
    i_h, i_d, i_p = reference_index(s.wi, s.wo)  # the cell the MERL reference reader reads there
    return _check_isotropy(s, i_p + N_PHI_D * (i_d + N_THETA_D * i_h), ph, tol, max_fraction, min_cells)


def _check_isotropy(s: SampleSet, cell: np.ndarray, ph: np.ndarray, tol: float, max_fraction: float,
                    min_cells: int) -> IsotropyCheck:
    """:func:`check_isotropy` on usable samples whose cells and φh are already known."""
    empty = IsotropyCheck(False, 0, 0.0, 0.0, tol, max_fraction)
    sector = np.minimum((ph / (2 * np.pi) * _N_SECTORS).astype(np.intp), _N_SECTORS - 1)
    key = cell * _N_SECTORS + sector
    # the (cell, sector) groups present, sorted: np.unique of the samples' keys, not a mask over all N_CELLS x 8
    # groups (12 M) and its cumulative sum, which cost more than everything else here on a small sample set
    sectors_per_cell = np.bincount(np.unique(key) // _N_SECTORS, minlength=N_CELLS)
    sel = sectors_per_cell[cell] >= 2
    if not sel.any():
        return empty
    y = s.f.mean(axis=1)
    sy = np.sqrt(np.sum(s.sigma**2, axis=1)) / 3.0
    # divide out the variation across each cell: the isotropic table of cell means, interpolated
    # trilinearly at every sample's own position (φh ignored), is what an isotropic BRDF would give.
    w0 = _weights(y, sy)
    has, slot = _cells(cell)
    mean = np.full(N_CELLS, np.nan)
    mean[has] = np.bincount(slot, w0 * y, minlength=has.size) / np.bincount(slot, w0, minlength=has.size)
    iso = trilinear(mean.reshape(SHAPE + (1,)), np.asarray(s.wi[sel], dtype=np.float64),
                    np.asarray(s.wo[sel], dtype=np.float64))[:, 0]
    scale = np.where(np.abs(iso) > 1e-300, iso, 1.0)
    y, sy = y[sel] / scale, sy[sel] / np.abs(scale)
    w = _weights(y, sy)
    keys, inv = np.unique(key[sel], return_inverse=True)  # sorted (cell, sector) groups; each sample's group
    wg = np.bincount(inv, w)
    mg = np.bincount(inv, w * y) / wg
    sg = 1.0 / np.sqrt(wg)
    cg = keys // _N_SECTORS
    order = np.lexsort((mg, cg))
    cells, start, n_sec = np.unique(cg[order], return_index=True, return_counts=True)
    tested = n_sec >= 2
    lo = order[start[tested]]
    hi = order[start[tested] + n_sec[tested] - 1]
    # cell mean over all its sectors
    cell_w = np.bincount(np.searchsorted(cells, cg), wg)[tested]
    cell_m = np.bincount(np.searchsorted(cells, cg), wg * mg)[tested] / cell_w
    spread = mg[hi] - mg[lo]
    rel = spread / np.maximum(np.abs(cell_m), 1e-300)
    aniso = (rel > tol) & (spread > 3.0 * np.hypot(sg[hi], sg[lo]))
    n = int(tested.sum())
    fraction = float(aniso.mean())
    return IsotropyCheck(n >= min_cells and fraction > max_fraction, n, fraction,
                         float(np.median(rel)), tol, max_fraction)


@dataclass(frozen=True)
class Tabulation:
    """A tabulated table and how it was made.

    Attributes
    ----------
    table : MerlTable
        Values, uncertainties and per-cell sample counts (0 for filled and for missing cells).
    n_used, n_flagged, n_invalid : int
        Samples averaged into cells; excluded by a quality flag; dropped as invalid (below the
        horizon, non-finite value or uncertainty).
    n_measured, n_filled, n_missing : int
        Cells with samples; holes filled by interpolation; cells above the horizon left not measured.
    fill_deg : float
        The interpolation distance limit used (degrees).
    isotropy : IsotropyCheck
    """

    table: MerlTable
    n_used: int
    n_flagged: int
    n_invalid: int
    n_measured: int
    n_filled: int
    n_missing: int
    fill_deg: float
    isotropy: IsotropyCheck

    def summary(self) -> str:
        """Multi-line human-readable report."""
        return "\n".join([
            f"samples: {self.n_used} tabulated, {self.n_flagged} flagged (excluded), {self.n_invalid} invalid",
            f"cells: {self.n_measured} measured, {self.n_filled} filled within {self.fill_deg:g} deg, "
            f"{self.n_missing} above the horizon not measured (of {N_CELLS})",
            self.isotropy.describe(),
        ])


def _fill_holes(values, sigma, measured, above, fill_deg, wi, wo):
    """Shepard (p = 2) interpolation of holes from measured cells within ``fill_deg``; in place."""
    holes = above & ~measured
    if fill_deg <= 0 or not measured.any() or not holes.any():
        return np.zeros(SHAPE, dtype=bool)
    from scipy.spatial import cKDTree

    wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
    r2 = np.sqrt(2.0)
    m_idx = np.flatnonzero(measured)
    # the embedding (wi, wo)/√2 and its reciprocal twin (wo, wi)/√2, of the rows needed only (measured cells, holes
    # asked about): the same values as the whole grid's embedding indexed, without its two 70 MB arrays
    pts = np.concatenate([np.concatenate([wi[m_idx], wo[m_idx]], axis=-1) / r2,
                          np.concatenate([wo[m_idx], wi[m_idx]], axis=-1) / r2])
    src = np.concatenate([m_idx, m_idx])
    tree = cKDTree(pts)
    bound = 2.0 * np.sin(np.radians(fill_deg) / 2.0)
    h_idx = np.flatnonzero(holes & _near_rows(measured, bound)[..., None])
    filled = np.zeros(N_CELLS, dtype=bool)
    k = min(_K_NEIGHBOURS, len(pts))
    v_flat, s_flat = values.reshape(-1, 3), sigma.reshape(-1, 3)
    # one bounded query per hole (a hole with no measured cell within the bound gets only infinite distances:
    # it stays a hole), in chunks that bound the memory of the k neighbours' values
    for chunk in np.array_split(h_idx, max(1, h_idx.size // 200_000)):
        d, j = tree.query(np.concatenate([wi[chunk], wo[chunk]], axis=-1) / r2, k=k, distance_upper_bound=bound)
        d, j = d.reshape(len(chunk), k), j.reshape(len(chunk), k)
        near = np.isfinite(d[:, 0])  # the nearest first
        chunk, d, j = chunk[near], d[near], j[near]
        if chunk.size == 0:
            continue
        ok = np.isfinite(d)
        w = np.where(ok, 1.0 / np.maximum(np.where(ok, d, 1.0), 1e-12) ** 2, 0.0)
        cells = src[np.where(ok, j, 0)]
        # sums over the k neighbours, one neighbour at a time in order (whole columns: no (holes, k, 3) temporaries);
        # each neighbour's values gathered once for both sums
        wsum = w.sum(axis=1)[:, None]
        vk = [v_flat[cells[:, i]] for i in range(k)]
        est = sum(w[:, i, None] * vk[i] for i in range(k)) / wsum
        # uncertainty: the neighbours' own uncertainty plus their scatter about the estimate
        var = sum(w[:, i, None] * (s_flat[cells[:, i]] ** 2 + (vk[i] - est) ** 2) for i in range(k)) / wsum
        v_flat[chunk] = est
        s_flat[chunk] = np.sqrt(var)
        filled[chunk] = True
    return filled.reshape(SHAPE)


def _near_rows(measured: np.ndarray, bound: float) -> np.ndarray:
    """(θh, θd) rows of the grid (90, 90) that can hold a cell within chord distance ``bound`` of a measured cell
    in :func:`_fill_holes`'s embedding e = (wi, wo)/√2 (its twins included): a necessary condition, so the k-d tree
    is asked only about holes that may have a neighbour (a sparse session's table is mostly far from any).

    For |e − e'| < b, |Δwi| + |Δwo| < 2b, and both wi·wo = cos 2θd and (wi + wo)_z = 2 cos θd cos θh (at φh = 0;
    Rusinkiewicz 1998) change by at most |Δwi| + |Δwo| (unit vectors): so |Δ cos 2θd| < 2b and
    |Δ(cos θd cos θh)| < b, which the rows' centres are tested for (Chebyshev distance, with a margin for rounding)."""
    from scipy.spatial import cKDTree

    from gonio.io.merl import cell_centres

    th, td, _ = cell_centres()
    rows = np.stack(np.broadcast_arrays(np.cos(2.0 * td)[None, :] / 2.0, np.cos(td)[None, :] * np.cos(th)[:, None]), -1)
    have = measured.any(axis=-1)
    d, _ = cKDTree(rows[have]).query(rows.reshape(-1, 2), p=np.inf, distance_upper_bound=bound * (1 + 1e-6) + 1e-12)
    return np.isfinite(d).reshape(have.shape)


def tabulate(samples: SampleSet, *, fill_deg: float = DEFAULT_FILL_DEG, include_flagged: bool = False,
             isotropy_tol: float = 0.1, force_isotropic: bool = False, source: str = "samples") -> Tabulation:
    """Tabulate scattered samples on the MERL grid (method in the module docstring).

    Parameters
    ----------
    samples : SampleSet
        BRDF samples in 1/sr (not × cos θ) with standard uncertainties.
    fill_deg : float
        Fill holes by interpolation only within this angular distance (degrees) of measured cells;
        0 disables filling.
    include_flagged : bool
        Also use samples with quality flags (excluded by default).
    isotropy_tol, force_isotropic
        See :func:`check_isotropy`; with ``force_isotropic`` the φh dependence is averaged out.
    source : str
        Named in error messages (e.g. the session directory).

    Raises
    ------
    DataError
        No usable sample, or the samples are anisotropic (and not ``force_isotropic``).
    """
    if not np.isfinite(fill_deg) or fill_deg < 0:
        raise DataError(f"{source}: fill distance = {fill_deg!r} deg: must be finite and >= 0")
    keep, n_flagged, n_invalid = _usable(samples, include_flagged)
    s = samples.subset(keep)
    if len(s) == 0:
        raise DataError(f"{source}: no usable samples to tabulate ({n_flagged} flagged, {n_invalid} invalid)")
    th, ph, td, pd = half_diff_from_dirs(s.wi, s.wo)
    i_h, i_d, i_p = reference_index(s.wi, s.wo)  # the cell the MERL reference reader reads there
    cell = i_p + N_PHI_D * (i_d + N_THETA_D * i_h)
    iso = _check_isotropy(s, cell, ph, isotropy_tol, _MAX_FRACTION, _MIN_CELLS)
    if iso.anisotropic and not force_isotropic:
        raise DataError(
            f"{source}: the samples are anisotropic ({iso.describe()}); a MERL table holds isotropic BRDFs "
            "only. Export the full 4-D samples with --format npz or csv, or pass --force-isotropic to "
            "average over the half-vector azimuth")
    w = _weights(s.f, s.sigma)
    count = np.bincount(cell, minlength=N_CELLS)
    values = np.full((N_CELLS, 3), np.nan)
    sigma = np.full((N_CELLS, 3), np.nan)
    has, slot = _cells(cell, count)
    for c in range(3):
        wsum = np.bincount(slot, w[:, c], minlength=has.size)
        values[has, c] = np.bincount(slot, w[:, c] * s.f[:, c], minlength=has.size) / wsum
        sigma[has, c] = 1.0 / np.sqrt(wsum)
    values, sigma = values.reshape(SHAPE + (3,)), sigma.reshape(SHAPE + (3,))
    measured = (count > 0).reshape(SHAPE)
    wi, wo, above = cell_directions(0.0)
    filled = _fill_holes(values, sigma, measured, above, fill_deg, wi, wo)
    table = MerlTable(values, sigma, count.reshape(SHAPE))
    return Tabulation(
        table=table, n_used=len(s), n_flagged=n_flagged, n_invalid=n_invalid,
        n_measured=int(measured.sum()), n_filled=int(filled.sum()),
        n_missing=int(np.sum(above & ~measured & ~filled)), fill_deg=float(fill_deg), isotropy=iso,
    )
