"""Regenerate ``vectors.json`` (``python -m firmware_protocol.make_vectors``).

Run only when the protocol changes, and review the diff by hand: the vectors are the contract both
codecs are tested against; the CRC check values and the COBS examples in them are independent of this
codec (Rocksoft catalogue "CRC-32/ISCSI"; RFC 3720 §B.4's 32-byte examples; Cheshire & Baker 1999),
and tests/protocol re-derives the frames with a bit-by-bit CRC and a hand-written stuffing rule.
"""

from __future__ import annotations

import json
import struct

from firmware_protocol import codec as c


def _frame_dict(f: c.Frame) -> dict:
    return {"type": f.type, "seq": f.seq, "payload": f.payload.hex()}


def _stream(description: str, data: bytes) -> dict:
    events = []
    for ev in c.Decoder().feed(data):
        events.append({"frame": _frame_dict(ev)} if isinstance(ev, c.Frame) else {"reject": ev.verdict})
    return {"description": description, "bytes": data.hex(), "events": events}


def _raw_body(type_: int, seq: int, length: int, payload: bytes) -> bytes:
    return bytes((type_, seq, length)) + payload


def _wire_of_encoded(enc: bytes) -> bytes:
    """00 | enc | check bytes of enc | 00: a segment whose check is right whatever enc holds."""
    return b"\x00" + c.segment_of(enc) + b"\x00"


def _send(name: str, seq: int, **values) -> dict:
    return {"send": c.encode_message(name, seq, **values).hex(), "request": name, "seq": seq, **(
        {"values": values} if values else {})}


def _reply(name: str, seq: int, **values) -> dict:
    """An exact expected reply (its bytes)."""
    return {"expect": c.encode_message(name, seq, **values).hex(), "reply": name, "values": values}


def _reply_fields(name: str, seq: int, **values) -> dict:
    """An expected reply checked by name, seq and the listed fields only (the rest is the controller's own:
    firmware version, uptime, temperature)."""
    return {"expect_fields": {"name": name, "seq": seq, "values": values}}


def exchanges() -> list:
    """SPEC.md §4–§5 as request/reply exchanges with the controller's inputs between them (``input``:
    ``estop`` / ``interlock`` true or false, ``heat_sink_c`` a temperature or null). A conforming controller
    answers each ``send`` with exactly ``expect`` (or a reply whose fields match ``expect_fields``)."""
    hello = [_send("HELLO", 1, major=c.PROTOCOL_MAJOR, minor=c.PROTOCOL_MINOR), _reply_fields("HELLO_REPLY", 1, major=2)]
    on = dict(on=1, level=30000)
    return [
        {"description": "a retried switch-on after an E-stop cut is executed again: ERROR ESTOP, not the stored 'on'",
         "steps": [*hello, _send("SET_LIGHT", 2, **on), _reply("SET_LIGHT_REPLY", 2, **on),
                   {"input": {"estop": True}},
                   _send("SET_LIGHT", 2, **on), _reply("ERROR", 2, code=c.ERR_ESTOP, request=c.SET_LIGHT),
                   _send("STATUS", 3), _reply_fields("STATUS_REPLY", 3, flags=c.FLAG_ESTOP, level=0)]},
        {"description": "a retried STATUS describes the present, not the first attempt's answer",
         "steps": [*hello, _send("SET_LIGHT", 2, **on), _reply("SET_LIGHT_REPLY", 2, **on),
                   _send("STATUS", 3), _reply_fields("STATUS_REPLY", 3, flags=c.FLAG_LIGHT_ON, level=30000),
                   {"input": {"interlock": True}},
                   _send("STATUS", 3), _reply_fields("STATUS_REPLY", 3, flags=c.FLAG_INTERLOCK_OPEN, level=0)]},
        {"description": "a retried TRIGGER is answered from the duplicate cache: one pulse",
         "steps": [*hello, _send("TRIGGER", 2, exposure_us=500_000), _reply("TRIGGER_REPLY", 2, exposure_us=500_000, count=1),
                   _send("TRIGGER", 2, exposure_us=500_000), _reply("TRIGGER_REPLY", 2, exposure_us=500_000, count=1)]},
        {"description": "over the temperature limit the controller cuts the light and refuses switch-on until it is "
                        "below the limit less the hysteresis",
         "steps": [*hello, _send("SET_LIGHT", 2, **on), _reply("SET_LIGHT_REPLY", 2, **on),
                   {"input": {"heat_sink_c": 90.0}},
                   _send("STATUS", 3), _reply_fields("STATUS_REPLY", 3, flags=c.FLAG_OVERTEMP, level=0),
                   _send("SET_LIGHT", 4, **on), _reply("ERROR", 4, code=c.ERR_OVERTEMP, request=c.SET_LIGHT),
                   {"input": {"heat_sink_c": 67.0}},
                   _send("SET_LIGHT", 5, **on), _reply("ERROR", 5, code=c.ERR_OVERTEMP, request=c.SET_LIGHT),
                   {"input": {"heat_sink_c": 60.0}},
                   _send("STATUS", 6), _reply_fields("STATUS_REPLY", 6, flags=0, level=0),
                   _send("SET_LIGHT", 7, **on), _reply("SET_LIGHT_REPLY", 7, **on)]},
    ]


