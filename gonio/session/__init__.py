"""Measurement sessions: the crash-safe session store (:mod:`gonio.store.directory`).

The session runner (``gonio measure``/``gonio resume``) builds on :class:`SessionStore`: create a
session with the plan in its manifest, append one record per measured pose, finish with an exit
status; on resume, reopen it and measure :meth:`SessionStore.remaining` poses.
"""

from gonio.store.directory import COSINE_CONVENTION, SessionStore, load_session, scan_samples

__all__ = ["SessionStore", "load_session", "scan_samples", "COSINE_CONVENTION"]
