"""The crash-safe session store: a directory with a self-describing manifest and an append-only,
checksummed samples file (docs/architecture.md §3: nothing measured is lost).

Layout of a session directory::

    manifest.json    what/why/how and how it ended; replaced atomically (tmp + fsync + rename)
    samples.jsonl    one record per measured pose, appended, flushed and fsynced per record

Records are described in :mod:`gonio.store.records` (and docs/formats.md §1).

The directory is untrusted input: only the fixed names above (and ``quarantine.jsonl``) are ever opened,
always with ``O_NOFOLLOW`` (a symlink is refused, never followed), with sizes bounded; the manifest's
``samples_file`` must be ``samples.jsonl``.

Crash rules: a record counts only when its newline is on disk. A session directory is created
atomically (built under a hidden name beside it, then renamed into place), so a kill leaves either
nothing or a resumable session. On :meth:`SessionStore.open` a torn last line (the write a crash
interrupted) is dropped and the file cut back to the last complete line; a damaged line anywhere
(flipped bits, stray newlines, crafted fields) is copied to ``quarantine.jsonl`` and removed from
``samples.jsonl`` (:meth:`SessionStore.repair`), so every good sample is kept and only the damaged
records' poses are measured again. A pose recorded twice (re-measured) keeps its *last* record:
samples are never duplicated. A run killed before it recorded its end gets its ``runs`` entry on the
next open, from its records' lab times, so the session's lab time survives the kill.
"""

from __future__ import annotations

import errno
import fcntl
import json
import math
import os
import secrets
import stat
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from gonio.errors import ConfigError, DataError
from gonio.samples import SampleSet
from gonio.store.records import MAX_POSE, ScanResult, _jsonable, decode_record, encode_record, scan_bytes

__all__ = ["SessionStore", "load_session", "scan_samples", "ScanResult", "MANIFEST", "SAMPLES", "QUARANTINE",
           "STORE_FORMAT", "COSINE_CONVENTION", "encode_record", "decode_record", "read_file_nofollow"]

MANIFEST = "manifest.json"
SAMPLES = "samples.jsonl"
#: The fields of a run's summary kept in the manifest's ``runs`` list (one entry per run, see ``finish``).
RUN_KEYS = ("status", "poses", "samples", "lab_time_s", "wall_time_s")
STORE_FORMAT = 1
#: What the stored ``f`` values are (docs/architecture.md §3).
COSINE_CONVENTION = "BRDF, not BRDF*cos"
UNITS = {"angles": "rad", "f": "1/sr", "sigma": "1/sr", "time": "s", "exposure": "s", "length": "m"}


def _wall() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


_SCALARS = (str, int, float, bool, type(None))
_ENCODER = json.JSONEncoder(allow_nan=False)


def _encode(obj: Any, level: int = 0, memo: dict | None = None, cache: dict | None = None) -> str:
    """``obj`` as indented JSON (one space a level; a list of scalars or of rows of them on one line): what
    ``json.dumps(obj, indent=1, allow_nan=False)`` reads back as, but the lists are written by the json module's
    C encoder — with ``indent`` the module encodes in Python, which took seconds per write for a manifest holding
    thousands of candidate poses (an adaptive session rewrites its manifest every round).

    ``memo``/``cache``: the text of each container at the top two levels of the last write, by identity
    (``id -> (obj, level, text)``): a value the caller kept unchanged since (the same object) is not encoded
    again. ``cache`` is read, ``memo`` receives this write's entries (so it holds only live objects)."""
    if isinstance(obj, dict):
        if not obj:
            return "{}"
        if not all(isinstance(k, str) for k in obj):
            return json.dumps(obj, indent=1, allow_nan=False)  # keys json converts itself: its own rules
        pad = "\n" + " " * (level + 1)
        if memo is None or level > 1:
            items = (json.dumps(k) + ": " + _encode(v, level + 1) for k, v in obj.items())
        else:
            items = (json.dumps(k) + ": " + _encode_memo(v, level + 1, memo, cache) for k, v in obj.items())
        return "{" + pad + ("," + pad).join(items) + "\n" + " " * level + "}"
    if isinstance(obj, (list, tuple)):
        if all(isinstance(x, _SCALARS) or (isinstance(x, (list, tuple)) and all(isinstance(y, _SCALARS) for y in x))
               for x in obj):  # scalars, or rows of them (poses, a covariance): one line, one call of the C encoder
            return _ENCODER.encode(obj)
        pad = "\n" + " " * (level + 1)
        return "[" + pad + ("," + pad).join(_encode(x, level + 1) for x in obj) + "\n" + " " * level + "]"
    return _ENCODER.encode(obj)


