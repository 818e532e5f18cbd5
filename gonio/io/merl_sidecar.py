"""The JSON sidecar of a MERL export: what the binary cannot say about itself.

A MERL binary (:mod:`gonio.io.merl`) holds values only: nothing tells a reader which cells were measured
and which were interpolated by ``gonio export --fill DEG``. ``gonio export --format merl -o T.binary``
therefore also writes ``T.binary.json``::

    {"format": "gonio-merl-sidecar/1", "source": "...", "exported_by": "gonio 0.x",
     "fill_deg": 2.0, "filled": true, "n_measured": 51234, "n_filled": 812,
     "filled_cells": [[start, stop], ...],      # flat cell index ranges [start, stop) that were filled
     "material_label": "...", "grid": "..."}

Flat index = iφd + 180·(iθd + 90·iθh) (:func:`gonio.io.merl.flat_index`). :func:`gonio.load` reads the
sidecar beside a MERL file: the filled cells stay in the table (lookups, plots) but are not offered to a
fit as measurements (:meth:`gonio.io.source.Measured.to_samples`), so a refit is not biased by them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from gonio.errors import DataError
from gonio.io.merl import N_CELLS, SHAPE, MerlTable
from gonio.io.outputs import write_text_atomically

__all__ = ["FORMAT", "sidecar_path", "build_sidecar", "write_sidecar", "read_sidecar", "filled_mask"]

FORMAT = "gonio-merl-sidecar/1"
_MAX_BYTES = 64 * 2 ** 20


def sidecar_path(merl_path) -> Path:
    """``T.binary`` → ``T.binary.json``."""
    p = Path(merl_path)
    return p.with_name(p.name + ".json")


def _ranges(mask: np.ndarray) -> list[list[int]]:
    flat = np.concatenate([[False], mask.ravel(), [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(flat))
    return [[int(a), int(b)] for a, b in zip(edges[::2], edges[1::2])]


def build_sidecar(table: MerlTable, *, source: str, tabulation=None, manifest: dict | None = None,
                  filled: np.ndarray | None = None) -> dict:
    """The sidecar content of ``table``; ``tabulation`` is the :class:`gonio.tabulate.Tabulation` it came
    from (None: the table was read as it is, e.g. a MERL file re-exported, whose own sidecar's ``filled``
    cells are carried over)."""
    from gonio import __version__
    from gonio.io.npz import build_metadata

    measured = table.measured
    if tabulation is not None and table.count is not None:
        filled = measured & (table.count == 0)
        fill_deg = float(tabulation.fill_deg)
    elif filled is not None:
        filled = filled & measured
        fill_deg = float((manifest or {}).get("fill_deg", 0.0)) if filled.any() else 0.0
    else:
        filled = np.zeros(SHAPE, dtype=bool)
        fill_deg = 0.0
    meta = build_metadata(manifest or {})
    return {
        "format": FORMAT, "source": source, "exported_by": f"gonio {__version__}",
        "grid": "MERL 90x90x180 (theta_h sqrt-mapped, theta_d, phi_d folded to [0, pi)); flat index = "
                "i_phi_d + 180*(i_theta_d + 90*i_theta_h); cells as the reference reader BRDFRead.cpp reads them",
        "fill_deg": fill_deg, "filled": bool(filled.any()),
        "n_measured": int((measured & ~filled).sum()), "n_filled": int(filled.sum()),
        "filled_cells": _ranges(filled),
        "material_label": meta.get("material_label"),
        "cosine_convention": meta.get("cosine_convention"),
    }


def write_sidecar(path, content: dict) -> Path:
    """Write ``content`` as JSON (to a temporary name, then renamed); returns the path."""
    path = Path(path)
    try:
        write_text_atomically(path, json.dumps(content, indent=1, ensure_ascii=False) + "\n")
    except OSError as exc:
        raise DataError(f"{path}: cannot write the MERL sidecar ({exc.strerror or exc})") from None
    return path


def read_sidecar(path) -> dict | None:
    """The validated sidecar at ``path``; None when there is none or it is some other JSON file.

    Raises :class:`DataError` naming the file and field when a gonio sidecar is malformed.
    """
    path = Path(path)
    if not path.is_file():
        return None
    try:
        if path.stat().st_size > _MAX_BYTES:
            raise DataError(f"{path}: MERL sidecar larger than {_MAX_BYTES} bytes")
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None  # not ours (or unreadable): the MERL file stands alone
    if not isinstance(content, dict) or content.get("format") != FORMAT:
        return None

    def bad(field, why):
        return DataError(f"{path}: MERL sidecar field {field!r} {why}")

    fill = content.get("fill_deg")
    if isinstance(fill, bool) or not isinstance(fill, (int, float)) or not 0 <= fill < 180:
        raise bad("fill_deg", f"= {fill!r}: must be a number in [0, 180)")
    ranges = content.get("filled_cells")
    if not isinstance(ranges, list):
        raise bad("filled_cells", "must be a list of [start, stop) pairs")
    for r in ranges:
        if (not isinstance(r, list) or len(r) != 2 or not all(isinstance(x, int) and not isinstance(x, bool) for x in r)
                or not 0 <= r[0] < r[1] <= N_CELLS):
            raise bad("filled_cells", f"has {r!r}: each entry must be [start, stop) with 0 <= start < stop <= {N_CELLS}")
    n = content.get("n_filled")
    if not isinstance(n, int) or isinstance(n, bool) or n != sum(b - a for a, b in ranges):
        raise bad("n_filled", f"= {n!r}: does not match filled_cells")
    return content


def filled_mask(content: dict | None) -> np.ndarray | None:
    """(90, 90, 180) bool of the cells a sidecar lists as filled (None: no sidecar)."""
    if content is None:
        return None
    mask = np.zeros(N_CELLS, dtype=bool)
    for a, b in content["filled_cells"]:
        mask[a:b] = True
    return mask.reshape(SHAPE)
