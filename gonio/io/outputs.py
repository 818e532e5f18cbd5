"""Where outputs may be written: never onto a session's own files, never over an existing file unless
asked (``--force``), never through a symlink into a session, and only with a suffix the writer knows.

Every command that writes a file (export, fit --json/--mitsuba, plot, plan --out, tabulate -o, camera
capture/response) asks :func:`check_output` first, so a typo (``-o S/samples.jsonl``) is a one-line
refusal, not 1,093 measured samples overwritten.
"""

from __future__ import annotations

import os
from pathlib import Path

from gonio.errors import ConfigError

__all__ = ["check_output", "session_root"]

def session_root(path: Path) -> Path | None:
    """The session directory ``path`` lies in (the nearest ancestor holding a manifest), if any."""
    for d in [path.parent, *path.parent.parents]:
        if (d / "manifest.json").is_file():
            return d
    return None


def check_output(path, *, option: str, force: bool = False, suffixes: tuple[str, ...] | None = None) -> Path:
    """``path`` if an output may be written there, else a one-line :class:`ConfigError` naming
    ``option``: inside a session directory (its own files or anything else in it: a session directory
    holds only what gonio measured), an existing file without ``force``, a directory, a file name
    ending other than ``suffixes``, or a missing parent directory."""
    p = Path(path).expanduser()
    resolved = Path(os.path.realpath(p))  # follow links: a link into a session is still the session's file
    for candidate in (p.absolute(), resolved):
        root = session_root(candidate)
        if root is not None:
            raise ConfigError.field(None, option, str(path), f"is inside the session directory {root}: outputs "
                                    "never go into a session (write it elsewhere)")
    if suffixes and p.suffix.lower() not in suffixes:
        raise ConfigError.field(None, option, str(path), f"must end in {' or '.join(suffixes)}")
    if p.is_dir():
        raise ConfigError.field(None, option, str(path), "is a directory; name a file")
    if (p.exists() or p.is_symlink()) and not force:
        raise ConfigError.field(None, option, str(path), "exists (use --force to overwrite it)")
    if not p.parent.exists():
        raise ConfigError.field(None, option, str(path), f"no such directory {p.parent}")
    return p
