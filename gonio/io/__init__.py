"""Data file formats: MERL binary tables (:mod:`gonio.io.merl`), per-sample CSV (:mod:`gonio.io.csv`)
and self-describing NPZ archives (:mod:`gonio.io.npz`)."""

from __future__ import annotations

from gonio.io.merl import MerlTable, cell_centres, cell_directions, read_merl, write_merl

__all__ = ["MerlTable", "cell_centres", "cell_directions", "read_merl", "write_merl"]
