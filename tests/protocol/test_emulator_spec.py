"""The emulator follows SPEC.md §3–§5, checked with raw bytes over its pty (no host client involved)."""

import pytest
import serial

from firmware_protocol import codec as fp
from gonio.errors import HardwareTimeout
from gonio.rig.controller import RigController
from sim.clock import SimClock


class Raw:
    """Send frames and collect the replies' messages with the codec only."""

    def __init__(self, path):
        self.port = serial.Serial(path, 115200, timeout=0.2)
        self.dec = fp.Decoder()

    def ask(self, wire: bytes, expect: int = 1) -> list[fp.Message]:
        self.port.write(wire)
        out = []
        for _ in range(20):  # bounded: 20 reads of at most 0.2 s; with expect=0, until 0.2 s of silence
            chunk = self.port.read(1)
            chunk += self.port.read(self.port.in_waiting)
            out += [fp.decode_message(e) for e in self.dec.feed(chunk) if isinstance(e, fp.Frame)]
            if len(out) >= expect and (expect or not chunk):
                break
        return out


@pytest.fixture
def raw(Emulator):
    with Emulator(SimClock()) as emu:
        r = Raw(emu.path)
        yield emu, r
        r.port.close()


def err(msg):
    return (msg.name, msg["code"], msg["request"])


def test_not_configured_until_hello_then_executes(raw):
    emu, r = raw
    [m] = r.ask(fp.encode_message("HEARTBEAT", 1))
    assert err(m) == ("ERROR", fp.ERR_NOT_READY, fp.HEARTBEAT) and m.seq == 1
    [m] = r.ask(fp.encode_message("STATUS", 2))
    assert m.name == "STATUS_REPLY" and m["flags"] & fp.FLAG_NOT_CONFIGURED
    [m] = r.ask(fp.encode_message("HELLO", 3, major=2, minor=7))
    assert (m.name, m["major"], m["watchdog_ms"]) == ("HELLO_REPLY", 2, fp.DEFAULT_WATCHDOG_MS)
    [m] = r.ask(fp.encode_message("HEARTBEAT", 4))
    assert m.name == "HEARTBEAT_REPLY" and m.seq == 4
    [m] = r.ask(fp.encode_message("HELLO", 5, major=1, minor=0))  # a version 1 host
    assert err(m) == ("ERROR", fp.ERR_VERSION, fp.HELLO)


def test_bad_requests_get_their_error_codes(raw):
    emu, r = raw
    r.ask(fp.encode_message("HELLO", 1, major=2, minor=0))
    [m] = r.ask(fp.encode_frame(0x42, 2, b"\x01"))
    assert err(m) == ("ERROR", fp.ERR_UNKNOWN_TYPE, 0x42)
    [m] = r.ask(fp.encode_frame(fp.SET_LIGHT, 3, b"\x01\xff"))
    assert err(m) == ("ERROR", fp.ERR_BAD_LENGTH, fp.SET_LIGHT)
    [m] = r.ask(fp.encode_frame(fp.SET_LIGHT, 4, b"\x02\xff\xff"))
    assert err(m) == ("ERROR", fp.ERR_BAD_VALUE, fp.SET_LIGHT)
    [m] = r.ask(fp.encode_frame(fp.SET_WATCHDOG, 5, (50).to_bytes(4, "little")))
    assert err(m) == ("ERROR", fp.ERR_BAD_VALUE, fp.SET_WATCHDOG)
    assert not emu.light_on and emu.watchdog_period == 10.0


def test_duplicate_is_answered_from_cache_and_hello_clears_it(raw):
    emu, r = raw
    r.ask(fp.encode_message("HELLO", 1, major=2, minor=0))
    trig = fp.encode_message("TRIGGER", 9, exposure_us=10)
    [a] = r.ask(trig)
    [b] = r.ask(trig)  # same type, seq and payload: a retry
    assert a == b and a["count"] == 1 and emu.executed["TRIGGER"] == 1 and emu.duplicates == 1
    emu.clock.sleep(1.0)
    [c] = r.ask(fp.encode_message("TRIGGER", 9, exposure_us=11))  # same seq, other payload: new command
    assert c["count"] == 2
    r.ask(fp.encode_message("HELLO", 10, major=2, minor=0))
    emu.clock.sleep(1.0)
    [d] = r.ask(fp.encode_message("TRIGGER", 9, exposure_us=11))  # after HELLO the cache is empty
    assert d["count"] == 3


def test_busy_while_pulse_high_and_corrupted_frames_are_not_answered(raw):
    emu, r = raw
    r.ask(fp.encode_message("HELLO", 1, major=2, minor=0))
    r.ask(fp.encode_message("TRIGGER", 2, exposure_us=1_000_000))
    [m] = r.ask(fp.encode_message("TRIGGER", 3, exposure_us=10))
    assert err(m) == ("ERROR", fp.ERR_BUSY, fp.TRIGGER)
    bad = bytearray(fp.encode_message("HEARTBEAT", 4))
    bad[2] ^= 0x01
    assert r.ask(bytes(bad) + b"\x13\x37\x00", expect=0) == []
    assert emu._decoder.rejects["crc"] == 2  # the flipped frame, and the garbage (too short to hold a check)


def test_pyserial_url_opens_and_own_echo_is_never_a_reply():
    """loop:// echoes the request back: a frame that is not a reply is discarded, then the timeout."""
    ctl = RigController.open("loop://", clock=SimClock(), connect=False, timeout=0.05, retries=1)
    with pytest.raises(HardwareTimeout, match="after 2 attempts"):
        ctl.heartbeat()
    assert ctl.stale_replies == 2
    ctl.close()
