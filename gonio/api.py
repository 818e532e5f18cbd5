"""The public Python API: what a notebook needs, re-exported at the top of the package.

>>> import gonio
>>> data = gonio.load("session-dir")                  # doctest: +SKIP
>>> result = gonio.fit(data, "lambert+ggx")           # doctest: +SKIP
>>> result.model.eval(wi, wo)                         # doctest: +SKIP

Every function here is a thin layer over the module that does the work (:mod:`gonio.io.source`,
:mod:`gonio.fit.fit`, :mod:`gonio.fit.select`); the ``gonio`` command calls the same functions.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

__all__ = ["load", "as_samples", "fit", "select"]


def load(path):
    """Read any source gonio knows — a session directory, a MERL ``.binary``, a gonio NPZ or CSV
    export, an RGL ``.bsdf`` — as a :class:`gonio.io.source.Measured` (samples, table, metadata,
    ``eval``/``lookup``); a fit JSON (``gonio fit --json``) as its :class:`gonio.fit.result.FitResult`
    (evaluable: ``.eval(wi, wo)``, ``.model``).

    Raises :class:`gonio.errors.DataError` with one line naming the path and what is wrong with it.
    """
    from gonio.io.source import load_source

    p = Path(path)
    if p.is_file():
        from gonio.io.sniff import sniff

        try:
            looks = sniff(p)[1]
        except OSError:
            looks = ""  # load_source names the fault
        if looks == "a JSON document":
            from gonio.fit.result import FitResult

            return FitResult.from_json(p)
    return load_source(path)


def calibration_modes(data):
    """A session's geometric-calibration error per pose (:func:`gonio.session.calibration_modes.session_modes`:
    what a fit propagates into its σ), or None (not a session, or its rig file has no calibration covariance).
    ``data``: a session directory or its :func:`load` result."""
    if isinstance(data, (str, Path)) and Path(data).is_dir():
        data = load(data)
    if getattr(data, "kind", None) != "session" or not getattr(data, "pose_meta", None):
        return None
    from gonio.session.calibration_modes import session_modes

    return session_modes(data.manifest, data.pose_meta, str(data.path))


def _with_geometry(data, options: dict):
    """``(samples, options)``: a session's calibration error (:func:`calibration_modes`) added to the fit's options
    as ``geometry`` (propagated into its σ: :mod:`gonio.fit.geometry`), unless given."""
    if isinstance(data, (str, Path)) and Path(data).is_dir():
        data = load(data)
    if "geometry" not in options:
        g = calibration_modes(data)
        if g is not None:
            options = {**options, "geometry": g}
    return as_samples(data), options


def as_samples(data):
    """The :class:`gonio.samples.SampleSet` behind ``data``: a SampleSet itself, a
    :class:`~gonio.io.source.Measured`, or a path that :func:`load` reads."""
    from gonio.samples import SampleSet

    if isinstance(data, SampleSet):
        return data
    if isinstance(data, (str, Path)):
        data = load(data)
    to_samples = getattr(data, "to_samples", None)
    if to_samples is None:
        raise TypeError(f"expected a path, a gonio.load() result or a SampleSet, not {type(data).__name__}")
    samples = to_samples()
    if len(samples) == 0:  # named here, where the source's name is known (the fit only sees the samples)
        from gonio.errors import DataError

        raise DataError(f"{getattr(data, 'path', 'data')}: holds no samples (an empty export or a session "
                        "stopped before its first pose)")
    return samples


def fit(data, model: str = "microfacet", *, fix: dict | None = None, **options):
    """Fit one model (a :func:`gonio.brdf.make` name, sums such as ``"lambert+2ggx"``) to ``data``
    (see :func:`as_samples`); ``options`` as :func:`gonio.fit.fit.fit` (``loss``, ``fixed``, ``seed``,
    ``max_theta_deg``, ...). ``fix`` (as ``--fix``) is ``fixed``: parameters held, named as ``gonio fit``
    prints them (``{"lobe1.f0": 1}``, ``{"f0": 1}`` for every lobe, ``{"kd.r": .., "kd.g": .., "kd.b": ..}``).
    Returns a :class:`gonio.fit.result.FitResult`: ``.model`` (evaluable), ``.params``, ``.uncertainty``,
    ``.errors``, ``.to_json()``; the renderer exports are :func:`gonio.io.exports.to_mitsuba` and its siblings."""
    from gonio.errors import ConfigError
    from gonio.fit.fit import fit as fit_samples

    if fix is not None:
        if options.get("fixed") is not None:
            raise ConfigError.field(None, "fix", fix, "give fix or fixed, not both")
        options["fixed"] = fix
    samples, options = _with_geometry(data, options)
    return fit_samples(samples, model, **options)


def select(data, candidates: Sequence[str] | None = None, **options):
    """Fit the ``candidates`` (default :data:`gonio.fit.select.DEFAULT_CANDIDATES`) and keep the
    simplest one the data support; ``options`` as :func:`gonio.fit.select.select`. Returns a
    :class:`gonio.fit.select.Selection` (``.winner``, one row per candidate, and the winner's
    ``.model``, ``.params``, ``.uncertainty``, ``.errors``)."""
    from gonio.fit.select import select as select_samples

    samples, options = _with_geometry(data, options)
    return select_samples(samples, tuple(candidates) if candidates else None, **options)
