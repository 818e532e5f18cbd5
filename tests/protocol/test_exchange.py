"""Byte-exchange tests of the host client: (sent, reply) pairs copied from SPEC.md's worked examples,
played by a scripted port; every pair must be used, in order. They read like the spec."""

import time

import pytest

from gonio.errors import ConfigError, ControllerError, EmergencyStop, HardwareTimeout, SafetyStop
from gonio.rig.controller import RigController
from gonio.rig.interfaces import RigController as RigControllerProtocol
from firmware_protocol import codec as fp
from sim.clock import SimClock


def h(s: str) -> bytes:
    return bytes.fromhex(s)


class ScriptedPort:
    """A transport that expects exactly the listed writes and answers each with its reply bytes."""

    def __init__(self, pairs):
        self.pairs = list(pairs)
        self.used = 0
        self.timeout = 0.0
        self.closed = False
        self._rx = bytearray()
        self.flushes = 0
        self.clock, self.latency = None, 0.0  # a SimClock advanced by `latency` s per exchange, if set

    def write(self, data):
        assert self.used < len(self.pairs), f"unexpected write {bytes(data).hex(' ')}"
        sent, reply = self.pairs[self.used]
        assert bytes(data) == sent, f"pair {self.used}: sent {bytes(data).hex(' ')}, spec says {sent.hex(' ')}"
        self.used += 1
        if self.clock is not None:
            self.clock.sleep(self.latency)
        self._rx += reply
        return len(data)

    @property
    def in_waiting(self):
        return len(self._rx)

    def read(self, n=1):
        if not self._rx:
            time.sleep(0.001)
            return b""
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    def reset_input_buffer(self):
        self.flushes += 1
        self._rx.clear()

    def close(self):
        self.closed = True

    def assert_all_used(self):
        assert self.used == len(self.pairs), f"only {self.used} of {len(self.pairs)} exchanges happened"


HELLO = h("00 06 01 01 02 02 02 BE F8 D8 90 85 00")  # HELLO 2.2
HELLO_REPLY = h("00 07 81 01 0B 02 02 1F 06 02 02 40 10 27 01 01 DE B3 83 98 8E 00")  # v2.2, firmware 0x0202
HELLO_REPLY_21 = h("00 07 81 01 0B 02 01 1F 06 01 02 40 10 27 01 01 98 AD CD 98 80 00")  # a 2.1 controller
HELLO_REPLY_20 = h("00 05 81 01 0B 02 02 1F 01 05 01 40 10 27 01 01 8B BB F5 F8 8F 00")  # a 2.0 controller
SET_WATCHDOG_10S = h("00 06 07 02 04 10 27 01 01 E7 A2 E1 A3 88 00")
SET_WATCHDOG_REPLY = h("00 06 87 02 04 10 27 01 01 93 BF D9 88 87 00")
HANDSHAKE = [(HELLO, HELLO_REPLY), (SET_WATCHDOG_10S, SET_WATCHDOG_REPLY)]


def connected(pairs, **kw):
    port = ScriptedPort(HANDSHAKE + pairs)
    ctl = RigController(port, clock=SimClock(), timeout=0.05, **kw)
    ctl.connect()
    return ctl, port


def test_session_reads_like_the_spec():
    ctl, port = connected([
        # SET_LIGHT seq 3: on=1, level=32768 (0.5)      -> SET_LIGHT_REPLY echoes it
        (h("00 05 03 03 03 01 02 80 8B D1 8B C4 86 00"), h("00 05 83 03 03 01 02 80 DD BE A9 A4 87 00")),
        # STATUS seq 4                 -> flags LIGHT_ON, level 32768, 25.37 °C, 123.456 s, reset cause power-on
        (h("00 03 06 04 01 B6 AC D7 B8 84 00"),
         h("00 05 86 04 0F 04 01 07 80 E9 09 40 E2 01 03 10 27 01 02 01 DF E6 D3 DA 84 00")),
        # TRIGGER seq 5: 20000 µs                        -> TRIGGER_REPLY count 1
        (h("00 06 05 05 04 20 4E 01 01 9A 8D 9E BA 85 00"), h("00 06 85 05 08 20 4E 01 02 01 01 01 01 C7 CD F3 84 8B 00")),
        # READ_PHOTODIODE seq 6: 16 samples  -> mean 0.987654, sem 0.0005, at uptime 123.457 s, over 1560 us
        (h("00 05 04 06 01 10 D5 FF A4 A2 83 00"),
         h("00 08 84 06 11 10 06 12 0F 03 F4 01 01 04 41 E2 01 03 18 06 01 01 80 D8 CF FB 88 00")),
        # HEARTBEAT seq 7                                -> HEARTBEAT_REPLY
        (h("00 03 02 07 01 B5 B5 B3 E9 8E 00"), h("00 03 82 07 01 F6 DB AE B0 86 00")),
    ])
    assert isinstance(ctl, RigControllerProtocol)
    assert ctl.info.capabilities == 0x1F and ctl.info.watchdog_s == 10.0
    ctl.set_light(True, 0.5)
    st = ctl.status()
    assert (st.light_on, st.estop, st.interlock_open) == (True, False, False)
    assert st.light_level == pytest.approx(32768 / 65535) and st.temperature_c == 25.37 and st.uptime_s == 123.456
    assert st.reset_cause == "power-on"
    ctl.trigger_camera(0.02)
    port.clock, port.latency = ctl.clock, 0.005  # the exchange takes 5 ms of the host's clock
    sent = ctl.clock.now()
    pd = ctl.read_photodiode(16)
    assert pd == pytest.approx((0.987654, 0.0005))  # still the (mean, sem) pair
    assert (pd.samples, pd.uptime, pd.span) == (16, 123.457, pytest.approx(0.00156))
    assert pd.time == pytest.approx(sent + 0.005 - 0.00078)  # the reply's arrival less half the span
    ctl.heartbeat()
    port.assert_all_used()
    assert ctl.retry_count == 0 and ctl.stale_replies == 0 and ctl.session_minor == 2


