"""The prior's grid: nodes in Rusinkiewicz half/difference angles and trilinear interpolation between them.

A prior's basis lives on a grid much coarser than MERL's 90 × 90 × 180 cells (the shipped prior must fit in a
few megabytes). The grid has ``n_h × n_d × n_p`` nodes (node values, not cell averages):

* ``θh_i = (i / (n_h − 1))² · π/2`` — the square-root spacing of MERL's θh axis (Matusik et al. 2003), dense
  near the specular peak;
* ``θd_j = j / (n_d − 1) · π/2``;
* ``φd_k = k / (n_p − 1) · π`` — φd folded to [0, π] by reciprocity, f(φd) = f(φd + π), as MERL folds it.
  Isotropic materials are also bilaterally symmetric, f(φd) = f(π − φd) (Romeiro, Vasilyev & Zickler, ECCV
  2008), which would halve the grid, but measured tables are not exactly so: folding the 63 real materials
  to [0, π/2] cost 0.015–0.026 in cube-root error (docs/prior.md), more than the whole grid's interpolation.

A direction pair (wi, wo) maps to continuous coordinates ``x_h = √(θh/(π/2))·(n_h−1)``,
``x_d = θd/(π/2)·(n_d−1)``, ``x_p = (φd mod π)/π·(n_p−1)`` and takes the trilinear combination of its 8
surrounding nodes (:meth:`PriorGrid.weights`, a sparse ``(n, G)`` matrix). The grid's :attr:`PriorGrid.grid_id`
names it in prior files: a prior is only ever used with the grid it was built on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PriorGrid", "DEFAULT_GRID", "merl_cell_angles", "merl_above"]


def merl_cell_angles(theta_h_rows=slice(None)):
    """``(θh, θd, φd, above)`` of the MERL cell centres (:func:`gonio.io.merl.cell_centres`) of the θh rows
    ``theta_h_rows``, each of shape ``(rows, 90, 180)``; ``above``: both directions above the horizon
    (cos θi,o = cos θd cos θh ∓ sin θd cos φd sin θh > 0, Rusinkiewicz 1998 at φh = 0)."""
    from gonio.io.merl import cell_centres

    th, td, pd = cell_centres()
    th = th[theta_h_rows]
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    return TH, TD, PD, _merl_above(th, td, pd)


def merl_above(theta_h_rows=slice(None)) -> np.ndarray:
    """:func:`merl_cell_angles`'s ``above`` alone, ``(rows, 90, 180)``."""
    from gonio.io.merl import cell_centres

    th, td, pd = cell_centres()
    return _merl_above(th[theta_h_rows], td, pd)


def _merl_above(th, td, pd) -> np.ndarray:
    """``above`` from the 1-D axes: the products of the per-axis factors, broadcast (the trigonometry on
    90 + 90 + 180 angles, not on every cell)."""
    ct, st = np.cos(th)[:, None, None], np.sin(th)[:, None, None]
    cd, sd = np.cos(td)[None, :, None], np.sin(td)[None, :, None]
    a, b = cd * ct, sd * np.cos(pd)[None, None, :] * st
    return (a - b > 0) & (a + b > 0)


