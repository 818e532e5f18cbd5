"""Open whatever the data commands are pointed at: a session directory (through
:func:`gonio.session.store.load_session`), an NPZ export (:mod:`gonio.io.npz`) or a MERL binary
(:mod:`gonio.io.merl`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

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

    @property
    def metadata(self) -> dict:
        """What the source says about itself (a session's manifest, an export's metadata)."""
        return self.manifest

    def to_samples(self) -> SampleSet:
        """The measured values as samples: the session's own, or one per measured table cell (at its
        centre, φh = 0). A table without uncertainties gives σ = NaN (fits then use an unweighted loss,
        not χ² on invented σ)."""
        import numpy as np

        if self.samples is not None:
            return self.samples
        if self.table is None:
            raise DataError(f"{self.path}: holds neither samples nor a table")
        s = self.table.to_samples()
        if self.table.sigma is None:
            s = SampleSet(s.wi, s.wo, s.f, np.full_like(s.f, np.nan), n_pixels=s.n_pixels)
        return s

    def tabulated(self) -> MerlTable:
        """The MERL table: the source's own, or the samples tabulated without filling (cached)."""
        if self.table is not None:
            return self.table
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
        """Same as :meth:`lookup` with trilinear interpolation: a measured BRDF evaluates like a model."""
        return self.lookup(wi, wo)

    def __repr__(self) -> str:
        parts = [f"Measured({self.kind}: {self.path}"]
        if self.samples is not None:
            parts.append(f"{len(self.samples)} samples")
        if self.table is not None:
            parts.append(f"table {int(self.table.measured.sum())} cells measured")
        mat = self.manifest.get("material") if isinstance(self.manifest, dict) else None
        if isinstance(mat, dict) and isinstance(mat.get("model"), str):
            parts.append(f"material {mat['model']}")
        return ", ".join(parts) + ")"


#: The name this class had before the public API (``gonio.load``) existed.
Source = Measured


def load_source(path) -> Measured:
    """Load a session directory, an ``.npz`` export, or a MERL binary (any other file).

    Raises :class:`DataError` naming ``path`` when it does not exist or cannot be read.
    """
    p = Path(path)
    if p.is_dir():
        try:
            from gonio.session.store import load_session
        except ImportError:
            raise DataError(f"{p}: cannot read session directories: gonio.session.store is not installed") from None
        manifest, samples = load_session(p)
        return Measured(p, "session", dict(manifest), samples, None)
    if not p.exists():
        raise DataError(f"{p}: no such session directory or data file")
    if p.suffix.lower() == ".npz":
        from gonio.io.npz import read_npz

        content = read_npz(p)
        manifest = content.metadata.get("manifest") or {}
        return Measured(p, "npz", dict(manifest), content.samples, content.table)
    from gonio.io.merl import read_merl

    return Measured(p, "merl", {}, None, read_merl(p))
