"""The Python codec against vectors.json, and against an independent bit-by-bit reading of SPEC.md."""

import struct

import pytest

from firmware_protocol import codec as c


def crc_bitwise(data: bytes) -> int:
    """CRC-32C written out from its definition: polynomial 0x1EDC6F41, reflected (LSB first), init and
    final XOR 0xFFFFFFFF."""
    poly = int(f"{0x1EDC6F41:032b}"[::-1], 2)  # the normal form, bit-reversed
    crc = 0xFFFFFFFF
    for byte in data:
        for bit in range(8):
            fb = (crc ^ (byte >> bit)) & 1
            crc = (crc >> 1) ^ (poly if fb else 0)
    return crc ^ 0xFFFFFFFF


def check_by_hand(crc: int) -> bytes:
    """SPEC.md §2.2's check bytes: seven CRC bits per byte, least significant first, high bit set."""
    return bytes(0x80 | ((crc >> s) & 0x7F) for s in (0, 7, 14, 21, 28))


def cobs_by_hand(data: bytes) -> bytes:
    """COBS for blocks < 254 bytes, as SPEC.md §2.2 words it: each zero-terminated run becomes len+1, run."""
    return b"".join(bytes([len(run) + 1]) + run for run in data.split(b"\x00"))


def test_crc_check_values(vectors):
    assert crc_bitwise(b"123456789") == 0xE3069283  # the catalogue check value: our reference is right
    assert crc_bitwise(bytes(32)) == 0x8A9136AA and crc_bitwise(b"\xff" * 32) == 0x62A8AB43  # RFC 3720 B.4
    for v in vectors["crc"]:
        data = bytes.fromhex(v["data"])
        assert c.crc32c(data) == v["crc"] == crc_bitwise(data)


def test_cobs_examples(vectors):
    for v in vectors["cobs"]:
        data, enc = bytes.fromhex(v["data"]), bytes.fromhex(v["encoded"])
        assert c.cobs_encode(data) == enc
        assert c.cobs_decode(enc) == data
        assert b"\x00" not in enc


def test_long_runs_round_trip():
    for n in (253, 254, 255, 600):
        data = bytes([7]) * n + b"\x00" + bytes([9]) * n
        assert c.cobs_decode(c.cobs_encode(data)) == data


@pytest.mark.parametrize("i", range(20))
def test_message_vectors(vectors, i):
    v = vectors["messages"][i]
    wire, minor = bytes.fromhex(v["bytes"]), v["session_minor"]
    assert c.encode_message(v["name"], v["seq"], session_minor=minor, **v["values"]) == wire
    # independent derivation of the same bytes from the spec's words: the fields of the session's version
    spec = c.BY_NAME[v["name"]]
    fields = [f for f in spec.fields if f.since <= minor]
    payload = struct.pack("<" + "".join(f.fmt for f in fields), *[v["values"][f.name] for f in fields])
    body = bytes([spec.code, v["seq"], len(payload)]) + payload
    enc = cobs_by_hand(body)
    assert wire == b"\x00" + enc + check_by_hand(crc_bitwise(enc)) + b"\x00"
    for session_minor in (None, minor):  # any version's size, or exactly the session's
        msg = c.decode_message(c.decode_frame(wire), session_minor)
        assert (msg.name, msg.seq, dict(msg.values)) == (v["name"], v["seq"], v["values"])


def test_vectors_cover_every_message_and_both_photodiode_reply_versions(vectors):
    assert len(vectors["messages"]) == 22 and vectors["protocol"] == {"major": 2, "minor": 2}
    pd = [(v["session_minor"], len(bytes.fromhex(v["frame"]["payload"]))) for v in vectors["messages"]
          if v["name"] == "READ_PHOTODIODE_REPLY"]
    assert sorted(pd) == [(0, 9), (2, 17)]
    st = [(v["session_minor"], len(bytes.fromhex(v["frame"]["payload"]))) for v in vectors["messages"]
          if v["name"] == "STATUS_REPLY"]
    assert sorted(st) == [(1, 14), (2, 15), (2, 15)]  # 2.2 appends reset_cause


def test_minor_versions_only_append_and_sizes_are_checked_per_session():
    """SPEC.md §3: a 2.0 session carries the 2.0 fields only; a receiver that knows the session's
    version refuses the other version's size; fields of a later version are not sent to an earlier one."""
    full = dict(samples=4, mean=500_000, sem=20, time_ms=7, span_us=300)
    w20 = c.encode_message("READ_PHOTODIODE_REPLY", 9, session_minor=0, **full)  # 2.1 fields dropped
    w21 = c.encode_message("READ_PHOTODIODE_REPLY", 9, **full)
    f20, f21 = c.decode_frame(w20), c.decode_frame(w21)
    assert f21.payload[:9] == f20.payload and len(f21.payload) == 17
    assert dict(c.decode_message(f20, 0).values) == dict(samples=4, mean=500_000, sem=20)
    assert dict(c.decode_message(f21, 1).values) == full
    with pytest.raises(c.ProtocolError, match="payload is 17 bytes, expected 9"):
        c.decode_message(f21, 0)
    with pytest.raises(c.ProtocolError, match="payload is 9 bytes, expected 17"):
        c.decode_message(f20, 1)
    with pytest.raises(c.ProtocolError, match="missing field 'time_ms'"):
        c.encode_message("READ_PHOTODIODE_REPLY", 9, samples=4, mean=1, sem=1)
    for spec in c.MESSAGES.values():  # appended, never inserted: each version's fields prefix the next's
        since = [f.since for f in spec.fields]
        assert since == sorted(since) and spec.size_for(0) <= spec.size_for(c.PROTOCOL_MINOR) == spec.size


