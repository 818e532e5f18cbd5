"""The crash-safe session store: a directory with a self-describing manifest and an append-only,
checksummed samples file (docs/architecture.md §3: nothing measured is lost).

Layout of a session directory::

    manifest.json    what/why/how and how it ended; replaced atomically (tmp + fsync + rename)
    samples.jsonl    one record per measured pose, appended, flushed and fsynced per record

A record is one line ``CCCCCCCC <payload>\\n``: the CRC-32 (ISO-HDLC, :func:`zlib.crc32`) of the payload
bytes as 8 lowercase hex digits, a space, and the payload, a JSON object::

    {"pose": 17, "n": 1, "cols": {"wi": ["<f8", [1, 3], "<base64>"], ...}, "meta": {...}}

Array columns are the columns of :class:`gonio.samples.SampleSet`, stored as base64 of their
little-endian bytes so float64 values (NaN included) round-trip bit for bit; ``meta`` holds per-pose
data (measured joint angles, exposures, photodiode value, lab-clock timestamps). No pickle.

Crash rules: a record counts only when its newline is on disk. On :meth:`SessionStore.open` a torn or
corrupted *last* record (the one being written when the process died) is dropped and the file is cut
back to the last good record; a bad record anywhere else is a :class:`DataError` naming the file and
line. A pose recorded twice (re-measured) keeps its *last* record: samples are never duplicated.
"""

from __future__ import annotations

import base64
import errno
import fcntl
import json
import math
import os
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from gonio.errors import ConfigError, DataError
from gonio.samples import SampleSet

__all__ = ["SessionStore", "load_session", "scan_samples", "ScanResult", "MANIFEST", "SAMPLES",
           "STORE_FORMAT", "COSINE_CONVENTION"]

MANIFEST = "manifest.json"
SAMPLES = "samples.jsonl"
#: The fields of a run's summary kept in the manifest's ``runs`` list (one entry per run, see ``finish``).
RUN_KEYS = ("status", "poses", "samples", "lab_time_s", "wall_time_s")
STORE_FORMAT = 1
#: What the stored ``f`` values are (docs/architecture.md §3).
COSINE_CONVENTION = "BRDF, not BRDF*cos"
UNITS = {"angles": "rad", "f": "1/sr", "sigma": "1/sr", "time": "s", "exposure": "s", "length": "m"}
_DTYPES = {"<f8", "<i8"}


def _wall() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


def _jsonable(obj: Any) -> Any:
    if hasattr(obj, "to_dict") and callable(obj.to_dict):  # e.g. a gonio.plan.Plan
        return _jsonable(obj.to_dict())
    if isinstance(obj, Mapping):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return repr(obj)  # "nan"/"inf": keep the file standard JSON
    return obj


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_json_atomic(path: Path, obj: Mapping[str, Any]) -> None:
    """Write ``obj`` as JSON to ``path`` atomically: a temporary file, fsync, rename, fsync the directory."""
    tmp = path.with_name(f".{path.name}.tmp")
    data = (json.dumps(_jsonable(obj), indent=1, allow_nan=False) + "\n").encode()
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


# -- records ---------------------------------------------------------------------------------------
def encode_record(pose_index: int, samples: SampleSet, meta: Mapping[str, Any]) -> bytes:
    """One record line (with its newline) for ``samples`` of plan pose ``pose_index``."""
    cols = {}
    for name, arr in samples.to_dict().items():
        a = np.ascontiguousarray(arr)
        a = a.astype(a.dtype.newbyteorder("<"), copy=False)
        cols[name] = [a.dtype.str, list(a.shape), base64.b64encode(a.tobytes()).decode("ascii")]
    payload = json.dumps({"pose": int(pose_index), "n": len(samples), "cols": cols, "meta": _jsonable(meta)},
                         separators=(",", ":"), allow_nan=False).encode()
    return b"%08x " % zlib.crc32(payload) + payload + b"\n"


