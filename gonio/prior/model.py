"""The :class:`Prior` data type and its file format (``.npz``, docs/formats.md "BRDF prior").

A prior is a Gaussian distribution over BRDFs in the mapped domain of :mod:`gonio.prior.mapping`, on the
nodes of a :class:`gonio.prior.grid.PriorGrid`, one colour channel at a time (the channels share it):

    u = μ + B·a + r,   a ~ N(0, diag(s²)),   r ~ N(0, diag(τ²))

``μ`` (G,) the mean of the training materials' mapped tables, ``B`` (G, K) their first K principal directions,
``s²`` (K,) the coefficients' variances, ``τ²`` (G,) the per-node variance of what the K components leave
out (so a material outside their span is not forced into it), ``f_ref`` (G,) the reference BRDF of the
mapping. ``weight`` (G,) is each node's share of the valid MERL cells (its trilinear weight summed over
them), the measure of expected errors "over the table". How they are estimated: :mod:`gonio.prior.build`.

File: a NumPy ``.npz`` without pickle, keys ``format`` (``"gonio-prior"``), ``version`` (:data:`FORMAT_VERSION`),
``grid_id``, ``eps``, ``mean`` (float32), ``basis`` (float16, each column divided by ``basis_scale``, float64),
``variance`` (float64), ``residual``, ``f_ref``, ``weight`` (float32), ``materials`` (unicode) and ``metadata``
(one JSON string). Reading one of another format version or grid is refused in one line
(:func:`load_prior`); :func:`save_prior` writes atomically.
"""

from __future__ import annotations

import functools
import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.errors import DataError
from gonio.prior.grid import PriorGrid

__all__ = ["Prior", "FORMAT", "FORMAT_VERSION", "save_prior", "load_prior", "default_prior_path", "default_prior"]

FORMAT = "gonio-prior"
#: Version of the file layout; a reader refuses any other.
FORMAT_VERSION = 1
_KEYS = ("format", "version", "grid_id", "eps", "mean", "basis", "basis_scale", "variance", "residual", "f_ref",
         "weight", "materials", "metadata")


@dataclass(frozen=True, eq=False)
class Prior:
    """A BRDF prior (module docstring); arrays float64 in memory whatever their storage."""

    grid: PriorGrid
    mean: np.ndarray
    basis: np.ndarray
    variance: np.ndarray
    residual: np.ndarray
    f_ref: np.ndarray
    weight: np.ndarray
    eps: float = 1e-3
    materials: tuple[str, ...] = ()
    metadata: dict = field(default_factory=dict)

    def __post_init__(self):
        g = self.grid.size
        for name, shape in (("mean", (g,)), ("residual", (g,)), ("f_ref", (g,)), ("weight", (g,))):
            a = np.asarray(getattr(self, name), dtype=np.float64)
            if a.shape != shape:
                raise DataError(f"prior: {name} has shape {a.shape}, the grid {self.grid.grid_id} needs {shape}")
            object.__setattr__(self, name, a)
        b = np.asarray(self.basis, dtype=np.float64)
        if b.ndim != 2 or b.shape[0] != g:
            raise DataError(f"prior: basis has shape {b.shape}, the grid {self.grid.grid_id} needs ({g}, K)")
        v = np.asarray(self.variance, dtype=np.float64)
        if v.shape != (b.shape[1],):
            raise DataError(f"prior: variance has shape {v.shape}, the basis has {b.shape[1]} components")
        for name, a in (("mean", self.mean), ("basis", b), ("variance", v), ("residual", self.residual),
                        ("f_ref", self.f_ref), ("weight", self.weight)):
            if not np.all(np.isfinite(a)):
                raise DataError(f"prior: {name} holds non-finite values")
        if np.any(v < 0) or np.any(self.residual < 0) or np.any(self.f_ref < 0):
            raise DataError("prior: negative variance or reference value")
        object.__setattr__(self, "basis", b)
        object.__setattr__(self, "variance", v)
        object.__setattr__(self, "materials", tuple(str(m) for m in self.materials))

    @property
    def n_components(self) -> int:
        return self.basis.shape[1]

    def node_mapped(self, coefficients) -> np.ndarray:
        """μ + B·a at every node for coefficients ``(..., K)``; shape ``(..., G)``."""
        return self.mean + np.asarray(coefficients, dtype=np.float64) @ self.basis.T

    def describe(self) -> str:
        """A few lines: what it was built from, its grid, components, variance kept, size (``gonio prior info``)."""
        m = self.metadata
        kept = m.get("variance_kept")
        lines = [f"prior {m.get('name') or '(unnamed)'}: {len(self.materials)} materials, grid {self.grid.grid_id} "
                 f"({self.grid.size} nodes), {self.n_components} components"
                 + (f" keeping {100 * kept:.2f} % of the mapped variance" if isinstance(kept, float) else ""),
                 f"mapping u = ln((f + ε)/(f_ref + ε)), ε = {self.eps:g} (after Nielsen et al. 2015); "
                 f"format {FORMAT}/{FORMAT_VERSION}"]
        if m.get("calibration"):
            lines.append(f"variances: {m['calibration']}")
        if self.materials:
            shown = ", ".join(self.materials[:12]) + (f", … ({len(self.materials) - 12} more)" if len(self.materials) > 12 else "")
            lines.append(f"materials: {shown}")
        if m.get("provenance"):
            lines.append(f"provenance: {m['provenance']}")
        return "\n".join(lines)