def _encode_memo(obj: Any, level: int, memo: dict, cache: dict | None) -> str:
    if not isinstance(obj, (dict, list)):
        return _encode(obj, level)
    hit = None if cache is None else cache.get(id(obj))
    if hit is not None and hit[0] is obj and hit[1] == level:
        text = hit[2]
        _carry(obj, level, memo, cache)
    else:
        text = _encode(obj, level, memo, cache)
    memo[id(obj)] = (obj, level, text)
    return text


def _carry(obj: Any, level: int, memo: dict, cache: dict) -> None:
    """Keep the cached text of the containers inside ``obj`` (reused whole) for the next write, which may
    replace ``obj`` but keep some of them (an adaptive session's new ``adaptive`` table, same candidates)."""
    if isinstance(obj, dict) and level <= 1:
        for v in obj.values():
            hit = cache.get(id(v)) if isinstance(v, (dict, list)) else None
            if hit is not None and hit[0] is v and hit[1] == level + 1:
                memo[id(v)] = hit
                _carry(v, level + 1, memo, cache)


def write_json_atomic(path: Path, obj: Mapping[str, Any], *, plain: bool = False, cache: dict | None = None) -> dict:
    """Write ``obj`` as JSON to ``path`` atomically: a temporary file, fsync, rename, fsync the directory.

    ``plain``: ``obj`` is JSON data already (what :func:`gonio.store.records._jsonable` returns), not converted
    again. ``cache``: the encoded text of the last write's containers (what this function returns; see
    :func:`_encode`): the values of ``obj`` unchanged since (the same objects) are not encoded again — the
    caller must not have changed them in place. Returns this write's cache."""
    tmp = path.with_name(f".{path.name}.tmp")
    memo: dict = {}
    data = (_encode(obj if plain else _jsonable(obj), 0, memo, cache) + "\n").encode()
    _write_new_file(tmp, data)
    try:
        os.replace(tmp, path)  # replaces a link itself, never its target
    except OSError:
        _unlink_quietly(tmp)
        raise
    _fsync_dir(path.parent)
    return memo


