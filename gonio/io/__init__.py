"""Data file formats: MERL binary tables (:mod:`gonio.io.merl`), per-sample CSV (:mod:`gonio.io.csv`),
self-describing NPZ archives (:mod:`gonio.io.npz`), and the renderer exports of a fit, one shape for all
(:mod:`gonio.io.exports`: ``to_mitsuba``, ``to_pbrt``, ``to_gltf``, imported on first use)."""

from __future__ import annotations

from gonio.io.merl import MerlTable, cell_centres, cell_directions, read_merl, write_merl

__all__ = ["MerlTable", "cell_centres", "cell_directions", "read_merl", "write_merl", "to_mitsuba", "to_pbrt",
           "to_gltf"]

_EXPORTS = ("to_mitsuba", "to_pbrt", "to_gltf")


def __getattr__(name):
    if name in _EXPORTS:  # PEP 562: the exports (and their renderer modules) load on first use
        from gonio.io import exports

        return getattr(exports, name)
    raise AttributeError(f"module 'gonio.io' has no attribute {name!r}")