@dataclass(frozen=True)
class PriorGrid:
    """Node counts along θh (square-root spaced), θd and folded φd (module docstring)."""

    n_h: int = 56
    n_d: int = 24
    n_p: int = 20

    def __post_init__(self):
        for name in ("n_h", "n_d", "n_p"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or not 2 <= v <= 512:
                raise ValueError(f"PriorGrid.{name} = {v!r}: must be an integer in [2, 512]")

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.n_h, self.n_d, self.n_p)

    @property
    def size(self) -> int:
        """Number of nodes G."""
        return self.n_h * self.n_d * self.n_p

    @property
    def grid_id(self) -> str:
        """The grid's name in prior files, e.g. ``hd-sqrt-56x24x20-pi``."""
        return f"hd-sqrt-{self.n_h}x{self.n_d}x{self.n_p}-pi"

    @classmethod
    def from_id(cls, grid_id: str) -> "PriorGrid":
        """Inverse of :attr:`grid_id`; ``ValueError`` for a grid this gonio does not know."""
        parts = str(grid_id).split("-")
        if len(parts) != 4 or parts[:2] != ["hd", "sqrt"] or parts[3] != "pi":
            raise ValueError(f"unknown prior grid {grid_id!r} (this gonio reads hd-sqrt-HxDxP-pi)")
        try:
            n_h, n_d, n_p = (int(x) for x in parts[2].split("x"))
        except ValueError:
            raise ValueError(f"unknown prior grid {grid_id!r} (this gonio reads hd-sqrt-HxDxP-pi)") from None
        return cls(n_h, n_d, n_p)

    def node_angles(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(θh, θd, φd)`` of every node, each of shape ``(G,)`` in C order over ``(n_h, n_d, n_p)``."""
        th = (np.arange(self.n_h) / (self.n_h - 1)) ** 2 * (math.pi / 2)
        td = np.arange(self.n_d) / (self.n_d - 1) * (math.pi / 2)
        pd = np.arange(self.n_p) / (self.n_p - 1) * math.pi
        TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
        return TH.ravel(), TD.ravel(), PD.ravel()

    def node_directions(self) -> tuple[np.ndarray, np.ndarray]:
        """``(wi, wo)`` of every node at φh = 0, each ``(G, 3)`` (:func:`gonio.geometry.dirs_from_half_diff`)."""
        from gonio.geometry import dirs_from_half_diff

        th, td, pd = self.node_angles()
        return dirs_from_half_diff(th, np.zeros_like(th), td, pd)

    def coords(self, theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Continuous node coordinates of half/difference angles (radians), clamped to the grid."""
        th = np.clip(np.asarray(theta_h, dtype=np.float64), 0.0, math.pi / 2)
        td = np.clip(np.nan_to_num(np.asarray(theta_d, dtype=np.float64), nan=0.0), 0.0, math.pi / 2)
        p = np.mod(np.nan_to_num(np.asarray(phi_d, dtype=np.float64), nan=0.0), math.pi)
        x_h = np.sqrt(th / (math.pi / 2)) * (self.n_h - 1)
        x_d = td / (math.pi / 2) * (self.n_d - 1)
        x_p = p / math.pi * (self.n_p - 1)
        return x_h, x_d, x_p

    def _axes(self, xs):
        """Per axis: the lower node index (clamped so the upper one exists) and the fraction towards the upper."""
        idx, frac = [], []
        for x, n in zip(xs, self.shape):
            i0 = np.minimum(np.floor(x).astype(np.intp), n - 2)
            idx.append(i0)
            frac.append(np.clip(x - i0, 0.0, 1.0))
        return idx, frac

    def _csr(self, cols: np.ndarray, vals: np.ndarray):
        """The ``(n, G)`` CSR matrix of 8 weights a row: ``cols``, ``vals`` (n, 8), corner k = 0..7 of (θh, θd, φd)
        offsets (0|1, 0|1, 0|1) in C order."""
        from scipy.sparse import csr_matrix

        n = cols.shape[0]
        indptr = np.arange(0, 8 * n + 1, 8, dtype=cols.dtype)
        return csr_matrix((vals.ravel(), cols.ravel(), indptr), shape=(n, self.size))

    def weights_angles(self, theta_h, theta_d, phi_d):
        """Sparse ``(n, G)`` CSR matrix of trilinear weights (8 per row, summing to 1) at the given angles."""
        xs = self.coords(np.ravel(theta_h), np.ravel(theta_d), np.ravel(phi_d))
        idx, frac = self._axes(xs)
        n = xs[0].shape[0]
        cols = np.empty((n, 8), dtype=np.intp)
        vals = np.empty((n, 8), dtype=np.float64)
        k = 0
        for a in (0, 1):
            wa = frac[0] if a else 1.0 - frac[0]
            for b in (0, 1):
                wb = frac[1] if b else 1.0 - frac[1]
                for c in (0, 1):
                    wc = frac[2] if c else 1.0 - frac[2]
                    cols[:, k] = ((idx[0] + a) * self.n_d + idx[1] + b) * self.n_p + idx[2] + c
                    vals[:, k] = wa * wb * wc
                    k += 1
        return self._csr(cols, vals)

    def weights_merl(self, theta_h_rows=slice(None)):
        """:meth:`weights_angles` at the MERL cell centres above the horizon of the θh rows ``theta_h_rows``, in C
        order (``weights_angles(θh[above], θd[above], φd[above])`` with :func:`merl_cell_angles`'s arrays), the same
        matrix bit for bit: the grid is separable, so coordinates, node indices and fractions are computed per
        axis (90 + 90 + 180 values); a cell's 8 weights are (wθh · wθd) · wφd, the first factor from a (θh, θd)
        table and the second from a φd one (the product :meth:`weights_angles` forms, in its order), and its 8
        columns its lower corner's node plus the corners' fixed offsets."""
        from gonio.io.merl import cell_centres

        th, td, pd = cell_centres()
        th = th[theta_h_rows]
        pick = np.flatnonzero(_merl_above(th, td, pd))
        (ih, id_, ip), (fh, fd, fp) = self._axes(self.coords(th, td, pd))
        # per (θh, θd) row: the 4 products wa·wb of corners (a, b) in C order; per φd: the 2 weights wc of c
        w_ab = np.stack([(fh if a else 1.0 - fh)[:, None] * (fd if b else 1.0 - fd)[None, :]
                         for a in (0, 1) for b in (0, 1)], axis=-1).reshape(-1, 4)
        w_c = np.stack([1.0 - fp, fp], axis=-1)
        row, k_p = np.divmod(pick, len(pd))
        vals = (w_ab[row][:, :, None] * w_c[k_p][:, None, :]).reshape(-1, 8)
        k_h, k_d = np.divmod(row, len(td))
        base = (ih[k_h] * self.n_d + id_[k_d]) * self.n_p + ip[k_p]
        # int32 indices where every column index and row pointer fits (what scipy.sparse stores then, so _csr hands
        # them over as they are; given int64 it checked their range and converted them: ~40 % of this method's time)
        itype = np.int32 if max(self.size, 8 * len(pick) + 1) <= np.iinfo(np.int32).max else np.int64
        offsets = np.array([(a * self.n_d + b) * self.n_p + c for a in (0, 1) for b in (0, 1) for c in (0, 1)],
                           dtype=itype)
        return self._csr(base.astype(itype)[:, None] + offsets[None, :], vals)

    def weights(self, wi, wo):
        """Trilinear weights (sparse ``(n, G)``) of direction pairs ``wi``, ``wo`` (``(n, 3)``)."""
        from gonio.geometry import half_diff_from_dirs

        th, _, td, pd = half_diff_from_dirs(np.reshape(wi, (-1, 3)), np.reshape(wo, (-1, 3)))
        return self.weights_angles(th, td, pd)


#: The grid of the shipped prior (56 × 24 × 20 = 26,880 nodes; docs/prior.md measures what it costs).
DEFAULT_GRID = PriorGrid(56, 24, 20)