def _unlink_quietly(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def write_failed(path: Path, exc: OSError) -> DataError:
    """The one line for a session file that could not be written (a full disk, a read-only mount, or a planted
    directory, FIFO or symbolic link at one of the store's names), saying that nothing stored is lost."""
    why = {errno.ELOOP: "is a symbolic link; a session's files are never written through links",
           errno.EISDIR: "is a directory, not a file gonio may write; remove it",
           errno.ENXIO: "is not a regular file (a FIFO?); remove it"}.get(exc.errno, f"cannot write: {exc.strerror or exc}")
    return DataError(f"{path}: {why}; every record already in {SAMPLES} is kept, and `gonio resume` continues "
                     "the session once this is fixed")


def _write_new_file(path: Path, data: bytes) -> None:
    """Write ``data`` to a new file at ``path`` (an old file or link of that name is removed first;
    ``O_EXCL | O_NOFOLLOW``: nothing outside the directory is ever written through a planted link)."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
        os.fsync(fd)
    except BaseException:  # e.g. ENOSPC: no partial file is left under the temporary name
        os.close(fd)
        _unlink_quietly(path)
        raise
    os.close(fd)


# -- reading, never through a link -------------------------------------------------------------------
#: Largest manifest accepted, bytes.
MAX_MANIFEST = 64 * 1024 * 1024
#: Largest samples file read into memory, bytes.
MAX_SAMPLES_FILE = 8 * 1024 ** 3
QUARANTINE = "quarantine.jsonl"


def read_file_nofollow(path: Path, limit: int, what: str) -> bytes:
    """The bytes of a regular file at ``path``, opened with ``O_NOFOLLOW`` (a link is refused, not
    followed) and at most ``limit`` bytes; :class:`DataError` naming the file otherwise."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise DataError(f"{path}: {what} is missing") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise DataError(f"{path}: is a symbolic link; a session's files are never followed through links") from None
        raise DataError(f"{path}: cannot read {what}: {exc.strerror}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise DataError(f"{path}: {what} is not a regular file")
        if st.st_size > limit:
            raise DataError(f"{path}: {what} of {st.st_size} bytes is larger than {limit}")
        chunks, left = [], st.st_size + 1
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 24))
            if not chunk:
                break
            chunks.append(chunk)
            left -= len(chunk)
        data = b"".join(chunks)
        if len(data) > limit:
            raise DataError(f"{path}: {what} is larger than {limit} bytes")
        return data
    finally:
        os.close(fd)


def scan_samples(path: Path) -> ScanResult:
    """Read and check a samples file (:func:`gonio.store.records.scan_bytes`): every good record,
    the damaged lines with their reasons, and a torn last line."""
    return scan_bytes(read_file_nofollow(Path(path), MAX_SAMPLES_FILE, "samples file"))


def _samples_path(d: Path, manifest: Mapping[str, Any]) -> Path:
    """``d / samples.jsonl``; a manifest naming any other file is refused (it could point outside)."""
    name = manifest.get("samples_file", SAMPLES)
    if name != SAMPLES:
        raise DataError(f"{d / MANIFEST}: samples_file = {str(name)[:80]!r}: only {SAMPLES!r} inside the session "
                        "directory is ever read or written")
    return d / SAMPLES


def _list(value) -> list:
    """A manifest's list field as a list (a crafted or damaged value reads as empty, never a traceback)."""
    return list(value) if isinstance(value, list) else []


def _quarantine(d: Path, path: Path, scan: ScanResult) -> dict:
    """Copy the damaged lines to ``quarantine.jsonl`` (appended, fsynced: nothing is thrown away), then
    replace ``samples.jsonl`` by its good lines (a new file renamed over it). Returns the repair entry."""
    data = read_file_nofollow(path, MAX_SAMPLES_FILE, "samples file")[: scan.good_end]
    bad = [(a, b) for _ln, a, b, _why in scan.damaged]
    # O_NONBLOCK: a FIFO planted at this name is refused (ENXIO, or not S_ISREG), never waited on for a reader
    qfd = os.open(d / QUARANTINE, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
    try:
        if not stat.S_ISREG(os.fstat(qfd).st_mode):
            raise OSError(errno.ENXIO, "not a regular file", str(d / QUARANTINE))
        for a, b in bad:
            chunk = data[a:b] if data[a:b].endswith(b"\n") else data[a:b] + b"\n"
            view = memoryview(chunk)
            while view:
                view = view[os.write(qfd, view):]
        os.fsync(qfd)
    finally:
        os.close(qfd)
    keep, pos = [], 0
    for a, b in bad:
        keep.append(data[pos:a])
        pos = b
    keep.append(data[pos:])
    tmp = d / f".{SAMPLES}.repair"
    _write_new_file(tmp, b"".join(keep))
    os.replace(tmp, path)
    _fsync_dir(d)
    return {"at": _wall(), "quarantined": [{"line": ln, "reason": why} for ln, _a, _b, why in scan.damaged],
            "file": QUARANTINE}


def _killed_run(manifest: Mapping[str, Any], scan: ScanResult) -> dict | None:
    """The ``runs`` entry of a run that was killed (a ``running`` mark and no recorded end): its poses
    and samples, and its lab time from its records' ``lab_time_s`` (the lab clock of that run)."""
    running = manifest.get("running")
    if not isinstance(running, Mapping) or manifest.get("exit_status") is not None:
        return None
    first = running.get("records_before", 0)
    if isinstance(first, bool) or not isinstance(first, int) or first < 0:
        first = 0
    mine = [pose for pose, _ln in scan.order[first:]]
    times = [scan.records[p][1].get("run_lab_time_s", scan.records[p][1].get("lab_time_s"))
             for p in mine if p in scan.records]
    times = [float(t) for t in times if isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t)]
    return {"status": "killed", "poses": len(mine), "samples": sum(len(scan.records[p][0]) for p in set(mine)),
            "lab_time_s": max(times) if times else 0.0, "wall_time_s": None, "stopped": None}