SET_LIGHT_ON = h("00 05 03 03 03 01 02 80 8B D1 8B C4 86 00")  # SET_LIGHT seq 3: on, 32768
SET_LIGHT_REPLY_ON = h("00 05 83 03 03 01 02 80 DD BE A9 A4 87 00")
ERROR_ESTOP = h("00 06 FF 03 02 04 03 81 99 B3 F5 8E 00")  # ERROR ESTOP for SET_LIGHT, seq 3
STATUS_4 = h("00 03 06 04 01 B6 AC D7 B8 84 00")


def test_retried_switch_on_after_an_estop_cut_is_refused_not_answered_from_a_cache():
    """SPEC.md §5 (2.2): the first SET_LIGHT switched the light on but its reply was lost; the E-stop cut the
    light; the retry (same bytes) is executed again: ERROR ESTOP, never the stored 'on'."""
    ctl, port = connected([(SET_LIGHT_ON, b""), (SET_LIGHT_ON, ERROR_ESTOP)], retries=1)
    with pytest.raises(EmergencyStop, match="SET_LIGHT refused"):
        ctl.set_light(True, 0.5)
    port.assert_all_used()
    assert ctl._light == (False, 0)  # a controller reset will not switch it back on


def test_a_2_1_controller_answers_the_retry_from_its_cache_so_the_host_asks_status():
    """SPEC.md §5: a 2.1 controller re-sends the stored 'on' for the retried switch-on; a 2.2 host does not
    believe a retried switch-on from it: STATUS (the 2.1 size: 14 bytes) says the light is off, E-stop pressed."""
    status_estop_21 = fp.encode_message("STATUS_REPLY", 4, session_minor=1, flags=fp.FLAG_ESTOP, level=0,
                                        temperature=2537, uptime_ms=123456, watchdog_ms=10000)
    port = ScriptedPort([(HELLO, HELLO_REPLY_21), (SET_WATCHDOG_10S, SET_WATCHDOG_REPLY),
                         (SET_LIGHT_ON, b""), (SET_LIGHT_ON, SET_LIGHT_REPLY_ON), (STATUS_4, status_estop_21)])
    ctl = RigController(port, clock=SimClock(), timeout=0.05, retries=1)
    assert ctl.connect().minor == 1 and ctl.session_minor == 1
    with pytest.raises(SafetyStop, match="light off after a retried switch-on: E-stop is pressed"):
        ctl.set_light(True, 0.5)
    port.assert_all_used()


def test_bytes_left_on_the_port_by_an_earlier_session_are_flushed_before_hello():
    """A HELLO_REPLY seq 1 left by an earlier host session is not taken as the answer to this one's HELLO."""
    port = ScriptedPort(HANDSHAKE)
    port._rx += HELLO_REPLY_21  # stale: an earlier session's HELLO_REPLY with the same seq
    ctl = RigController(port, clock=SimClock(), timeout=0.05)
    assert ctl.connect().minor == 2 and port.flushes == 1
    port.assert_all_used()


