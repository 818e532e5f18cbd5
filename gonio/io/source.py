"""Open whatever the data commands are pointed at: a session directory (through
:func:`gonio.store.directory.load_session`), an NPZ export (:mod:`gonio.io.npz`), a gonio CSV export
(:mod:`gonio.io.csv`), an RGL material ``.bsdf`` (:mod:`gonio.io.powitacq`) or a MERL binary
(:mod:`gonio.io.merl`, with its sidecar :mod:`gonio.io.merl_sidecar` when present).

The file's content decides how it is read (:mod:`gonio.io.sniff`); a file whose content is not what its
name ends in (``.binary`` holding a Git LFS pointer, ``.csv`` holding HTML, ...) is refused in one line
naming what it looks like."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gonio.errors import DataError
from gonio.io.merl import MerlTable
from gonio.samples import SampleSet

__all__ = ["Measured", "Source", "load_source"]


@dataclass(frozen=True)
class Measured:
    """A measured BRDF as loaded from a file or a session directory (what :func:`gonio.load` returns).

    ``kind`` says what was read (``"session"``, ``"npz"``, ``"merl"``, ...). A MERL file has a table and
    no samples, a session has samples and no table (:meth:`lookup` tabulates them on first use), an NPZ
    export may have both. ``manifest`` (also :attr:`metadata`) is what the source says about itself.
    """

    path: Path
    kind: str
    manifest: dict = field(default_factory=dict)
    samples: SampleSet | None = None
    table: MerlTable | None = None
    #: (90, 90, 180) bool: table cells interpolated, not measured (from a MERL export's sidecar), or None
    filled: np.ndarray | None = None
    #: an evaluable measured BRDF that is neither samples nor a table (an RGL ``.bsdf`` material), or None
    brdf: object = None
    #: a session's per-pose record metadata (``{pose: meta}``: joints, board pose, ...), or None
    pose_meta: dict | None = None

    @property
    def metadata(self) -> dict:
        """What the source says about itself (a session's manifest, an export's metadata)."""
        return self.manifest

    def to_samples(self) -> SampleSet:
        """The measured values as samples: the session's own, or one per measured table cell (at its
        centre, φh = 0). A table without uncertainties gives σ = NaN (fits then use an unweighted loss,
        not χ² on invented σ)."""

        if self.samples is not None:
            return self.samples
        if self.table is None and self.brdf is not None:
            return self.brdf.to_samples()
        if self.table is None:
            raise DataError(f"{self.path}: holds neither samples nor a table")
        table = self.table
        if self.filled is not None and self.filled.any():  # interpolated cells are not measurements
            values = table.values.copy()
            values[self.filled] = np.nan
            table = MerlTable(values, table.sigma, table.count)
        s = table.to_samples()
        if self.table.sigma is None:
            s = SampleSet(s.wi, s.wo, s.f, np.full_like(s.f, np.nan), n_pixels=s.n_pixels)
        return s

    def tabulated(self) -> MerlTable:
        """The MERL table: the source's own, or the samples tabulated without filling (cached)."""
        if self.table is not None:
            return self.table
        if self.brdf is not None:
            return self.brdf.to_table()
        cached = self.__dict__.get("_tabulated")
        if cached is None:
            from gonio.tabulate import tabulate

            cached = tabulate(self.to_samples(), source=str(self.path), fill_deg=0.0).table
            object.__setattr__(self, "_tabulated", cached)
        return cached

    def lookup(self, wi, wo, method: str = "trilinear"):
        """BRDF values (1/sr, RGB) at directions ``wi``, ``wo`` (..., 3) from the table
        (:meth:`gonio.io.merl.MerlTable.lookup`); cells never measured give NaN."""
        return self.tabulated().lookup(wi, wo, method=method)

    def eval(self, wi, wo):
        """Same as :meth:`lookup` with trilinear interpolation: a measured BRDF evaluates like a model
        (an RGL material evaluates its own tensor: :meth:`gonio.io.powitacq.PowitacqBRDF.eval`)."""
        if self.brdf is not None:
            return self.brdf.eval(wi, wo)
        return self.lookup(wi, wo)

    def __repr__(self) -> str:
        parts = [f"Measured({self.kind}: {self.path}"]
        if self.samples is not None:
            parts.append(f"{len(self.samples)} samples")
        if self.table is not None:
            parts.append(f"table {int(self.table.measured.sum())} cells measured")
        if self.filled is not None and self.filled.any():
            parts.append(f"{int(self.filled.sum())} of them filled by interpolation")
        if self.brdf is not None:
            parts.append(repr(self.brdf))
        mat = self.manifest.get("material") if isinstance(self.manifest, dict) else None
        if isinstance(mat, dict) and isinstance(mat.get("model"), str):
            parts.append(f"material {mat['model']}")
        return ", ".join(parts) + ")"


#: The name this class had before the public API (``gonio.load``) existed.
Source = Measured


