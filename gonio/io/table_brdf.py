"""A MERL-grid table that evaluates like a model: what the simulated rig renders a measured material with.

:class:`TableBRDF` wraps a :class:`gonio.io.merl.MerlTable` and answers ``eval(wi, wo)`` (1/sr, RGB) by
**trilinear interpolation in the Rusinkiewicz (θh, θd, φd) parametrisation** (Rusinkiewicz 1998), in the
MERL grid's index space — ``uθh = sqrt(θh / (π/2)) · 90``, ``uθd = θd / (π/2) · 90``,
``uφd = (φd mod π) / π · 180`` (Matusik et al. 2003) — between the 8 surrounding cell centres, clamped at
the θh/θd edges and periodic in φd (:meth:`gonio.io.merl.MerlTable.lookup`, ``method="trilinear"``).
The interpolation is continuous across cells, so a rendered highlight does not show the grid's steps
that the reference reader's nearest-cell lookup would.

Cells a table does not hold (stored negative in a MERL file, NaN in memory: not measured, or below the
horizon) would make a rendered pixel NaN. They are **filled** once, when the table is wrapped, with the
value of the nearest held cell in index space (Euclidean distance transform, ``scipy.ndimage
.distance_transform_edt``; Maurer, Qi & Raghavan 2003); :meth:`TableBRDF.fill_note` says in one line how
many cells above the horizon were filled. A table with no value at all is refused.
"""

from __future__ import annotations

import numpy as np

from gonio.errors import DataError
from gonio.geometry import half_diff_from_dirs
from gonio.io.merl import N_PHI_D, N_THETA_D, N_THETA_H, MerlTable, cell_centres, grid_coords

__all__ = ["TableBRDF", "above_horizon_cells"]


def above_horizon_cells() -> np.ndarray:
    """(90, 90, 180) bool: cells whose centre pair has both directions above the horizon.

    With the half vector at θh and the difference vector d at (θd, φd) (Rusinkiewicz 1998:
    wi = R_z(φh) R_y(θh) d, wo = 2 (wi·h) h − wi), the heights are
    ``wi_z = cos θh cos θd − sin θh sin θd cos φd`` and ``wo_z = cos θh cos θd + sin θh sin θd cos φd``;
    both are positive iff ``cos θh cos θd > sin θh sin θd |cos φd|`` (independent of φh).
    """
    th, td, pd = cell_centres()
    a = np.cos(th)[:, None, None] * np.cos(td)[None, :, None]
    b = np.sin(th)[:, None, None] * np.sin(td)[None, :, None] * np.abs(np.cos(pd))[None, None, :]
    return a > b


class TableBRDF:
    """An evaluable BRDF from a MERL-grid table, holes filled (module docstring).

    Parameters
    ----------
    table : MerlTable
        The table (NaN = not held).
    source : str
        Named in messages (the file it came from).

    Attributes
    ----------
    table : MerlTable
        The filled table that :meth:`eval` interpolates (no NaN).
    n_filled : int
        Cells above the horizon that the source did not hold and that were filled.
    n_above : int
        Cells above the horizon.
    """

    def __init__(self, table: MerlTable, source: str = "table"):
        from scipy import ndimage

        self.source = source
        values = table.values
        held = np.all(np.isfinite(values), axis=-1)
        if not held.any():
            raise DataError(f"{source}: the table holds no value (every cell not measured)")
        above = above_horizon_cells()
        self.n_above = int(above.sum())
        self.n_filled = int(np.sum(above & ~held))
        if not held.all():
            idx = ndimage.distance_transform_edt(~held, return_distances=False, return_indices=True)
            values = values[idx[0], idx[1], idx[2]]
        self.table = MerlTable(np.maximum(values, 0.0))  # a negative measured value is noise about 0
        self._flat = self.table.values.reshape(-1, 3)

    def eval(self, wi, wo) -> np.ndarray:
        """BRDF (1/sr, RGB) at direction pairs of shape ``(..., 3)``: trilinear interpolation in
        (θh, θd, φd) index space (module docstring; the weights of
        :meth:`gonio.io.merl.MerlTable.lookup`'s ``"trilinear"``, on a table without holes, so the 8 corners
        are gathered from one flat array); 0 below the horizon, never NaN."""
        wi, wo = np.broadcast_arrays(np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64))
        shape = wi.shape[:-1]
        wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
        th, _, td, pd = half_diff_from_dirs(wi, wo)
        u_h, u_d, u_p = grid_coords(th, np.nan_to_num(td), pd)

        def edge(u, n):  # clamped at the θh / θd ends of the grid
            x = np.clip(u - 0.5, 0.0, n - 1)
            i0 = np.minimum(x.astype(np.intp), n - 2)
            return i0, x - i0

        h0, fh = edge(u_h, N_THETA_H)
        d0, fd = edge(u_d, N_THETA_D)
        x = u_p - 0.5
        fl = np.floor(x)
        fp = x - fl
        p0 = np.mod(fl, N_PHI_D).astype(np.intp)
        p1 = np.where(p0 == N_PHI_D - 1, 0, p0 + 1)  # periodic in φd (reciprocity)
        out = np.zeros((len(wi), 3))
        for dh, wh in ((0, 1.0 - fh), (1, fh)):
            for dd, wd in ((0, 1.0 - fd), (1, fd)):
                row = ((h0 + dh) * N_THETA_D + d0 + dd) * N_PHI_D
                w_hd = wh * wd
                out += (w_hd * (1.0 - fp))[:, None] * self._flat[row + p0]
                out += (w_hd * fp)[:, None] * self._flat[row + p1]
        above = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
        out[~above] = 0.0
        return out.reshape(shape + (3,))

    def fill_note(self) -> str:
        """One line: how many cells above the horizon were filled ('' when the table held them all)."""
        if not self.n_filled:
            return ""
        pct = 100.0 * self.n_filled / self.n_above
        return (f"{self.source}: {self.n_filled:,} of {self.n_above:,} table cells above the horizon not measured "
                f"({pct:.2g} %): rendered with the nearest measured cell's value")

    def __repr__(self) -> str:
        return f"TableBRDF({self.source}, {self.n_filled} cells filled)"