def test_a_2_0_controller_gives_readings_without_timestamp():
    """SPEC.md §3: HELLO_REPLY says 2.0, so the session is 2.0: the 9-byte photodiode reply is the
    answer, and a 17-byte one is not (wrong size for the session: refused as corrupted)."""
    port = ScriptedPort([(HELLO, HELLO_REPLY_20), (SET_WATCHDOG_10S, SET_WATCHDOG_REPLY),
                         (h("00 05 04 03 01 10 B1 93 D8 FE 80 00"),  # READ_PHOTODIODE seq 3: 16 samples
                          h("00 08 84 03 09 10 06 12 0F 03 F4 01 01 01 E7 D2 FF F7 8D 00")),
                         # READ_PHOTODIODE seq 4, sent twice, answered twice with a 2.1-sized reply
                         *[(h("00 05 04 04 01 10 D8 DB 99 D9 87 00"),
                            h("00 08 84 04 11 10 06 12 0F 03 F4 01 01 04 41 E2 01 03 18 06 01 01 BF 86 A4 C7 8F 00"))] * 2])
    ctl = RigController(port, clock=SimClock(5.0), timeout=0.05, retries=1)
    assert ctl.connect().minor == 0 and ctl.session_minor == 0
    pd = ctl.read_photodiode(16)
    assert pd == pytest.approx((0.987654, 0.0005)) and (pd.uptime, pd.span, pd.time) == (None, None, 5.0)
    from gonio.errors import ChecksumError
    with pytest.raises(ChecksumError, match="corrupted reply to READ_PHOTODIODE"):
        ctl.read_photodiode(16)
    port.assert_all_used()


def test_error_reply_becomes_emergency_stop_with_code():
    ctl, port = connected([
        # SET_LIGHT seq 3 -> ERROR seq 3 code ESTOP (4) for request 0x03
        (h("00 05 03 03 03 01 02 80 8B D1 8B C4 86 00"), h("00 06 FF 03 02 04 03 81 99 B3 F5 8E 00")),
    ])
    with pytest.raises(EmergencyStop, match=r"E-stop pressed or enclosure interlock open \(SET_LIGHT refused\)") as e:
        ctl.set_light(True, 0.5)
    assert e.value.code == 4
    port.assert_all_used()


def test_late_reply_with_old_seq_is_discarded():
    """A reply whose seq is not the request's is never taken as its answer."""
    stale = h("00 05 83 03 03 01 02 80 DD BE A9 A4 87 00")  # SET_LIGHT_REPLY seq 3, arriving late
    ctl, port = connected([
        (h("00 03 02 03 01 E9 F6 9A 9D 8A 00"), b""),  # HEARTBEAT seq 3: no answer (times out)
        # HEARTBEAT seq 3 retried: the late stale reply is flushed; then a proper HEARTBEAT_REPLY
        (h("00 03 02 03 01 E9 F6 9A 9D 8A 00"), stale + h("00 03 82 03 01 AA 98 87 C4 82 00")),
    ], retries=1)
    ctl.heartbeat()
    port.assert_all_used()
    assert ctl.retry_count == 1 and ctl.stale_replies == 1 and port.flushes == 2  # at HELLO, then at the retry


def test_no_reply_raises_timeout_after_bounded_retries():
    hb = h("00 03 02 03 01 E9 F6 9A 9D 8A 00")
    ctl, port = connected([(hb, b"")] * 3, retries=2)
    with pytest.raises(HardwareTimeout, match="no reply to HEARTBEAT .seq 3. after 3 attempts"):
        ctl.heartbeat()
    port.assert_all_used()


def test_version_and_capabilities_are_checked():
    port = ScriptedPort([(HELLO, h("00 06 FF 01 02 07 01 EE EE DC A0 88 00"))])  # ERROR VERSION for HELLO
    with pytest.raises(ControllerError, match="VERSION") as e:
        RigController(port, clock=SimClock(), timeout=0.05).connect()
    assert e.value.code == 7
    from firmware_protocol import codec as fp
    no_trigger = fp.encode_message("HELLO_REPLY", 1, major=2, minor=0, capabilities=0x1B, firmware=1,
                                   max_payload=64, watchdog_ms=10000)
    port = ScriptedPort([(HELLO, no_trigger)])
    with pytest.raises(ControllerError, match="lacks capabilities: trigger"):
        RigController(port, clock=SimClock(), timeout=0.05).connect()
    port.assert_all_used()


def test_values_are_validated_before_any_byte_leaves():
    ctl, port = connected([])
    for call, match in ((lambda: ctl.set_light(True, 1.5), "light level = 1.5"),
                        (lambda: ctl.read_photodiode(0), "photodiode samples = 0"),
                        (lambda: ctl.trigger_camera(-1.0), "trigger exposure = -1.0"),
                        (lambda: ctl.set_watchdog(0.01), "watchdog = 0.01")):
        with pytest.raises(ConfigError, match=match):
            call()
    port.assert_all_used()