_BY_SUFFIX = {".npz": "npz", ".csv": "csv", ".bsdf": "bsdf", ".binary": "merl", ".merl": "merl"}


def _warn_if_unfinished(path: Path, manifest: dict, samples, records: int | None = None) -> None:
    """A warning (one line through the CLI) when a session did not finish its plan: what is fitted,
    exported or shown is then a part of the plan, and ``gonio resume`` measures the rest. ``records``: the
    poses ``samples.jsonl`` holds a record of (a record may hold no sample — a sphere pose whose pixels were all
    rejected — so the samples' poses undercount them, as ``gonio status`` counts records)."""
    import warnings

    from gonio.store.directory import missing_poses

    done = records if records is not None else (
        len(set(samples.pose.tolist())) if samples is not None and getattr(samples, "pose", None) is not None else None)
    damaged = manifest.get("damaged_records") if isinstance(manifest.get("damaged_records"), list) else []
    lost = missing_poses(manifest, (done or 0) + len(damaged))
    if lost:
        warnings.warn(f"{path}: {lost} pose(s) the manifest counted at its last stop are not in samples.jsonl (a "
                      "truncated or replaced file?); restore it from a backup, or `gonio resume` measures them "
                      "again", stacklevel=4)
        return
    status = manifest.get("exit_status")
    if status == "completed":
        return
    if str(status).startswith("unusable"):  # gonio.session.usability: every pose may be stored, most unusable
        import textwrap

        warnings.warn(f"{path}: the session ended {textwrap.shorten(str(status), 200, placeholder=' …')}: its "
                      "samples are mostly flagged or missing", stacklevel=4)
        return
    plan = manifest.get("plan")
    n_plan = plan.get("n_poses") if isinstance(plan, dict) else None
    if isinstance(n_plan, int) and not isinstance(n_plan, bool) and done is not None and done >= n_plan:
        return
    import textwrap

    how = {None: "no exit status: killed, or still running", "interrupted": "interrupted"}.get(
        status, textwrap.shorten(str(status), 160, placeholder=" …"))  # whole words: "(no ): 0 of 38" was cut mid-word
    of = f"{done} of {n_plan} poses" if isinstance(n_plan, int) and done is not None else "part of its plan"
    warnings.warn(f"{path}: the session is not complete ({how}): {of} measured; `gonio resume {path}` "
                  "measures the rest", stacklevel=4)


def load_source(path) -> Measured:
    """Load a session directory or a data file: MERL binary, gonio NPZ or CSV export, RGL ``.bsdf``.

    The content decides the reader (:func:`gonio.io.sniff.sniff`); a file named for one format
    (``.npz``, ``.csv``, ``.bsdf``, ``.binary``/``.merl``) whose content is another, or a file of no
    format gonio reads, is one :class:`DataError` line naming what it looks like.
    """
    p = Path(path)
    if p.is_dir():
        try:
            from gonio.store.directory import load_session_records
        except ImportError:
            raise DataError(f"{p}: cannot read session directories: gonio.store.directory is not installed") from None
        manifest, samples, meta = load_session_records(p)
        _warn_if_unfinished(p, manifest, samples, records=len(meta))
        return Measured(p, "session", dict(manifest), samples, None, pose_meta=meta)
    if not p.exists():
        raise DataError(f"{p}: no such session directory or data file")
    from gonio.io.sniff import KIND_NAMES, sniff

    try:
        kind, looks = sniff(p)
    except OSError as exc:
        raise DataError(f"{p}: cannot read ({exc.strerror or exc})") from None
    expected = _BY_SUFFIX.get(p.suffix.lower())
    if kind == "other" or (expected is not None and kind != expected):
        wanted = KIND_NAMES[expected] if expected else "a data file gonio reads (MERL, NPZ, CSV, .bsdf)"
        raise DataError(f"{p}: not {wanted}: it looks like {looks}")
    if kind == "npz":
        from gonio.io.npz import read_npz

        content = read_npz(p)
        manifest = content.metadata.get("manifest") or {}
        samples = content.samples
        if samples is not None and len(samples) == 0 and content.table is not None:
            samples = None  # a table's export (`gonio export T.binary --format npz`) reads as the table did
        return Measured(p, "npz", dict(manifest), samples, content.table, filled=content.filled)
    if kind == "csv":
        from gonio.io.csv import read_csv

        return Measured(p, "csv", {}, read_csv(p), None)
    if kind == "bsdf":
        from gonio.io.powitacq import read_bsdf

        brdf = read_bsdf(p)
        return Measured(p, "bsdf", {"description": brdf.description, "isotropic": brdf.isotropic}, brdf=brdf)
    from gonio.io.merl import read_merl
    from gonio.io.merl_sidecar import filled_mask, read_sidecar, sidecar_path

    table = read_merl(p)
    side = read_sidecar(sidecar_path(p))
    return Measured(p, "merl", dict(side or {}), None, table, filled=filled_mask(side))
