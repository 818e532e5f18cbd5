"""Records of ``samples.jsonl``: the codec, its validation, and a scan that keeps every good record.

A record is one line ``CCCCCCCC <payload>\\n``: the CRC-32 (ISO-HDLC, :func:`zlib.crc32`) of the payload
bytes as 8 lowercase hex digits, a space, and the payload, a JSON object::

    {"pose": 17, "n": 1, "cols": {"wi": ["<f8", [1, 3], "<base64>"], ...}, "meta": {...}}

Array columns are the columns of :class:`gonio.samples.SampleSet`, stored as base64 of their
little-endian bytes so float64 values (NaN included) round-trip bit for bit; ``meta`` holds per-pose
data. No pickle. (docs/formats.md §1.2.)

A session directory is untrusted input: a record with a valid checksum may still have been crafted.
Every field is checked for type and range, and every size is bounded *before* memory is allocated
(a 10**30 pose index, a shape of 10**12 elements, JSON nested 100,000 deep are one-line errors, not a
MemoryError or a RecursionError).

A scan keeps every good record: a damaged line anywhere (flipped bit, stray newline, crafted fields)
is reported with its line number and reason in :attr:`ScanResult.damaged` and skipped; only an
incomplete *last* line (no newline: the write a crash interrupted) is :attr:`ScanResult.torn`.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import zlib
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from gonio.errors import DataError
from gonio.samples import SampleSet

__all__ = ["encode_record", "decode_record", "ScanResult", "scan_bytes", "MAX_POSE", "MAX_RECORD_SAMPLES"]

_DTYPES = {"<f8", "<i8"}
#: Largest pose index a record may carry (a plan of ten million poses is beyond any rig).
MAX_POSE = 10_000_000
#: Largest number of samples in one record (one pose: tiles of one frame).
MAX_RECORD_SAMPLES = 1_000_000
#: Longest record line, bytes.
MAX_LINE = 256 * 1024 * 1024
#: Deepest JSON nesting accepted in a record's meta.
MAX_DEPTH = 32
_COLUMNS = {name: width for name, width in (("wi", 3), ("wo", 3), ("f", 3), ("sigma", 3), ("flags", None),
                                            ("n_pixels", None), ("pose", None), ("sigma_pose", 3))}
#: Columns a record may leave out (records written before they existed): read as the SampleSet's default.
_OPTIONAL = {"sigma_pose"}


_PLAIN = (int, str, bool, type(None))


def _jsonable(obj: Any) -> Any:
    t = type(obj)  # the built-in types a pose's meta is made of first (none has a to_dict): what the checks below do
    if t is float:
        return obj if math.isfinite(obj) else repr(obj)
    if t in _PLAIN:
        return obj
    if t is dict:
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if t is list or t is tuple:
        return [_jsonable(v) for v in obj]
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


def _int(obj: Mapping, key: str, lo: int, hi: int) -> int:
    v = obj.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ValueError(f"{key} = {str(v)[:40]}: not an integer in [{lo}, {hi}]")
    return v


def _depth(obj: Any, limit: int) -> int:
    """Nesting depth of a parsed JSON value (a scalar or an empty container: 1), or ``limit + 1`` as soon as it is
    deeper than ``limit``. Iterative, level by level (no recursion on crafted input), visiting containers only: a
    non-empty one makes the next level exist, and its scalars need no visit of their own."""
    depth, level = 1, [obj]
    while True:
        children, deeper = [], False
        for cur in level:
            if isinstance(cur, dict):
                values = cur.values()
            elif isinstance(cur, list):
                values = cur
            else:
                continue
            if values:
                deeper = True
                children.extend([v for v in values if isinstance(v, (dict, list))])
        if not deeper:
            return depth
        depth += 1
        if depth > limit:
            return depth
        level = children


def decode_record(line: bytes) -> tuple[int, SampleSet, dict]:
    """Inverse of :func:`encode_record` for a line without its newline; ``ValueError`` says what is
    wrong (checksum, JSON, a field's type or range, a size)."""
    if len(line) > MAX_LINE:
        raise ValueError(f"record of {len(line)} bytes is longer than {MAX_LINE}")
    if len(line) < 10 or line[8:9] != b" ":
        raise ValueError("no checksum field")
    try:
        crc = int(line[:8], 16)
    except ValueError:
        raise ValueError("checksum field is not hexadecimal") from None
    payload = line[9:]
    if zlib.crc32(payload) != crc:
        raise ValueError("CRC-32 mismatch")
    try:
        obj = json.loads(payload)
    except RecursionError:
        raise ValueError("JSON nested too deeply") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"not JSON ({exc})") from None
    if not isinstance(obj, dict) or _depth(obj, MAX_DEPTH) > MAX_DEPTH:
        raise ValueError("not a record object (or nested deeper than {MAX_DEPTH})")
    pose = _int(obj, "pose", 0, MAX_POSE)
    n = _int(obj, "n", 0, MAX_RECORD_SAMPLES)
    cols, meta = obj.get("cols"), obj.get("meta", {})
    if not isinstance(cols, dict) or not set(_COLUMNS) - _OPTIONAL <= set(cols) <= set(_COLUMNS):
        raise ValueError(f"cols must hold exactly the columns {', '.join(_COLUMNS)}")
    if not isinstance(meta, dict):
        raise ValueError("meta must be an object")
    arrays = {}
    for name, entry in cols.items():
        if not (isinstance(entry, list) and len(entry) == 3 and isinstance(entry[0], str)
                and isinstance(entry[1], list) and isinstance(entry[2], str)):
            raise ValueError(f"column {name!r} must be [dtype, shape, base64]")
        dtype, shape, b64 = entry
        if dtype not in _DTYPES:
            raise ValueError(f"column {name!r} has dtype {dtype!r}")
        width = _COLUMNS[name]
        want = [n] if width is None else [n, width]
        if shape != want or any(isinstance(k, bool) for k in shape):
            raise ValueError(f"column {name!r} has shape {str(shape)[:40]}, the record's n = {n} needs {want}")
        nbytes = int(np.prod(want)) * 8
        if len(b64) != 4 * ((nbytes + 2) // 3):  # checked before decoding: no allocation from a crafted size
            raise ValueError(f"column {name!r}: {len(b64)} base64 characters for {nbytes} bytes")
        try:
            raw = base64.b64decode(b64, validate=True)
        except (binascii.Error, ValueError):
            raise ValueError(f"column {name!r}: not base64") from None
        arr = np.frombuffer(raw, dtype=np.dtype(dtype)).reshape(want)
        arrays[name] = arr.astype(arr.dtype.newbyteorder("="))
    if np.any(arrays["pose"] != pose):
        raise ValueError("the pose column differs from the record's pose")
    try:
        samples = SampleSet.from_dict(arrays, source="record")
    except DataError as exc:
        raise ValueError(str(exc)) from None
    return pose, samples, meta


@dataclass
class ScanResult:
    """What a scan of a samples file found."""

    records: dict[int, tuple[SampleSet, dict]] = field(default_factory=dict)  #: pose -> last record
    n_records: int = 0  #: good records, duplicates included
    n_duplicates: int = 0  #: records that replaced an earlier record of the same pose
    good_end: int = 0  #: byte offset just after the last complete line
    torn: str | None = None  #: why the last (incomplete) line was dropped, if it was
    #: damaged lines: ``(line number, start byte, end byte (after the newline), reason)``
    damaged: list[tuple[int, int, int, str]] = field(default_factory=list)
    #: record order: ``(pose, line number)`` of every good record
    order: list[tuple[int, int]] = field(default_factory=list)

    def samples(self) -> SampleSet:
        """All samples, one record per pose, in pose order; ``pose`` column = the pose index."""
        sets = []
        for pose in sorted(self.records):
            s = self.records[pose][0]
            sets.append(SampleSet(**{**s.to_dict(), "pose": np.full(len(s), pose, dtype=np.int64)}))
        return SampleSet.concat(sets) if sets else SampleSet.empty()

    def describe_damage(self, limit: int = 5) -> str:
        """'line 7 (CRC-32 mismatch), line 9 (...)' for the first ``limit`` damaged lines."""
        parts = [f"line {ln} ({why})" for ln, _a, _b, why in self.damaged[:limit]]
        more = len(self.damaged) - limit
        return ", ".join(parts) + (f" and {more} more" if more > 0 else "")


def scan_bytes(data: bytes) -> ScanResult:
    """Scan the bytes of a samples file (see the module docstring)."""
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
        except (ValueError, KeyError, TypeError, OverflowError, IndexError) as exc:
            res.damaged.append((lineno, pos, nl + 1, str(exc)[:200] or type(exc).__name__))
        else:
            res.n_duplicates += pose in res.records
            res.records[pose] = (samples, meta)
            res.order.append((pose, lineno))
            res.n_records += 1
        pos = res.good_end = nl + 1
    return res