def _read_manifest(d: Path, known: tuple[bytes, dict] | None = None) -> dict:
    """The manifest of session directory ``d``, checked. ``known``: ``(bytes, manifest)`` of an earlier read
    (:func:`read_manifest_bytes`), whose manifest is returned, not parsed again, when the file still holds those
    bytes (an adaptive session's manifest is up to ~1 MB)."""
    return read_manifest_bytes(d, known)[1]


def read_manifest_bytes(d: Path, known: tuple[bytes, dict] | None = None) -> tuple[bytes, dict]:
    """``(the file's bytes, the manifest)`` of session directory ``d``: :func:`_read_manifest` with the bytes it
    parsed, for a later read (:meth:`SessionStore.open`'s ``known``) to compare with."""
    path = d / MANIFEST
    if d.is_file():
        raise DataError(f"{d}: is a file, not a session directory (the directory gonio measure --out made)")
    if not d.exists():
        raise DataError(f"{d}: no such session directory")
    if not path.exists() and not path.is_symlink():
        raise DataError(f"{path}: no session manifest (is {d} a session directory?)")
    data = read_file_nofollow(path, MAX_MANIFEST, "manifest")
    if known is not None and known[0] == data:
        return known
    try:
        manifest = json.loads(data.decode("utf-8"))
    except RecursionError:
        raise DataError(f"{path}: unreadable manifest (JSON nested too deeply)") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: unreadable manifest ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != STORE_FORMAT:
        got = manifest.get("format") if isinstance(manifest, dict) else type(manifest).__name__
        raise DataError(f"{path}: format = {got!r}: expected a gonio session manifest, format {STORE_FORMAT}")
    return data, manifest


def missing_poses(manifest, present: int) -> int:
    """Poses the manifest counted at its last stop (``pose_count``) that ``samples.jsonl`` no longer holds,
    neither as good nor as damaged records nor moved to quarantine by a repair: records lost (a truncated
    or replaced file). 0 when none are missing or the manifest does not say."""
    count = manifest.get("pose_count")
    if isinstance(count, bool) or not isinstance(count, int):
        return 0
    repairs = manifest.get("repairs") if isinstance(manifest.get("repairs"), list) else []
    moved = sum(len(r["quarantined"]) for r in repairs if isinstance(r, dict) and isinstance(r.get("quarantined"), list))
    return max(0, count - present - moved)


def plan_pose_count(manifest) -> int | None:
    """The number of poses of the manifest's plan (``plan.n_poses``, else its ``poses``' count); None when the
    manifest does not say or says something that is not a pose count (a crafted or damaged plan)."""
    plan = manifest.get("plan") if isinstance(manifest, Mapping) else None
    if not isinstance(plan, Mapping):
        return None
    poses = plan.get("poses")
    n = plan.get("n_poses", len(poses) if isinstance(poses, list) else None)
    return n if isinstance(n, int) and not isinstance(n, bool) and 0 <= n <= MAX_POSE else None


def poses_beyond_plan(manifest, poses) -> list[int]:
    """The pose indices among ``poses`` (a session's records) that its plan does not have — a record of pose 500
    in a 38-pose plan comes from another session or an edit, not from this plan: its samples are not this
    session's. [] when the plan's size is not known."""
    n = plan_pose_count(manifest)
    return [] if n is None else sorted(int(p) for p in poses if p >= n)