def build() -> dict:
    msgs = [
        ("HELLO", 0, {"major": 1, "minor": 0}),
        ("HELLO_REPLY", 0, {"major": 1, "minor": 0, "capabilities": 0x1F, "firmware": 0x0100,
                            "max_payload": 64, "watchdog_ms": 10000}),
        ("HEARTBEAT", 1, {}),
        ("HEARTBEAT_REPLY", 1, {}),
        ("SET_LIGHT", 2, {"on": 1, "level": 65535}),
        ("SET_LIGHT_REPLY", 2, {"on": 1, "level": 65535}),
        ("SET_LIGHT", 3, {"on": 0, "level": 0}),
        ("READ_PHOTODIODE", 4, {"samples": 16}),
        ("READ_PHOTODIODE_REPLY", 4, {"samples": 16, "mean": 987654, "sem": 500, "time_ms": 123457,
                                      "span_us": 1560}),
        ("READ_PHOTODIODE_REPLY", 4, {"samples": 16, "mean": 987654, "sem": 500}, 0),  # a 2.0 session
        ("TRIGGER", 5, {"exposure_us": 20000}),
        ("TRIGGER_REPLY", 5, {"exposure_us": 20000, "count": 1}),
        ("STATUS", 6, {}),
        ("STATUS_REPLY", 6, {"flags": 0x0004, "level": 32768, "temperature": 2537, "uptime_ms": 123456,
                             "watchdog_ms": 10000, "reset_cause": 1}),
        ("STATUS_REPLY", 6, {"flags": 0x0004, "level": 32768, "temperature": 2537, "uptime_ms": 123456,
                             "watchdog_ms": 10000}, 1),  # a 2.1 session: no reset cause
        ("ERROR", 9, {"code": c.ERR_OVERTEMP, "request": c.SET_LIGHT}),
        ("STATUS_REPLY", 7, {"flags": 0x0009, "level": 0, "temperature": -500, "uptime_ms": 0, "watchdog_ms": 100,
                             "reset_cause": 4}),
        ("SET_WATCHDOG", 8, {"period_ms": 2000}),
        ("SET_WATCHDOG_REPLY", 8, {"period_ms": 2000}),
        ("ERROR", 9, {"code": c.ERR_ESTOP, "request": c.SET_LIGHT}),
        ("HEARTBEAT", 0, {}),   # seq 0: the body's zero bytes are stuffed
        ("HEARTBEAT", 255, {}),
    ]
    messages = []
    for name, seq, values, *minor in msgs:
        session_minor = minor[0] if minor else c.PROTOCOL_MINOR  # the fields of that minor version (SPEC.md §3)
        code, payload = c.pack_payload(name, values, session_minor)
        messages.append({"name": name, "seq": seq, "session_minor": session_minor, "values": values,
                         "frame": {"type": code, "seq": seq, "payload": payload.hex()},
                         "bytes": c.encode_frame(code, seq, payload).hex()})

    status = c.encode_message("STATUS", 6)
    light = c.encode_message("SET_LIGHT", 2, on=1, level=65535)
    hb0 = c.encode_message("HEARTBEAT", 0)
    flip_payload = bytearray(light)
    flip_payload[5] ^= 0x01
    flip_check = bytearray(light)
    flip_check[-2] ^= 0x01
    streams = [
        _stream("one frame", status),
        _stream("two frames back to back", light + status),
        _stream("leading delimiter is optional", status[1:]),
        _stream("empty segments (repeated delimiters) are ignored", b"\x00\x00\x00" + status + b"\x00\x00"),
        _stream("garbage without zero bytes before a frame: one reject, then the frame",
                b"\x13\x37\xAB" + status),
        _stream("payload bit flipped -> crc", bytes(flip_payload) + status),
        _stream("check byte bit flipped -> crc", bytes(flip_check)),
        _stream("check byte with its high bit cleared -> crc", light[:-2] + bytes([light[-2] & 0x7F]) + b"\x00"),
        _stream("LEN field disagrees with the frame size (check valid) -> length",
                _wire_of_encoded(c.cobs_encode(_raw_body(c.SET_LIGHT, 2, 2, bytes([1, 0xFF, 0xFF]))))),
        _stream("decoded body shorter than 3 bytes -> length", _wire_of_encoded(c.cobs_encode(b"\x06\x06"))),
        _stream("COBS block overruns the segment (check valid) -> cobs", _wire_of_encoded(b"\x05\x01\x02") + status),
        _stream("segment too short to hold the check -> crc", b"\x00\x81\x82\x83\x00" + status),
        _stream("more than 73 bytes without a delimiter -> one overflow, then resync",
                bytes(range(1, 101)) + status),
        _stream("truncated frame, then a complete one", light[:5] + status),
        _stream("a zero byte inside a frame splits it into two rejects",
                light[:4] + b"\x00" + light[4:] + status),
        _stream("seq 0 frame (zero bytes stuffed)", hb0),
        _stream("frame of unknown type is still a valid frame (the message layer answers UNKNOWN_TYPE)",
                c.encode_frame(0x42, 1, b"\x01\x02")),
        _stream("largest frame: 64-byte payload", c.encode_frame(0x10, 3, bytes(range(64)))),
        _stream("65-byte payload encodes to 74 bytes -> overflow",
                _wire_of_encoded(c.cobs_encode(_raw_body(0x10, 3, 65, bytes(range(1, 66)))))),
    ]
    encode_errors = [
        {"name": "SET_LIGHT", "values": {"on": 2, "level": 0}, "field": "on"},
        {"name": "SET_LIGHT", "values": {"on": 1, "level": 65536}, "field": "level"},
        {"name": "READ_PHOTODIODE", "values": {"samples": 0}, "field": "samples"},
        {"name": "TRIGGER", "values": {"exposure_us": 0}, "field": "exposure_us"},
        {"name": "TRIGGER", "values": {"exposure_us": 600_000_001}, "field": "exposure_us"},
        {"name": "SET_WATCHDOG", "values": {"period_ms": 99}, "field": "period_ms"},
    ]
    message_errors = [
        {"description": "unknown type", "frame": {"type": 0x42, "seq": 1, "payload": "0102"}},
        {"description": "SET_LIGHT with a 2-byte payload", "frame": {"type": 3, "seq": 1, "payload": "01ff"}},
        {"description": "STATUS with a payload", "frame": {"type": 6, "seq": 1, "payload": "00"}},
        {"description": "READ_PHOTODIODE_REPLY of neither the 2.0 (9) nor the 2.1 size (17)",
         "frame": {"type": 0x84, "seq": 1, "payload": "00" * 13}},
    ]
    return {
        "protocol": {"major": c.PROTOCOL_MAJOR, "minor": c.PROTOCOL_MINOR},
        "exchanges": exchanges(),
        "crc": [{"data": b"123456789".hex(), "crc": 0xE3069283}, {"data": "", "crc": 0x00000000},
                {"data": "00" * 32, "crc": 0x8A9136AA}, {"data": "ff" * 32, "crc": 0x62A8AB43},
                {"data": "04060106", "crc": c.crc32c(b"\x04\x06\x01\x06")}],
        "cobs": [{"data": "00", "encoded": "0101"}, {"data": "0000", "encoded": "010101"},
                 {"data": "11220033", "encoded": "03112202" + "33"}, {"data": "11223344", "encoded": "0511223344"},
                 {"data": "11000000", "encoded": "0211010101"}],
        "messages": messages,
        "streams": streams,
        "encode_errors": encode_errors,
        "message_errors": message_errors,
    }


def main() -> None:
    from firmware_protocol import VECTORS_PATH

    VECTORS_PATH.write_text(json.dumps(build(), indent=1) + "\n")
    print(f"wrote {VECTORS_PATH}")


if __name__ == "__main__":
    main()