def save_prior(prior: Prior, path) -> Path:
    """Write ``prior`` to ``path`` (``.npz``, module docstring) atomically; returns the path."""
    from gonio.io.outputs import written_atomically

    path = Path(path)
    b = prior.basis
    scale = np.max(np.abs(b), axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    arrays = {
        "format": np.array(FORMAT), "version": np.array(FORMAT_VERSION), "grid_id": np.array(prior.grid.grid_id),
        "eps": np.array(float(prior.eps)), "mean": prior.mean.astype(np.float32),
        "basis": (b / scale).astype(np.float16), "basis_scale": scale, "variance": prior.variance,
        "residual": prior.residual.astype(np.float32), "f_ref": prior.f_ref.astype(np.float32),
        "weight": prior.weight.astype(np.float32), "materials": np.array(list(prior.materials), dtype=str),
        "metadata": np.array(json.dumps(prior.metadata, default=str)),
    }
    try:
        with written_atomically(path, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    except OSError as exc:
        raise DataError(f"{path}: cannot write the prior ({exc.strerror or exc})") from None
    return path


def load_prior(path) -> Prior:
    """Read a prior written by :func:`save_prior`. A file of another format, format version or grid family, or
    with missing or inconsistent arrays, is one :class:`DataError` line naming the file."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            files = set(z.files)
            if "format" not in files or str(z["format"]) != FORMAT:
                raise DataError(f"{path}: not a gonio prior (no format = {FORMAT!r})")
            version = int(z["version"]) if "version" in files else None
            if version != FORMAT_VERSION:
                raise DataError(f"{path}: prior format version {version}, this gonio reads version {FORMAT_VERSION} "
                                "(rebuild it with `gonio prior build`)")
            missing = [k for k in _KEYS if k not in files]
            if missing:
                raise DataError(f"{path}: prior without {missing[0]!r}")
            try:
                grid = PriorGrid.from_id(str(z["grid_id"]))
            except ValueError as exc:
                raise DataError(f"{path}: {exc}") from None
            basis = z["basis"].astype(np.float64) * z["basis_scale"].astype(np.float64)
            meta = json.loads(str(z["metadata"]))
            return Prior(grid=grid, mean=z["mean"], basis=basis, variance=z["variance"], residual=z["residual"],
                         f_ref=z["f_ref"], weight=z["weight"], eps=float(z["eps"]),
                         materials=tuple(z["materials"].tolist()), metadata=meta if isinstance(meta, dict) else {})
    except DataError as exc:
        msg = str(exc)
        raise DataError(msg if msg.startswith(str(path)) else f"{path}: {msg.removeprefix('prior: ')}") from None
    except FileNotFoundError:
        raise DataError(f"{path}: no such prior file") from None
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as exc:
        raise DataError(f"{path}: cannot read the prior ({exc})") from None


def default_prior_path() -> Path:
    """Where the shipped prior lives (package data, built by ``python -m gonio.prior.build_default``)."""
    return Path(__file__).parent / "data" / "default-prior.npz"


@functools.lru_cache(maxsize=1)
def default_prior() -> Prior:
    """The shipped prior (read once per process); :class:`DataError` if the package was installed without it."""
    p = default_prior_path()
    if not p.is_file():
        raise DataError(f"{p}: the default prior is not installed (build it: python -m gonio.prior.build_default)")
    return load_prior(p)
