"""Where outputs may be written: never onto a session's own files, never over an existing file unless
asked (``--force``), never through a symlink into a session, and only with a suffix the writer knows.

Every command that writes a file (export, fit --json/--mitsuba, plot, plan --out, tabulate -o, camera
capture/response) asks :func:`check_output` first, so a typo (``-o S/samples.jsonl``) is a one-line
refusal, not 1,093 measured samples overwritten.

This module depends on nothing but :mod:`gonio.errors`, so every layer writes through it (a fit result's
JSON as well as the exports); :mod:`gonio.io.outputs` adds what only the data formats know (a MERL input's
sidecar is one of the inputs an output must not replace).
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

from gonio.errors import ConfigError

__all__ = ["check_output", "check_output_dir", "session_root", "written_atomically", "write_text_atomically"]

def session_root(path: Path) -> Path | None:
    """The session directory ``path`` lies in (the nearest ancestor holding a manifest), if any."""
    for d in [path.parent, *path.parent.parents]:
        if (d / "manifest.json").is_file():
            return d
    return None


def _refuse_in_session(p: Path, given, option: str, root_of) -> None:
    """A one-line :class:`ConfigError` naming ``option`` if ``root_of`` finds a session directory for
    ``p`` as given or with links followed (a link into a session is still the session's file)."""
    for candidate in (p.absolute(), Path(os.path.realpath(p))):
        root = root_of(candidate)
        if root is not None:
            raise ConfigError.field(None, option, str(given), f"is inside the session directory {root}: outputs "
                                    "never go into a session (write it elsewhere)")


def _input_files(inputs) -> list[Path]:
    """The files a command reads (``~`` expanded); :func:`gonio.io.outputs.check_output` adds a MERL input's
    sidecar."""
    return [Path(i).expanduser() for i in inputs]


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.realpath(a) == os.path.realpath(b) or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def check_output(path, *, option: str, force: bool = False, suffixes: tuple[str, ...] | None = None,
                 inputs=()) -> Path:
    """``path`` if an output may be written there, else a one-line :class:`ConfigError` naming
    ``option``: inside a session directory (its own files or anything else in it: a session directory
    holds only what gonio measured), one of the command's ``inputs`` (or a MERL input's sidecar; even
    with ``force``), an existing file without ``force``, a directory, a device or FIFO (even with ``force``: the
    atomic rename would replace the device node, e.g. ``/dev/null``, by a file), a file name ending other than
    ``suffixes``, a missing parent directory, or a name spelled as a directory (``fits/``: ``Path`` drops the
    separator, so the file would be named ``fits``)."""
    if isinstance(path, str) and path.endswith(("/", os.sep)):
        raise ConfigError.field(None, option, path, "names a directory (ends in a separator); name a file "
                                "(a directory of one output per source is for several sources, or --jobs)")
    p = Path(path).expanduser()
    _refuse_in_session(p, path, option, session_root)
    for q in _input_files(inputs):
        if _same_file(p, q):
            what = "an input of this command" if p == q else f"{q}, an input of this command"
            raise ConfigError.field(None, option, str(path), f"is {what}: an output never replaces what it is "
                                    "made from (name another file)")
    if suffixes and p.suffix.lower() not in suffixes:
        raise ConfigError.field(None, option, str(path), f"must end in {' or '.join(suffixes)}")
    if p.is_dir():
        raise ConfigError.field(None, option, str(path), "is a directory; name a file")
    if p.exists() and not p.is_symlink() and not p.is_file():  # even with force: the rename would replace it
        raise ConfigError.field(None, option, str(path), "is not a regular file (a device or a FIFO): an output is "
                                "written as a new file renamed into place, which would replace it; name a file")
    if (p.exists() or p.is_symlink()) and not force:
        raise ConfigError.field(None, option, str(path), "exists (use --force to overwrite it)")
    if not p.parent.exists():
        raise ConfigError.field(None, option, str(path), f"no such directory {p.parent}")
    return p


def check_output_dir(path, *, option: str) -> Path:
    """``path`` if a directory of outputs (one per source) may be created or used there, else a one-line
    :class:`ConfigError` naming ``option``: a session directory or anything inside one, or a file."""
    d = Path(path).expanduser()
    _refuse_in_session(d, path, option, lambda c: c if (c / "manifest.json").is_file() else session_root(c))
    if d.exists() and not d.is_dir():
        raise ConfigError.field(None, option, str(path), "with several sources this must be a directory")
    return d


@contextmanager
def written_atomically(path, mode: str = "w", **open_kw):
    """Open a temporary file beside ``path`` for writing; when the block ends normally it is renamed onto
    ``path`` (``os.replace``: atomic on one file system), else (an error, Ctrl-C) removed. A reader never
    sees a half-written export (a CSV cut at a line boundary reads as a smaller valid one), and a failed
    ``--force`` leaves the previous file as it was."""
    p = Path(path)
    tmp = p.with_name(f".{p.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, mode, **open_kw) as fh:
            yield fh
        os.replace(tmp, p)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomically(path, text: str) -> None:
    """``path``'s content replaced by ``text`` (UTF-8) through :func:`written_atomically`."""
    with written_atomically(path, "w", encoding="utf-8") as fh:
        fh.write(text)