def decode_record(line: bytes) -> tuple[int, SampleSet, dict]:
    """Inverse of :func:`encode_record` for a line without its newline; ``ValueError`` says what is wrong."""
    if len(line) < 10 or line[8:9] != b" ":
        raise ValueError("no checksum field")
    try:
        crc = int(line[:8], 16)
    except ValueError:
        raise ValueError("checksum field is not hexadecimal") from None
    payload = line[9:]
    if zlib.crc32(payload) != crc:
        raise ValueError("CRC-32 mismatch")
    obj = json.loads(payload)
    pose, n, cols = int(obj["pose"]), int(obj["n"]), obj["cols"]
    arrays = {}
    for name, (dtype, shape, b64) in cols.items():
        if dtype not in _DTYPES:
            raise ValueError(f"column {name!r} has dtype {dtype!r}")
        arr = np.frombuffer(base64.b64decode(b64, validate=True), dtype=np.dtype(dtype)).reshape(shape)
        arrays[name] = arr.astype(arr.dtype.newbyteorder("="))
    samples = SampleSet.from_dict(arrays, source="record")
    if len(samples) != n:
        raise ValueError(f"record says {n} samples, holds {len(samples)}")
    return pose, samples, dict(obj.get("meta", {}))


@dataclass
class ScanResult:
    """What :func:`scan_samples` found in a samples file."""

    records: dict[int, tuple[SampleSet, dict]] = field(default_factory=dict)  #: pose -> last record
    n_records: int = 0  #: good records, duplicates included
    n_duplicates: int = 0  #: records that replaced an earlier record of the same pose
    good_end: int = 0  #: byte offset just after the last good record
    torn: str | None = None  #: why the last record was dropped, if it was

    def samples(self) -> SampleSet:
        """All samples, one record per pose, in pose order; ``pose`` column = the pose index."""
        sets = []
        for pose in sorted(self.records):
            s = self.records[pose][0]
            sets.append(SampleSet(**{**s.to_dict(), "pose": np.full(len(s), pose, dtype=np.int64)}))
        return SampleSet.concat(sets) if sets else SampleSet.empty()


