"""Open whatever the data commands are pointed at: a session directory (through
:func:`gonio.session.store.load_session`), an NPZ export (:mod:`gonio.io.npz`) or a MERL binary
(:mod:`gonio.io.merl`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from gonio.errors import DataError
from gonio.io.merl import MerlTable
from gonio.samples import SampleSet

__all__ = ["Source", "load_source"]


@dataclass(frozen=True)
class Source:
    """Loaded input. ``kind`` is ``"session"``, ``"npz"`` or ``"merl"``; a MERL file has no samples,
    a session has no table (tabulate it), an NPZ export may have both."""

    path: Path
    kind: str
    manifest: dict = field(default_factory=dict)
    samples: SampleSet | None = None
    table: MerlTable | None = None


def load_source(path) -> Source:
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
        return Source(p, "session", dict(manifest), samples, None)
    if not p.exists():
        raise DataError(f"{p}: no such session directory or data file")
    if p.suffix.lower() == ".npz":
        from gonio.io.npz import read_npz

        content = read_npz(p)
        manifest = content.metadata.get("manifest") or {}
        return Source(p, "npz", dict(manifest), content.samples, content.table)
    from gonio.io.merl import read_merl

    return Source(p, "merl", {}, None, read_merl(p))