def load_session(path) -> tuple[dict, SampleSet]:
    """``(manifest, samples)`` of a session directory, read-only; a torn last record is ignored, and records of
    poses the plan does not have (:func:`poses_beyond_plan`) are left out with a warning.

    Samples are in pose order, one record per pose. Raises :class:`DataError` naming the file.
    """
    manifest, samples, _ = load_session_records(path)
    return manifest, samples


def load_session_records(path, manifest: Mapping[str, Any] | None = None) -> tuple[dict, SampleSet, dict]:
    """:func:`load_session` plus each pose's record metadata (``{pose: meta}``: joints, board pose, ...).

    ``manifest``: the directory's manifest as last written, from a caller that holds it (:meth:`SessionStore.samples`):
    not read and parsed again (an adaptive session's is up to ~1 MB, read after every round), and not changed (the
    result's is a shallow copy)."""
    d = Path(path)
    if d.is_file() and d.name == MANIFEST:
        d = d.parent
    manifest = _read_manifest(d) if manifest is None else dict(manifest)
    scan = scan_samples(_samples_path(d, manifest))
    if scan.damaged:  # every good sample is kept; say what was skipped (one line through the CLI)
        import warnings

        manifest["damaged_records"] = [{"line": ln, "bytes": [a, b], "reason": why} for ln, a, b, why in scan.damaged]
        warnings.warn(f"{_samples_path(d, manifest)}: {len(scan.damaged)} damaged record(s) skipped: "
                      f"{scan.describe_damage()}; `gonio repair {d}` quarantines them and `gonio resume {d}` "
                      "measures their poses again", stacklevel=2)
    beyond = poses_beyond_plan(manifest, scan.records)
    if beyond:
        import warnings

        for p in beyond:
            del scan.records[p]
        warnings.warn(f"{_samples_path(d, manifest)}: {len(beyond)} record(s) of poses the plan does not have "
                      f"(pose {', '.join(map(str, beyond[:5]))}{' …' if len(beyond) > 5 else ''}; the plan has "
                      f"{plan_pose_count(manifest)}) left out: not this session's measurements", stacklevel=2)
    return manifest, scan.samples(), {p: meta for p, (_, meta) in scan.records.items()}


