"""Reconstruct a whole BRDF table from a measurement's samples under a prior, and write it as a gonio source.

:func:`reconstruct` reads a session directory, CSV or NPZ export (anything :func:`gonio.load` reads that has
samples), leaves out samples with quality flags (saturated, low signal: :mod:`gonio.samples`, as ``gonio fit`` does),
checks every remaining sample before any arithmetic (no samples, a non-finite value or direction, σ ≤ 0 or
missing: one :class:`gonio.errors.DataError` line naming the source and the sample; the index is among the
unflagged samples), and conditions the prior on them (:class:`gonio.prior.posterior.Posterior`).

:func:`write_reconstruction` writes the posterior table: ``.npz`` (:mod:`gonio.io.npz`'s format: ``table/values``
the posterior median, ``table/sigma`` its per-cell standard uncertainty, no samples, so every reader takes the
table; ``metadata.reconstruction`` says how it was made) or a MERL ``.binary`` (values only). Both are ordinary
sources for ``gonio fit``, ``export``, ``plot``, ``report`` and ``view``.
"""

from __future__ import annotations

from pathlib import Path


from gonio.errors import DataError
from gonio.prior.model import Prior
from gonio.prior.posterior import Posterior

__all__ = ["measured_samples", "reconstruct", "write_reconstruction"]


def measured_samples(source):
    """``(Measured, SampleSet)`` of a source's unflagged measured samples, checked (module docstring)."""
    from gonio.io.source import Measured, load_source
    from gonio.prior.posterior import _check_samples

    m = source if isinstance(source, Measured) else load_source(source)
    name = str(m.path)
    if m.samples is None and (m.table is not None or m.brdf is not None):
        raise DataError(f"{name}: a full table, not a sparse measurement: there is nothing to reconstruct")
    s = m.to_samples()
    if len(s) == 0:
        raise DataError(f"{name}: holds no samples (an empty export or a session stopped before its first pose)")
    keep = s.flags == 0
    if not keep.any():
        raise DataError(f"{name}: all {len(s)} samples carry quality flags (saturated, low signal): none to use")
    used = s.subset(keep) if not keep.all() else s
    _check_samples(used.wi, used.wo, used.f, used.sigma, name)  # a flagged sample is not used, so not checked
    return m, used


def reconstruct(source, prior: Prior):
    """``(posterior, measured, samples)``: the posterior of ``prior`` given the source's samples, the source as
    loaded (:class:`gonio.io.source.Measured`) and the samples used (module docstring)."""
    m, s = measured_samples(source)
    return Posterior.start(prior).update_samples(s, source=str(m.path)), m, s


def write_reconstruction(path, posterior: Posterior, *, source: str = "", prior_name: str = "",
                         manifest: dict | None = None) -> Path:
    """Write the posterior table to ``path`` (``.npz`` with σ, or MERL ``.binary``); returns the path."""
    path = Path(path)
    table = posterior.table()
    q = posterior.quality()
    info = {"method": "Bayesian linear model under a data-driven prior (docs/prior.md)", "source": source,
            "prior": prior_name, "n_samples": posterior.n_samples, "expected_error": posterior.expected_error(),
            "quality": q.line(), "out_of_span": q.out_of_span, "chi2": q.chi2, "dof": q.dof, "p_value": q.p_value,
            "values": "posterior median of f; table/sigma: delta-method standard uncertainty"}
    if path.suffix.lower() == ".npz":
        from gonio.io.npz import build_metadata, write_npz
        from gonio.samples import SampleSet

        meta = build_metadata(manifest or {}, reconstruction=info)
        return write_npz(path, SampleSet.empty(), meta, table=table)
    if path.suffix.lower() in (".binary", ".merl"):
        from gonio.io.merl import write_merl

        return write_merl(path, table)
    raise DataError(f"{path}: the reconstruction is written as .npz (with σ) or .binary (MERL)")
