"""BRDF samples binned straight into MERL cells, streaming (image-based acquisition, issue 30): a session of
hundreds of frames adds each frame's pixels and keeps only per-cell sums (about 100 MB for the 1,458,000 cells × RGB),
never the pixels.

Per cell and channel, with each sample's standard uncertainty σ_k and weight w_k = 1/σ_k²:

* the inverse-variance weighted mean ``f̄ = Σ w f / Σ w`` and its propagated uncertainty ``(Σ w)^-½``
  (GUM, JCGM 100:2008, for independent inputs);
* the weighted scatter ``s² = (Σ w f² − f̄² Σ w) / Σ w`` and the Birge ratio ``R_B² = χ²/(n−1)``,
  ``χ² = Σ w (f − f̄)²`` (Birge 1932): when the samples scatter more than their σ say (the cell's BRDF varies
  across it, the normals' errors), the stated σ is scaled by ``max(1, R_B)``, so a cell's σ is never smaller than
  what its own samples show (Particle Data Group's scale factor, Rev. Part. Phys., "Introduction").

Counts are conserved: every sample added to the accumulator is in exactly one cell's count (tests).
"""

from __future__ import annotations

import numpy as np

from gonio.io.merl import N_CELLS, SHAPE, MerlTable
from gonio.io.merl_index import half_diff_index
from gonio.samples import all_channels

__all__ = ["CellAccumulator"]


class CellAccumulator:
    """Running per-cell sums of weighted BRDF samples on the MERL grid (float64)."""

    def __init__(self):
        self.count = np.zeros(N_CELLS, dtype=np.int64)
        self._sw = np.zeros((N_CELLS, 3))
        self._swf = np.zeros((N_CELLS, 3))
        self._swf2 = np.zeros((N_CELLS, 3))
        self.added = 0  #: samples accepted in total
        self.refused = 0  #: samples refused (non-finite value or σ ≤ 0)

    def add(self, theta_h, theta_d, phi_d, f, sigma) -> int:
        """Add samples: angles (n,), values and standard uncertainties (n, 3). Samples whose f or σ is not finite
        or σ ≤ 0 in any channel are refused (counted in :attr:`refused`). Returns how many were added."""
        f = np.asarray(f, dtype=np.float64).reshape(-1, 3)
        s = np.asarray(sigma, dtype=np.float64).reshape(-1, 3)
        ok = all_channels(np.isfinite(f) & np.isfinite(s) & (s > 0))
        self.refused += int((~ok).sum())
        if not ok.any():
            return 0
        ih, idd, ip = half_diff_index(np.asarray(theta_h)[ok], np.asarray(theta_d)[ok], np.asarray(phi_d)[ok])
        cell = ip + 180 * (idd + 90 * ih)
        f, s = f[ok], s[ok]
        w = 1.0 / (s * s)
        self.count += np.bincount(cell, minlength=N_CELLS)
        for c in range(3):
            self._sw[:, c] += np.bincount(cell, w[:, c], minlength=N_CELLS)
            self._swf[:, c] += np.bincount(cell, w[:, c] * f[:, c], minlength=N_CELLS)
            self._swf2[:, c] += np.bincount(cell, w[:, c] * f[:, c] ** 2, minlength=N_CELLS)
        n = int(ok.sum())
        self.added += n
        return n

    def merge(self, other: "CellAccumulator") -> None:
        """Add another accumulator's sums (frames binned apart, e.g. on other workers)."""
        self.count += other.count
        self._sw += other._sw
        self._swf += other._swf
        self._swf2 += other._swf2
        self.added += other.added
        self.refused += other.refused

    def mean_sigma(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mean, σ)`` per cell (N_CELLS, 3); NaN where a cell has no sample (see the module docstring)."""
        has = self.count > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(has[:, None], self._swf / self._sw, np.nan)
            sig = np.where(has[:, None], 1.0 / np.sqrt(self._sw), np.nan)
            chi2 = np.maximum(self._swf2 - mean * self._swf, 0.0)
            dof = np.maximum(self.count - 1, 1)[:, None]
            birge = np.where((self.count > 1)[:, None], np.sqrt(chi2 / dof), 1.0)
        return mean, sig * np.maximum(birge, 1.0)

    def table(self) -> MerlTable:
        """The binned cells as a :class:`MerlTable` (values, σ, count; NaN where no sample)."""
        mean, sig = self.mean_sigma()
        return MerlTable(mean.reshape(SHAPE + (3,)), sigma=sig.reshape(SHAPE + (3,)),
                         count=self.count.reshape(SHAPE))

    @property
    def filled(self) -> int:
        """Cells holding at least one sample."""
        return int(np.count_nonzero(self.count))