def scan_samples(path: Path) -> ScanResult:
    """Read and check a samples file. A bad last record is reported in ``torn``; a bad record before
    it raises :class:`DataError` naming the file and the line."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise DataError(f"{path}: samples file is missing") from None
    except OSError as exc:
        raise DataError(f"{path}: cannot read samples file: {exc.strerror}") from None
    res = ScanResult()
    pos, lineno = 0, 0
    while pos < len(data):
        lineno += 1
        nl = data.find(b"\n", pos)
        if nl < 0:
            res.torn = f"line {lineno}: incomplete record ({len(data) - pos} bytes, no newline)"
            break
        try:
            pose, samples, meta = decode_record(data[pos:nl])
        except (ValueError, KeyError, TypeError, DataError) as exc:
            if data.find(b"\n", nl + 1) < 0 and not data[nl + 1:].strip():
                res.torn = f"line {lineno}: corrupted last record ({exc})"
                break
            raise DataError(f"{path}: line {lineno}: corrupted record ({exc})") from None
        if pose < 0:
            raise DataError(f"{path}: line {lineno}: pose index {pose} is negative")
        res.n_duplicates += pose in res.records
        res.records[pose] = (samples, meta)
        res.n_records += 1
        pos = res.good_end = nl + 1
    return res


def _read_manifest(d: Path) -> dict:
    path = d / MANIFEST
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DataError(f"{path}: no session manifest (is {d} a session directory?)") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: unreadable manifest ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != STORE_FORMAT:
        got = manifest.get("format") if isinstance(manifest, dict) else type(manifest).__name__
        raise DataError(f"{path}: format = {got!r}: expected a gonio session manifest, format {STORE_FORMAT}")
    return manifest


def load_session(path) -> tuple[dict, SampleSet]:
    """``(manifest, samples)`` of a session directory, read-only; a torn last record is ignored.

    Samples are in pose order, one record per pose. Raises :class:`DataError` naming the file.
    """
    d = Path(path)
    if d.is_file() and d.name == MANIFEST:
        d = d.parent
    manifest = _read_manifest(d)
    scan = scan_samples(d / manifest.get("samples_file", SAMPLES))
    return manifest, scan.samples()


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
        self._fd = fd
        self._records = {p: len(s) for p, (s, _m) in scan.records.items()}
        self.n_records = scan.n_records
        self.torn = scan.torn  #: why a torn last record was dropped on open (None if none was)

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def create(cls, directory, manifest: Mapping[str, Any]) -> "SessionStore":
        """Start a new session in ``directory`` (created if missing) with ``manifest``.

        The store adds the format, software version, units, cosine convention, start time, the
        samples file name and ``exit_status = None``. Refuses with :class:`ConfigError` (nothing
        overwritten) a directory that holds another session, is a file, or is not writable.
        """
        from gonio import __version__

        d = Path(directory)
        if d.exists() and not d.is_dir():
            raise ConfigError.field(None, "session directory", str(d), "exists and is not a directory")
        for name in (MANIFEST, SAMPLES):
            if (d / name).exists():
                raise ConfigError.field(None, "session directory", str(d),
                                        f"holds another session ({name} exists); choose a new directory or resume it")
        try:
            d.mkdir(parents=True, exist_ok=True)
            fd = os.open(d / SAMPLES, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o644)
        except FileExistsError:
            raise ConfigError.field(None, "session directory", str(d), "holds another session") from None
        except OSError as exc:
            raise ConfigError.field(None, "session directory", str(d), f"not writable ({exc.strerror})") from None
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
        }
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            write_json_atomic(d / MANIFEST, full)
        except (OSError, TypeError, ValueError) as exc:
            os.close(fd)
            os.unlink(d / SAMPLES)
            why = exc.strerror if isinstance(exc, OSError) else f"manifest is not JSON-able ({exc})"
            raise ConfigError.field(None, "session directory", str(d), f"cannot write the manifest: {why}") from None
        os.fsync(fd)
        _fsync_dir(d)
        return cls(d, full, fd, ScanResult())

    @classmethod
    def open(cls, directory, *, resume: bool = True) -> "SessionStore":
        """Reopen a session to resume it: checks every record, drops a torn last record (cutting the
        file back to the last good record), and marks the manifest as running again (a ``resumes``
        entry; ``resume=False`` opens it only to record its end, e.g. a session with nothing left)."""
        d = Path(directory)
        manifest = _read_manifest(d)
        path = d / manifest.get("samples_file", SAMPLES)
        try:
            fd = os.open(path, os.O_RDWR | os.O_APPEND)
        except OSError as exc:
            raise DataError(f"{path}: cannot open samples file for appending ({exc.strerror})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EAGAIN, errno.EACCES):
                raise ConfigError.field(None, "session directory", str(d), "is in use by another process") from None
            raise
        try:
            scan = scan_samples(path)
            if scan.torn is not None:
                os.ftruncate(fd, scan.good_end)
                os.fsync(fd)
            if resume or scan.torn is not None:
                manifest.setdefault("resumes", []).append(
                    {"at": _wall(), "previous_exit_status": manifest.get("exit_status"), "dropped_torn_record": scan.torn})
                manifest["exit_status"] = None
                manifest["stopped"] = None
                write_json_atomic(d / MANIFEST, manifest)
        except BaseException:
            os.close(fd)
            raise
        return cls(d, manifest, fd, scan)

    # -- use ------------------------------------------------------------------------------------
    @property
    def manifest(self) -> dict:
        """The manifest as last written (a copy)."""
        return json.loads(json.dumps(self._manifest))

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
        view = memoryview(line)
        while view:
            view = view[os.write(self._fd, view):]
        os.fsync(self._fd)
        self._records[pose_index] = len(samples)
        self.n_records += 1

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
            n = int(plan.get("n_poses", len(plan.get("poses", ()))))
        elif isinstance(plan, (int, np.integer)):
            n = int(plan)
        else:
            n = len(plan)
        done = self._records
        return np.array([i for i in range(n) if i not in done], dtype=np.int64)

    def update_manifest(self, **fields: Any) -> None:
        """Set top-level manifest fields (e.g. calibration results) and rewrite it atomically."""
        reserved = {"format", "samples_file"} & set(fields)
        if reserved:
            raise ConfigError.field(None, "manifest", sorted(reserved)[0], "is managed by the store")
        self._manifest.update(_jsonable(fields))
        write_json_atomic(self.directory / MANIFEST, self._manifest)

    def finish(self, exit_status: str, **fields: Any) -> None:
        """Record how the session ended (``"completed"``, ``"interrupted"``, ``"error: ..."``), the stop
        time and the sample count, then close the samples file.

        A ``last_run`` summary (the runner's) is also appended, abridged, to the manifest's ``runs`` list:
        one entry per run (the first and each resume), so the session's total lab time is their sum."""
        stopped = _wall()
        run = fields.get("last_run")
        if isinstance(run, Mapping):
            entry = {k: run.get(k) for k in RUN_KEYS if k in run}
            fields["runs"] = [*(self._manifest.get("runs") or []), {**entry, "stopped": stopped}]
        self.update_manifest(**fields, exit_status=str(exit_status), stopped=stopped,
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