def test_every_message_type_has_a_vector(vectors):
    assert {m["name"] for m in vectors["messages"]} == set(c.BY_NAME)


def test_stream_vectors(vectors):
    for s in vectors["streams"]:
        got = []
        for ev in c.Decoder().feed(bytes.fromhex(s["bytes"])):
            if isinstance(ev, c.Frame):
                got.append({"frame": {"type": ev.type, "seq": ev.seq, "payload": ev.payload.hex()}})
            else:
                got.append({"reject": ev.verdict})
        assert got == s["events"], s["description"]


def test_stream_vectors_byte_by_byte(vectors):
    for s in vectors["streams"]:
        d, events = c.Decoder(), []
        for b in bytes.fromhex(s["bytes"]):
            events += d.feed(bytes([b]))
        kinds = ["frame" if isinstance(e, c.Frame) else e.verdict for e in events]
        assert kinds == [("frame" if "frame" in e else e["reject"]) for e in s["events"]], s["description"]


def test_encode_errors_name_the_field(vectors):
    for v in vectors["encode_errors"]:
        with pytest.raises(c.ProtocolError, match=v["field"]):
            c.encode_message(v["name"], 1, **v["values"])
    with pytest.raises(c.ProtocolError, match="missing field 'level'"):
        c.encode_message("SET_LIGHT", 1, on=1)
    with pytest.raises(c.ProtocolError, match="unknown field 'volume'"):
        c.encode_message("SET_LIGHT", 1, on=1, level=3, volume=2)
    with pytest.raises(c.ProtocolError, match="payload of 65 bytes"):
        c.encode_frame(1, 1, bytes(65))


def test_message_errors(vectors):
    for v in vectors["message_errors"]:
        f = v["frame"]
        frame = c.decode_frame(c.encode_frame(f["type"], f["seq"], bytes.fromhex(f["payload"])))
        with pytest.raises(c.ProtocolError):
            c.decode_message(frame)


def test_decode_frame_names_the_verdict():
    wire = bytearray(c.encode_message("STATUS", 3))
    wire[3] ^= 0x10
    with pytest.raises(c.ProtocolError, match="crc"):
        c.decode_frame(bytes(wire))
    with pytest.raises(c.ProtocolError, match="incomplete"):
        c.decode_frame(b"")


def test_every_single_and_double_bit_flip_of_every_vector_is_rejected(vectors):
    """Exhaustive: flipping any one bit (and any two bits within 4 bytes) of a vector frame's wire bytes
    never yields an accepted frame; the following frame is always decoded (resynchronization)."""
    tail = c.encode_message("HEARTBEAT", 77)
    for v in vectors["messages"]:
        wire = bytes.fromhex(v["bytes"])
        nbits = 8 * len(wire)
        pairs = [(i,) for i in range(nbits)] + [(i, j) for i in range(nbits) for j in range(i + 1, min(i + 32, nbits))]
        for flips in pairs:
            b = bytearray(wire)
            for k in flips:
                b[k // 8] ^= 1 << (k % 8)
            events = c.Decoder().feed(bytes(b) + tail)
            frames = [e for e in events if isinstance(e, c.Frame)]
            assert frames == [c.Frame(c.HEARTBEAT, 77)], (v["name"], flips)


def _flipped(wire: bytes, bits) -> bytes:
    w = bytearray(wire)
    for k in bits:
        w[k // 8] ^= 1 << (k % 8)
    return bytes(w)


def _accepted(data: bytes) -> list:
    return [e for e in c.Decoder().feed(data + b"\x00") if isinstance(e, c.Frame)]


def test_every_1_and_2_bit_error_of_every_vector_is_detected(vectors):
    """SPEC.md §2.5, exhaustively: for every vector frame, every single and every pair of flipped bits
    anywhere on the wire (delimiters included) yields no frame at all."""
    import itertools

    for v in vectors["messages"]:
        wire = bytes.fromhex(v["bytes"])
        n = 8 * len(wire)
        for k in range(n):
            assert not _accepted(_flipped(wire, [k])), (v["name"], k)
        for a, b in itertools.combinations(range(n), 2):
            assert not _accepted(_flipped(wire, [a, b])), (v["name"], a, b)


def test_3_to_5_bit_errors_by_sampling(vectors):
    rng = __import__("numpy").random.default_rng(5)
    for v in vectors["messages"]:
        wire = bytes.fromhex(v["bytes"])
        for _ in range(300):
            k = int(rng.integers(3, 6))
            bits = rng.choice(8 * len(wire), size=k, replace=False)
            assert not _accepted(_flipped(wire, bits)), (v["name"], sorted(bits))
