"""Python codec of the rig-controller protocol (normative text: ``SPEC.md`` beside this file).

Two layers:

* **Frames** — ``00 | E | K | 00`` with ``E = COBS(TYPE SEQ LEN PAYLOAD)`` and ``K`` the CRC-32C of the
  *encoded* bytes ``E`` in five bytes of seven bits each, high bit set (never 0x00). Checking the bytes
  that travel, not the decoded body, is what makes the guarantee of SPEC.md §2.5 hold: every pattern of
  up to 5 flipped bits in a frame is detected (Hamming distance 6 of CRC-32C at these lengths).
  :func:`encode_frame`, :func:`decode_frame`, and the streaming :class:`Decoder`, which takes arbitrary
  byte chunks, never raises, and reports every rejected segment with its verdict.
* **Messages** — the catalogue (:data:`MESSAGES`): field names, wire types, units and ranges of each
  message type. :func:`encode_message` validates values and packs them; :func:`decode_message` unpacks.

This module depends on nothing but the standard library, so the firmware engineer (and the emulator in
``sim/``) can use it alone.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Mapping

PROTOCOL_MAJOR = 2
PROTOCOL_MINOR = 2

MAX_PAYLOAD = 64
HEADER = 3  # TYPE SEQ LEN
MIN_FRAME = HEADER  # a body: TYPE SEQ LEN PAYLOAD
MAX_FRAME = HEADER + MAX_PAYLOAD
CHECK_SIZE = 5  # CRC-32C in five 7-bit groups
MAX_ENCODED = MAX_FRAME + 1 + CHECK_SIZE  # COBS adds one byte per 254 bytes: one byte here; 73
DELIMITER = 0x00

#: Decoder verdicts for rejected segments, in the order the checks are made (SPEC.md §2.4).
VERDICTS = ("overflow", "crc", "cobs", "length")

REPLY_BIT = 0x80

# -- message type codes (SPEC.md §4) -------------------------------------------------------------
HELLO = 0x01
HEARTBEAT = 0x02
SET_LIGHT = 0x03
READ_PHOTODIODE = 0x04
TRIGGER = 0x05
STATUS = 0x06
SET_WATCHDOG = 0x07
ERROR = 0xFF

# -- capability bits (HELLO reply) ---------------------------------------------------------------
CAP_DIMMING = 1 << 0
CAP_PHOTODIODE = 1 << 1
CAP_TRIGGER = 1 << 2
CAP_TEMPERATURE = 1 << 3
CAP_INTERLOCK = 1 << 4

# -- status flag bits (STATUS reply) -------------------------------------------------------------
FLAG_ESTOP = 1 << 0
FLAG_INTERLOCK_OPEN = 1 << 1
FLAG_LIGHT_ON = 1 << 2
FLAG_WATCHDOG_TRIPPED = 1 << 3
FLAG_NOT_CONFIGURED = 1 << 4
FLAG_OVERTEMP = 1 << 5
FLAG_TRIGGER_ACTIVE = 1 << 6

# -- error codes (ERROR reply) -------------------------------------------------------------------
ERR_UNKNOWN_TYPE = 0x01
ERR_BAD_LENGTH = 0x02
ERR_BAD_VALUE = 0x03
ERR_ESTOP = 0x04
ERR_NOT_READY = 0x05
ERR_BUSY = 0x06
ERR_VERSION = 0x07
ERR_OVERTEMP = 0x08
# -- reset causes (STATUS reply, since 2.2; SPEC.md §4.5) ------------------------------------------
RESET_UNKNOWN = 0
RESET_POWER_ON = 1
RESET_EXTERNAL = 2
RESET_BROWN_OUT = 3
RESET_WATCHDOG = 4
RESET_CAUSES = {RESET_UNKNOWN: "unknown", RESET_POWER_ON: "power-on", RESET_EXTERNAL: "external reset",
                RESET_BROWN_OUT: "brown-out", RESET_WATCHDOG: "hardware watchdog"}

#: Status flags that mean the light must be off and nothing may go on (SPEC.md §4.2 "unsafe"): the host stops a
#: session on any of them. WATCHDOG_TRIPPED is unsafe once the host has switched the light on in this session.
UNSAFE_FLAGS = FLAG_ESTOP | FLAG_INTERLOCK_OPEN | FLAG_OVERTEMP | FLAG_WATCHDOG_TRIPPED

#: Requests that are not idempotent: a retry of one (same TYPE, SEQ, payload) is answered from the duplicate
#: cache, never executed again (SPEC.md §5). Every other request is executed on each arrival.
NON_IDEMPOTENT = frozenset({TRIGGER})

ERROR_NAMES = {
    ERR_UNKNOWN_TYPE: "UNKNOWN_TYPE", ERR_BAD_LENGTH: "BAD_LENGTH", ERR_BAD_VALUE: "BAD_VALUE",
    ERR_ESTOP: "ESTOP", ERR_NOT_READY: "NOT_READY", ERR_BUSY: "BUSY", ERR_VERSION: "VERSION",
    ERR_OVERTEMP: "OVERTEMP",
}

# -- timing (SPEC.md §6) -------------------------------------------------------------------------
DEFAULT_WATCHDOG_MS = 10_000
WATCHDOG_MIN_MS = 100
WATCHDOG_MAX_MS = 3_600_000
LEVEL_FULL_SCALE = 65535
MICRO = 1e-6


class ProtocolError(ValueError):
    """A value cannot be encoded, or bytes cannot be decoded (message names the field or verdict)."""


# ================================================================================================
# CRC and COBS
# ================================================================================================
def _crc32c_table() -> tuple[int, ...]:
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0x82F63B78 if c & 1 else c >> 1
        table.append(c)
    return tuple(table)


_CRC32C = _crc32c_table()


def crc32c(data: bytes) -> int:
    """CRC-32C (Castagnoli): reflected polynomial 0x82F63B78 (0x1EDC6F41 normal), init 0xFFFFFFFF,
    reflected in and out, xorout 0xFFFFFFFF — as in iSCSI (RFC 3720 §B.4) and SCTP (RFC 4960).

    Check value (Rocksoft catalogue, "CRC-32/ISCSI"): ``crc32c(b"123456789") == 0xE3069283``.
    Hamming distance 6 for messages of 178 to 5,243 bits, 8 below (Koopman, "32-Bit Cyclic Redundancy
    Codes for Internet Applications", DSN 2002, Table 1).
    """
    crc, table = 0xFFFFFFFF, _CRC32C
    for b in bytes(data):
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc ^ 0xFFFFFFFF


def check_bytes(crc: int) -> bytes:
    """The five check bytes of a 32-bit CRC: bits 0-6, 7-13, 14-20, 21-27, 28-31, each in the low bits of
    a byte whose high bit is set (so none is 0x00); the last byte's bits 4-6 are 0."""
    return bytes(0x80 | ((crc >> (7 * k)) & 0x7F) for k in range(CHECK_SIZE))


def check_value(k: bytes) -> int | None:
    """Inverse of :func:`check_bytes`; None for bytes no CRC encodes to (a high bit clear, stray bits)."""
    k = bytes(k)
    if len(k) != CHECK_SIZE or min(k) < 0x80 or k[-1] & 0x70:
        return None
    # the five 7-bit groups at bits 0, 7, 14, 21, 28, written out (the decoder judges every segment by them)
    return (k[0] & 0x7F) | (k[1] & 0x7F) << 7 | (k[2] & 0x7F) << 14 | (k[3] & 0x7F) << 21 | (k[4] & 0x7F) << 28


def cobs_encode(data: bytes) -> bytes:
    """Consistent Overhead Byte Stuffing (Cheshire & Baker, IEEE/ACM ToN 7(2), 1999).

    The output contains no zero byte; each block is a code byte ``n`` (1..255) followed by ``n - 1``
    data bytes, and every block with ``n < 255`` stands for its bytes plus one zero, except the last.
    """
    out = bytearray()
    for part in bytes(data).split(b"\x00"):
        while len(part) >= 254:
            out.append(0xFF)
            out += part[:254]
            part = part[254:]
        out.append(len(part) + 1)
        out += part
    return bytes(out)


def cobs_decode(enc: bytes) -> bytes:
    """Inverse of :func:`cobs_encode`; raises :class:`ProtocolError` ("cobs") on a malformed block."""
    out = bytearray()
    i, n = 0, len(enc)
    while i < n:
        code = enc[i]
        j = i + code
        if code == 0 or j > n:
            raise ProtocolError(f"cobs: block code {code} at offset {i} overruns the {n}-byte segment")
        out += enc[i + 1:j]
        if code < 0xFF and j < n:
            out.append(0)
        i = j
    return bytes(out)


# ================================================================================================
# Frames
# ================================================================================================
@dataclass(frozen=True)
class Frame:
    """One decoded frame: message ``type`` (0..255), sequence number ``seq`` (0..255), ``payload``."""

    type: int
    seq: int
    payload: bytes = b""


@dataclass(frozen=True)
class Reject:
    """A segment the decoder refused: ``verdict`` is one of :data:`VERDICTS`; ``raw`` its bytes."""

    verdict: str
    raw: bytes


def frame_body(type_: int, seq: int, payload: bytes = b"") -> bytes:
    """Unstuffed frame body ``TYPE SEQ LEN PAYLOAD``."""
    if not (0 <= type_ <= 255 and 0 <= seq <= 255):
        raise ProtocolError(f"frame: type {type_} / seq {seq} must be bytes (0..255)")
    if len(payload) > MAX_PAYLOAD:
        raise ProtocolError(f"frame: payload of {len(payload)} bytes exceeds MAX_PAYLOAD = {MAX_PAYLOAD}")
    return bytes((type_, seq, len(payload))) + bytes(payload)


def segment_of(encoded: bytes) -> bytes:
    """A segment: the encoded bytes followed by the check bytes of their CRC-32C."""
    return bytes(encoded) + check_bytes(crc32c(encoded))


def encode_frame(type_: int, seq: int, payload: bytes = b"") -> bytes:
    """Bytes on the wire for one frame: ``00 E K 00``, ``E = COBS(body)``, ``K`` = check bytes of E."""
    return b"\x00" + segment_of(cobs_encode(frame_body(type_, seq, payload))) + b"\x00"


def decode_segment(seg: bytes) -> Frame | Reject:
    """Verdict on one segment (the bytes between two delimiters, non-empty); never raises."""
    seg = bytes(seg)
    if len(seg) > MAX_ENCODED:
        return Reject("overflow", seg)
    enc, k = seg[:-CHECK_SIZE], seg[-CHECK_SIZE:]
    if len(seg) < CHECK_SIZE + 1:
        return Reject("crc", seg)
    check = check_value(k)  # bytes no CRC encodes to are rejected without computing one
    if check is None or check != crc32c(enc):
        return Reject("crc", seg)
    try:
        body = cobs_decode(enc)
    except ProtocolError:
        return Reject("cobs", seg)
    n = len(body)
    if n < MIN_FRAME or n > MAX_FRAME or body[2] != n - MIN_FRAME:
        return Reject("length", seg)
    return Frame(body[0], body[1], body[3:])


def decode_frame(data: bytes) -> Frame:
    """Decode exactly one frame (delimiters optional); raise :class:`ProtocolError` naming the verdict."""
    events = Decoder().feed(bytes(data) + b"\x00")
    if len(events) != 1 or not isinstance(events[0], Frame):
        verdicts = [e.verdict if isinstance(e, Reject) else "frame" for e in events] or ["incomplete"]
        raise ProtocolError(f"frame: expected exactly one valid frame, got {', '.join(verdicts)}")
    return events[0]


class Decoder:
    """Streaming frame decoder: feed arbitrary chunks, get frames and rejects; never raises.

    Bytes accumulate until a delimiter (0x00); each non-empty segment then gets a verdict
    (:func:`decode_segment`). A segment longer than :data:`MAX_ENCODED` is discarded as it grows (the
    buffer never exceeds ``MAX_ENCODED`` bytes) and reported once, as ``"overflow"``, at its delimiter.
    Garbage therefore costs at most the frame it touches: the decoder resynchronizes at the next 0x00.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overflow = False
        self._overflow_raw = b""
        self.frames = 0  #: frames accepted so far
        self.rejects = dict.fromkeys(VERDICTS, 0)  #: rejected segments so far, by verdict

    def reset(self) -> None:
        """Forget any partial segment (e.g. after the host flushed its input)."""
        self._buf.clear()
        self._overflow = False

    def feed(self, chunk: bytes) -> list[Frame | Reject]:
        """Consume ``chunk``; return the frames and rejects it completed, in order."""
        events: list[Frame | Reject] = []
        data = bytes(chunk)
        start = 0
        while True:
            k = data.find(b"\x00", start)
            piece = data[start:] if k < 0 else data[start:k]
            if k >= 0 and not self._buf and not self._overflow and len(piece) <= MAX_ENCODED:
                # a whole segment within this chunk: judged where it lies (what the buffer would hold)
                if piece:
                    events.append(self._counted(decode_segment(piece)))
                start = k + 1
                continue
            if self._overflow or len(self._buf) + len(piece) > MAX_ENCODED:
                if not self._overflow:
                    self._overflow_raw = bytes(self._buf[:16])
                self._overflow = True
                self._buf.clear()
            else:
                self._buf += piece
            if k < 0:
                return events
            if self._overflow:
                ev: Frame | Reject = Reject("overflow", self._overflow_raw)
                self._overflow = False
            elif self._buf:
                ev = decode_segment(self._buf)
            else:
                start = k + 1
                continue
            self._buf.clear()
            events.append(self._counted(ev))
            start = k + 1

    def _counted(self, ev: Frame | Reject) -> Frame | Reject:
        """``ev``, counted in :attr:`frames` or :attr:`rejects`."""
        if isinstance(ev, Frame):
            self.frames += 1
        else:
            self.rejects[ev.verdict] += 1
        return ev


# ================================================================================================
# Messages
# ================================================================================================
@dataclass(frozen=True)
class Field:
    """One payload field: ``name``, struct code (little-endian), inclusive range, unit (for docs), and the
    minor version that appended it to its message (``since``; SPEC.md §4: a minor version only appends)."""

    name: str
    fmt: str
    lo: int
    hi: int
    unit: str = ""
    since: int = 0


@dataclass(frozen=True)
class MessageSpec:
    """A message type: its ``code``, ``name`` and payload ``fields`` (in wire order).

    Fields carry the minor version that appended them (:attr:`Field.since`); a session of minor version
    ``m`` (the lower of the host's and the controller's, SPEC.md §3) carries the fields with
    ``since <= m``: :meth:`fields_for`, :meth:`size_for`.
    """

    code: int
    name: str
    fields: tuple[Field, ...] = ()
    _struct: struct.Struct = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "_struct", struct.Struct("<" + "".join(f.fmt for f in self.fields)))

    @property
    def size(self) -> int:
        """Payload size in the current minor version (:data:`PROTOCOL_MINOR`)."""
        return self._struct.size

    def fields_for(self, minor: int) -> tuple[Field, ...]:
        """The fields a session of minor version ``minor`` carries (a prefix of :attr:`fields`)."""
        return tuple(f for f in self.fields if f.since <= minor)

    def size_for(self, minor: int) -> int:
        """Payload size in a session of minor version ``minor``."""
        return struct.calcsize("<" + "".join(f.fmt for f in self.fields_for(minor)))


def _u(fmt: str) -> tuple[int, int]:
    return {"B": (0, 0xFF), "H": (0, 0xFFFF), "I": (0, 0xFFFFFFFF), "h": (-0x8000, 0x7FFF)}[fmt]


def _f(name: str, fmt: str, lo: int | None = None, hi: int | None = None, unit: str = "", since: int = 0) -> Field:
    dlo, dhi = _u(fmt)
    return Field(name, fmt, dlo if lo is None else lo, dhi if hi is None else hi, unit, since)


#: The message catalogue (SPEC.md §4), requests and their replies (code | 0x80), and ERROR.
MESSAGES: dict[int, MessageSpec] = {m.code: m for m in (
    MessageSpec(HELLO, "HELLO", (_f("major", "B"), _f("minor", "B"))),
    MessageSpec(HEARTBEAT, "HEARTBEAT"),
    MessageSpec(SET_LIGHT, "SET_LIGHT", (_f("on", "B", 0, 1), _f("level", "H", unit="1/65535"))),
    MessageSpec(READ_PHOTODIODE, "READ_PHOTODIODE", (_f("samples", "B", 1, 255),)),
    MessageSpec(TRIGGER, "TRIGGER", (_f("exposure_us", "I", 1, 600_000_000, "us"),)),
    MessageSpec(STATUS, "STATUS"),
    MessageSpec(SET_WATCHDOG, "SET_WATCHDOG", (_f("period_ms", "I", WATCHDOG_MIN_MS, WATCHDOG_MAX_MS, "ms"),)),
    MessageSpec(HELLO | REPLY_BIT, "HELLO_REPLY", (
        _f("major", "B"), _f("minor", "B"), _f("capabilities", "H"), _f("firmware", "H"),
        _f("max_payload", "B"), _f("watchdog_ms", "I", unit="ms"))),
    MessageSpec(HEARTBEAT | REPLY_BIT, "HEARTBEAT_REPLY"),
    MessageSpec(SET_LIGHT | REPLY_BIT, "SET_LIGHT_REPLY", (_f("on", "B", 0, 1), _f("level", "H", unit="1/65535"))),
    MessageSpec(READ_PHOTODIODE | REPLY_BIT, "READ_PHOTODIODE_REPLY", (
        _f("samples", "B", 1, 255), _f("mean", "I", unit="1e-6 rel"), _f("sem", "I", unit="1e-6 rel"),
        _f("time_ms", "I", unit="ms", since=1), _f("span_us", "I", unit="us", since=1))),
    MessageSpec(TRIGGER | REPLY_BIT, "TRIGGER_REPLY", (_f("exposure_us", "I", unit="us"), _f("count", "I"))),
    MessageSpec(STATUS | REPLY_BIT, "STATUS_REPLY", (
        _f("flags", "H"), _f("level", "H", unit="1/65535"), _f("temperature", "h", unit="0.01 degC"),
        _f("uptime_ms", "I", unit="ms"), _f("watchdog_ms", "I", unit="ms"), _f("reset_cause", "B", since=2))),
    MessageSpec(SET_WATCHDOG | REPLY_BIT, "SET_WATCHDOG_REPLY", (_f("period_ms", "I", unit="ms"),)),
    MessageSpec(ERROR, "ERROR", (_f("code", "B"), _f("request", "B"))),
)}
BY_NAME: dict[str, MessageSpec] = {m.name: m for m in MESSAGES.values()}


@dataclass(frozen=True)
class Message:
    """A decoded message: catalogue ``name``, ``seq`` and field ``values`` (wire integers)."""

    name: str
    seq: int
    values: Mapping[str, int] = field(default_factory=dict)

    @property
    def code(self) -> int:
        return BY_NAME[self.name].code

    def __getitem__(self, key: str) -> int:
        return self.values[key]


def pack_payload(name: str, values: Mapping[str, int], session_minor: int = PROTOCOL_MINOR) -> tuple[int, bytes]:
    """Validate ``values`` against message ``name`` and pack them; return ``(code, payload)``.

    ``session_minor``: the session's minor version; fields appended by a later minor version are not sent
    (they may be given, and are ignored), every field of ``session_minor`` is required."""
    spec = BY_NAME.get(name)
    if spec is None:
        raise ProtocolError(f"message: unknown name {name!r}")
    names = [f.name for f in spec.fields]
    extra = set(values) - set(names)
    if extra:
        raise ProtocolError(f"{name}: unknown field {sorted(extra)[0]!r}; fields: {', '.join(names) or 'none'}")
    fields = spec.fields_for(session_minor)
    out = []
    for f in fields:
        if f.name not in values:
            raise ProtocolError(f"{name}: missing field {f.name!r}")
        v = values[f.name]
        if isinstance(v, bool):
            v = int(v)
        if not isinstance(v, int) or not f.lo <= v <= f.hi:
            raise ProtocolError(f"{name}: {f.name} = {v!r}: must be an integer in [{f.lo}, {f.hi}]")
        out.append(v)
    if len(fields) == len(spec.fields):
        return spec.code, spec._struct.pack(*out)
    return spec.code, struct.pack("<" + "".join(f.fmt for f in fields), *out)


def encode_message(name: str, seq: int, *, session_minor: int = PROTOCOL_MINOR, **values: int) -> bytes:
    """Wire bytes of message ``name`` with sequence number ``seq`` and field ``values`` (in a session of
    minor version ``session_minor``: see :func:`pack_payload`)."""
    code, payload = pack_payload(name, values, session_minor)
    return encode_frame(code, seq, payload)


def decode_message(frame: Frame, session_minor: int | None = None) -> Message:
    """Unpack a frame's payload by the catalogue; :class:`ProtocolError` on unknown type or bad size.

    ``session_minor``: the session's minor version, whose payload size is then required exactly; None accepts
    the size of any minor version up to :data:`PROTOCOL_MINOR` (before the handshake, or a tool that reads
    both), and the message then holds the fields that size carries. Values are only range-checked by the
    receiver's logic, not here (a controller answers BAD_VALUE).
    """
    spec = MESSAGES.get(frame.type)
    if spec is None:
        raise ProtocolError(f"message: unknown type 0x{frame.type:02X}")
    n = len(frame.payload)
    if n == spec.size and (session_minor is None or session_minor >= PROTOCOL_MINOR):
        vals = spec._struct.unpack(frame.payload)
        return Message(spec.name, frame.seq, dict(zip((f.name for f in spec.fields), vals)))
    minors = range(PROTOCOL_MINOR + 1) if session_minor is None else (min(session_minor, PROTOCOL_MINOR),)
    for m in sorted(minors, reverse=True):
        if n == spec.size_for(m):
            fields = spec.fields_for(m)
            vals = struct.unpack("<" + "".join(f.fmt for f in fields), frame.payload)
            return Message(spec.name, frame.seq, dict(zip((f.name for f in fields), vals)))
    expected = spec.size_for(session_minor) if session_minor is not None else spec.size
    raise ProtocolError(f"{spec.name}: payload is {n} bytes, expected {expected}")


def check_ranges(msg: Message) -> str | None:
    """Name of the first field of ``msg`` outside its catalogue range, or None if all are in range."""
    for f in BY_NAME[msg.name].fields:
        if f.name not in msg.values:
            continue  # appended by a later minor version than the message's
        if not f.lo <= msg.values[f.name] <= f.hi:
            return f.name
    return None
