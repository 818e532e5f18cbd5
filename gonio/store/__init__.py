"""The crash-safe session store: a session directory's manifest and its append-only, checksummed records.

The persistence layer under both the session runner (:mod:`gonio.session`, which writes sessions) and the
data formats (:mod:`gonio.io`, which reads them as a source): it depends on neither (docs/architecture.md §1,
issue 31: layers point one way). :mod:`gonio.store.records` is the record codec, :mod:`gonio.store.directory`
the directory (create, append, repair, resume, load).
"""

from gonio.store.directory import COSINE_CONVENTION, SessionStore, load_session, scan_samples

__all__ = ["SessionStore", "load_session", "scan_samples", "COSINE_CONVENTION"]