# -- the writer ------------------------------------------------------------------------------------
class SessionStore:
    """A session directory open for appending (one writer at a time, enforced with ``flock``).

    Use :meth:`create` for a new session and :meth:`open` to resume one; then :meth:`append` once
    per measured pose and :meth:`finish` at the end. The object keeps the file open; :meth:`close`
    (or the context manager) releases it.
    """

    def __init__(self, directory: Path, manifest: dict, fd: int, scan: ScanResult):
        self.directory = directory
        self._manifest = manifest
        self._encoded: dict | None = None  #: the last manifest write's text of its containers (write_json_atomic)
        self._manifest_text: str | None = None  #: json.dumps of the manifest as last written (``manifest``'s copy)
        self._fd = fd
        self._records = {p: len(s) for p, (s, _m) in scan.records.items()}
        #: the ``meta`` of the last good record (the pose measured last), None in an empty store: a resumed run
        #: continues from it (:class:`gonio.session.runner.SessionRunner` reuses its board pose when the camera
        #: is where it was). Read from the file, so unchecked: its reader validates what it uses
        self.last_meta: dict | None = scan.records[scan.order[-1][0]][1] if scan.order else None
        self.n_records = scan.n_records
        self.torn = scan.torn  #: why a torn last record was dropped on open (None if none was)
        self.repaired: dict | None = None  #: the damaged records moved to quarantine.jsonl on open, if any

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def create(cls, directory, manifest: Mapping[str, Any]) -> "SessionStore":
        """Start a new session in ``directory`` (which must not exist, or be an empty directory) with
        ``manifest``, atomically: the session is built in a hidden directory beside it and renamed into
        place, so a kill at any instant leaves either no session or a complete, resumable one.

        The store adds the format, software version, units, cosine convention, start time, the
        samples file name and ``exit_status = None``. Refuses with :class:`ConfigError` (nothing
        overwritten) a directory that holds anything, a file, or a place that is not writable.
        """
        from gonio import __version__

        d = Path(directory)
        if d.is_symlink():
            raise ConfigError.field(None, "session directory", str(d), "is a symbolic link; name a new directory")
        if d.exists() and not d.is_dir():
            raise ConfigError.field(None, "session directory", str(d), "exists and is not a directory")
        if d.is_dir() and any(d.iterdir()):
            held = "holds another session" if (d / MANIFEST).exists() or (d / SAMPLES).exists() else "is not empty"
            raise ConfigError.field(None, "session directory", str(d),
                                    f"{held}; choose a new directory (or resume the session)")
        full = {
            "format": STORE_FORMAT,
            "software": {"name": "gonio", "version": __version__},
            "units": dict(UNITS),
            "values": COSINE_CONVENTION,
            **_jsonable(dict(manifest)),
            "samples_file": SAMPLES,
            "started": _wall(),
            "stopped": None,
            "exit_status": None,
            "sample_count": 0,
            "pose_count": 0,
            "running": {"records_before": 0, "started": _wall()},
        }
        try:
            d.parent.mkdir(parents=True, exist_ok=True)
            work = d.parent / f".{d.name}.gonio-new-{os.getpid()}-{secrets.token_hex(4)}"
            work.mkdir()
        except OSError as exc:
            raise ConfigError.field(None, "session directory", str(d), f"not writable ({exc.strerror})") from None
        fd = -1
        try:
            fd = os.open(work / SAMPLES, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND | os.O_NOFOLLOW, 0o644)
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            write_json_atomic(work / MANIFEST, full)
            os.fsync(fd)
            _fsync_dir(work)
            os.rename(work, d)  # atomic; replaces an empty directory of that name
            _fsync_dir(d.parent)
        except (OSError, TypeError, ValueError) as exc:
            if fd >= 0:
                os.close(fd)
            for name in (SAMPLES, MANIFEST, f".{MANIFEST}.tmp"):
                try:
                    os.unlink(work / name)
                except OSError:
                    pass
            try:
                work.rmdir()
            except OSError:
                pass
            if isinstance(exc, OSError) and exc.errno in (errno.ENOTEMPTY, errno.EEXIST):
                raise ConfigError.field(None, "session directory", str(d), "was created by someone else meanwhile") from None
            why = exc.strerror if isinstance(exc, OSError) else f"manifest is not JSON-able ({exc})"
            raise ConfigError.field(None, "session directory", str(d), f"cannot write the manifest: {why}") from None
        return cls(d, full, fd, ScanResult())

    @classmethod
    def open(cls, directory, *, resume: bool = True, known: tuple[bytes, dict] | None = None) -> "SessionStore":
        """Reopen a session to resume it: checks every record, drops a torn last line (cutting the file
        back), moves damaged records to ``quarantine.jsonl`` (:meth:`repair`; their poses are measured
        again), and marks the manifest as running again (a ``resumes`` entry; ``resume=False`` opens it
        only to record its end, e.g. a session with nothing left). A run that was killed (no recorded
        end) gets its ``runs`` entry now, from its records' lab time, so the session's lab time keeps it.

        ``known``: :func:`read_manifest_bytes` of the directory from a read before this one (a resume's checks);
        the store takes its manifest over (the caller must not use it after) when the file, read again here,
        holds the same bytes, instead of parsing them again."""
        d = Path(directory)
        manifest = _read_manifest(d, known)
        path = _samples_path(d, manifest)
        try:
            fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_NOFOLLOW)
        except OSError as exc:
            why = "is a symbolic link" if exc.errno == errno.ELOOP else exc.strerror
            raise DataError(f"{path}: cannot open samples file for appending ({why})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EAGAIN, errno.EACCES):
                raise ConfigError.field(None, "session directory", str(d), "is in use by another process") from None
            raise
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):
                raise DataError(f"{path}: samples file is not a regular file")
            scan = scan_samples(path)
            if scan.torn is not None:
                os.ftruncate(fd, scan.good_end)
                os.fsync(fd)
            repaired = None
            if scan.damaged:
                repaired = _quarantine(d, path, scan)
                os.close(fd)
                fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_NOFOLLOW)
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                manifest["repairs"] = [*_list(manifest.get("repairs")), repaired]
            killed = _killed_run(manifest, scan)
            if killed is not None:
                manifest["runs"] = [*_list(manifest.get("runs")), killed]
            if resume or scan.torn is not None or repaired is not None or killed is not None:
                if resume:
                    manifest["resumes"] = _list(manifest.get("resumes"))
                    manifest["resumes"].append(
                        {"at": _wall(), "previous_exit_status": manifest.get("exit_status"), "dropped_torn_record": scan.torn})
                manifest["exit_status"] = None if resume else manifest.get("exit_status")
                manifest["stopped"] = None if resume else manifest.get("stopped")
                manifest["running"] = {"records_before": scan.n_records, "started": _wall()} if resume else None
                write_json_atomic(d / MANIFEST, manifest)
        except BaseException as exc:
            try:
                os.close(fd)
            except OSError:
                pass
            if isinstance(exc, OSError):  # quarantine.jsonl, the repaired copy or the manifest could not be written
                raise write_failed(Path(exc.filename) if exc.filename else d, exc) from None
            raise
        store = cls(d, manifest, fd, scan)
        store.repaired = repaired
        return store

    @classmethod
    def repair(cls, directory) -> dict | None:
        """Move damaged records of a session to ``quarantine.jsonl`` and cut a torn last line, without
        resuming it; returns what was quarantined (None if nothing was damaged)."""
        store = cls.open(directory, resume=False)
        try:
            return store.repaired
        finally:
            store.close()

    # -- use ------------------------------------------------------------------------------------
    @property
    def manifest(self) -> dict:
        """The manifest as last written (a copy)."""
        if self._manifest_text is None:  # encoded once per write; each reader gets its own copy
            self._manifest_text = json.dumps(self._manifest)
        return json.loads(self._manifest_text)

    def samples(self) -> SampleSet:
        """The stored samples as :func:`load_session` reads them from :attr:`directory`, with the manifest this store
        last wrote instead of the file's (the same data) parsed again."""
        return load_session_records(self.directory, self._manifest)[1]

    def has_manifest_entry(self, key: str) -> bool:
        """Whether the manifest has a top-level field ``key`` (whatever its value), without copying it."""
        return key in self._manifest

    def manifest_entry(self, key: str) -> Any:
        """The stored value of the manifest's top-level field ``key`` (None if absent), not a copy: read it and
        pass its entries back to :meth:`update_manifest` unchanged, never change it in place."""
        return self._manifest.get(key)

    def append(self, pose_index: int, samples: SampleSet, meta: Mapping[str, Any] | None = None) -> None:
        """Append the samples of plan pose ``pose_index``, durably (write, flush, fsync) before returning.

        The ``pose`` column is set to ``pose_index``. A pose appended again replaces its earlier
        record when read (its samples are not duplicated).
        """
        if self._fd < 0:
            raise DataError(f"{self.directory / SAMPLES}: session store is closed")
        pose_index = int(pose_index)
        if pose_index < 0:
            raise ConfigError.field(None, "pose_index", pose_index, "must be >= 0")
        samples = SampleSet(**{**samples.to_dict(), "pose": np.full(len(samples), pose_index, dtype=np.int64)})
        line = encode_record(pose_index, samples, meta or {})
        size = os.fstat(self._fd).st_size
        try:
            view = memoryview(line)
            while view:
                view = view[os.write(self._fd, view):]
            os.fsync(self._fd)
        except OSError as exc:  # e.g. a full disk: cut what landed, so the next append starts a clean line
            try:
                os.ftruncate(self._fd, size)
                os.fsync(self._fd)
            except OSError:
                pass  # the partial line has no newline: a reader drops it as torn
            raise write_failed(self.directory / SAMPLES, exc) from None
        self._records[pose_index] = len(samples)
        self.n_records += 1
        self.last_meta = dict(meta or {})

    def done_poses(self) -> set[int]:
        """Indices of the plan poses that have a record."""
        return set(self._records)

    @property
    def sample_count(self) -> int:
        """Samples stored, one record per pose."""
        return sum(self._records.values())

    def remaining(self, plan=None) -> np.ndarray:
        """Indices of ``plan``'s poses (a :class:`~gonio.plan.Plan`, its dict, or a pose count; default:
        the manifest's ``plan``) still to measure, in plan order."""
        if plan is None:
            plan = self._manifest.get("plan")
            if plan is None:
                raise DataError(f"{self.directory / MANIFEST}: no plan in the manifest")
        if isinstance(plan, Mapping):
            n = plan.get("n_poses", len(plan.get("poses", ()) or ()))
            if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= MAX_POSE:
                raise DataError(f"{self.directory / MANIFEST}: plan.n_poses = {str(n)[:40]}: not a pose count")
        elif isinstance(plan, (int, np.integer)):
            n = int(plan)
        else:
            n = len(plan)
        done = self._records
        return np.array([i for i in range(n) if i not in done], dtype=np.int64)

    def update_manifest(self, **fields: Any) -> None:
        """Set top-level manifest fields (e.g. calibration results) and rewrite it atomically.

        An entry of a table field that is the stored entry itself (:meth:`manifest_entry`'s, e.g. an adaptive
        session's ~1 MB of candidate poses, written again with new rounds every round) is neither converted
        nor encoded again (:func:`write_json_atomic`'s cache)."""
        reserved = {"format", "samples_file"} & set(fields)  # the store's own fields
        if reserved:
            raise ConfigError.field(None, "manifest", sorted(reserved)[0], "is managed by the store")
        self._manifest_text = None
        for key, value in fields.items():
            old = self._manifest.get(str(key))
            if type(value) is dict and type(old) is dict and all(type(k) is str for k in value):
                self._manifest[str(key)] = {k: v if k in old and v is old[k] else _jsonable(v)
                                            for k, v in value.items()}
            else:
                self._manifest[str(key)] = _jsonable(value)
        try:
            try:
                self._encoded = write_json_atomic(self.directory / MANIFEST, self._manifest, plain=True,
                                                  cache=self._encoded)
            except (TypeError, ValueError):  # a non-finite number the session's file held: converted, as before
                self._encoded = write_json_atomic(self.directory / MANIFEST, self._manifest)
        except OSError as exc:
            raise write_failed(Path(exc.filename) if exc.filename else self.directory / MANIFEST, exc) from None

    def finish(self, exit_status: str, **fields: Any) -> None:
        """Record how the session ended (``"completed"``, ``"interrupted"``, ``"error: ..."``), the stop
        time and the sample count, then close the samples file.

        A ``last_run`` summary (the runner's) is also appended, abridged, to the manifest's ``runs`` list:
        one entry per run (the first and each resume), so the session's total lab time is their sum."""
        stopped = _wall()
        run = fields.get("last_run")
        if isinstance(run, Mapping):
            entry = {k: run.get(k) for k in RUN_KEYS if k in run}
            fields["runs"] = [*_list(self._manifest.get("runs")), {**entry, "stopped": stopped}]
        self.update_manifest(**fields, exit_status=str(exit_status), stopped=stopped, running=None,
                             sample_count=self.sample_count, pose_count=len(self._records))
        self.close()

    def close(self) -> None:
        """Release the samples file and its lock (idempotent)."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __enter__(self) -> "SessionStore":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):  # pragma: no cover - safety net
        try:
            self.close()
        except Exception:
            pass
