"""The servo emulator against the real dynamixel-sdk over a real pty (no driver in between)."""

from __future__ import annotations

import time

import dynamixel_sdk as sdk
import pytest

from gonio.rig.control_table import load_control_table
from gonio.rig.dynamixel import PortHandler
from sim import dxl_packet as P
from sim.clock import SimClock
from sim.servo_bus import HW_OVERLOAD, ServoBus

XM430 = load_control_table("XM430-W350")


def test_crc_and_packet_vector_from_field_notes():
    # FIELD-NOTES.md / e-manual: ping of ID 1
    assert P.encode(1, P.INST_PING) == bytes.fromhex("FFFFFD0001030001194E")
    assert P.crc16(bytes.fromhex("FFFFFD00010300 01".replace(" ", ""))) == 0x4E19


def test_byte_stuffing_round_trip_and_parser_skips_garbage():
    payload = bytes([0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00])
    pkt = P.encode(2, P.INST_WRITE, payload)
    assert b"\xff\xff\xfd\xfd" in pkt[7:]  # stuffed
    parser = P.Parser()
    got = parser.feed(b"\x00\x13\xff" + pkt[:5]) + parser.feed(pkt[5:])
    assert got == [P.Packet(2, P.INST_WRITE, payload, True)]
    bad = bytearray(pkt)
    bad[-1] ^= 0x01
    assert parser.feed(bytes(bad))[0].crc_ok is False


@pytest.fixture
def sdk_bus():
    clock = SimClock()
    with ServoBus({1: "XM540-W270", 2: "XM430-W350", 3: "XM430-W350"}, clock, noise_ticks=0.0) as bus:
        # the SDK's packet handler on gonio's PortHandler: the SDK's own busy-polls for its 34 ms timeout, which
        # on a loaded machine starves the emulator thread it waits for (these tests then failed with RX_TIMEOUT)
        port = PortHandler(bus.path, latency_timer_ms=250.0)  # protocol behaviour here, not timing: a generous timeout
        assert port.openPort() and port.setBaudRate(1_000_000)
        yield bus, port, sdk.PacketHandler(2.0), clock
        port.closePort()


def test_ping_read_write_and_unknown_id(sdk_bus):
    bus, port, ph, _ = sdk_bus
    assert ph.ping(port, 1) == (1120, sdk.COMM_SUCCESS, 0)
    assert ph.ping(port, 2) == (1020, sdk.COMM_SUCCESS, 0)
    assert ph.ping(port, 9)[1] == sdk.COMM_RX_TIMEOUT
    port.clearPort()
    assert ph.read1ByteTxRx(port, 2, 11) == (3, sdk.COMM_SUCCESS, 0)  # operating mode default
    assert ph.write1ByteTxRx(port, 2, 65, 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 2, 65)[0] == 1
    # signed field: the SDK returns unsigned, the table decodes
    assert ph.write4ByteTxRx(port, 2, 20, XM430["homing_offset"].to_unsigned(-100)) == (sdk.COMM_SUCCESS, 0)
    raw, _, _ = ph.read4ByteTxRx(port, 2, 20)
    assert raw == 2**32 - 100 and XM430["homing_offset"].from_unsigned(raw) == -100
    assert ph.read4ByteTxRx(port, 2, 132)[0] == 2048 - 100  # homing offset shifts Present Position


def test_eeprom_locked_while_torque_on_and_read_only_fields(sdk_bus):
    _, port, ph, _ = sdk_bus
    assert ph.write1ByteTxRx(port, 2, 64, 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 2, 11, 4) == (sdk.COMM_SUCCESS, P.ERR_ACCESS)  # EEPROM, torque on
    assert ph.read1ByteTxRx(port, 2, 11)[0] == 3
    assert ph.write4ByteTxRx(port, 2, 132, 5)[1] == P.ERR_ACCESS  # read-only
    assert ph.write2ByteTxRx(port, 2, 116, 5)[1] == P.ERR_DATA_LENGTH  # half a field
    assert ph.write1ByteTxRx(port, 2, 64, 0)[1] == 0
    assert ph.write1ByteTxRx(port, 2, 11, 4) == (sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 2, 11)[0] == 4


def test_sync_read_replies_in_listed_order_and_sync_write(sdk_bus):
    bus, port, ph, clock = sdk_bus
    order = []
    real_send = bus.send
    bus.send = lambda data, **kw: (order.append(data[4]), real_send(data, **kw))  # record reply IDs
    w = sdk.GroupSyncWrite(port, ph, 65, 1)
    for i, v in ((1, 1), (3, 1), (2, 0)):
        assert w.addParam(i, [v])
    assert w.txPacket() == sdk.COMM_SUCCESS
    r = sdk.GroupSyncRead(port, ph, 64, 2)  # torque + LED
    for i in (3, 1, 2):
        r.addParam(i)
    assert r.txRxPacket() == sdk.COMM_SUCCESS
    assert order == [3, 1, 2]
    assert [r.getData(i, 65, 1) for i in (1, 2, 3)] == [1, 0, 1]


def test_bulk_read_of_different_fields(sdk_bus):
    _, port, ph, _ = sdk_bus
    g = sdk.GroupBulkRead(port, ph)
    assert g.addParam(1, 0, 2) and g.addParam(3, 132, 4)
    assert g.txRxPacket() == sdk.COMM_SUCCESS
    assert g.getData(1, 0, 2) == 1120 and g.getData(3, 132, 4) == 2048


def test_motion_follows_the_trapezoidal_profile_on_the_clock(sdk_bus):
    bus, port, ph, clock = sdk_bus
    ph.write4ByteTxRx(port, 2, 112, 100)   # 22.9 rev/min
    ph.write4ByteTxRx(port, 2, 108, 50)    # 10728.85 rev/min^2
    ph.write1ByteTxRx(port, 2, 64, 1)
    assert ph.write4ByteTxRx(port, 2, 116, 3072) == (sdk.COMM_SUCCESS, 0)
    v = 100 * 0.229 / 60 * 4096           # ticks/s
    a = 50 * 214.577 / 3600 * 4096        # ticks/s^2
    t_total = 1024 / v + v / a            # trapezoid (1024 >= v^2/a)
    clock.sleep(0.5 * t_total)
    mid = ph.read4ByteTxRx(port, 2, 132)[0]
    assert ph.read1ByteTxRx(port, 2, 122)[0] == 1
    assert ph.read1ByteTxRx(port, 2, 123)[0] >> 4 == 3  # trapezoidal profile
    assert abs(mid - (2048 + 512)) <= 2   # symmetric profile: half way at half time
    clock.sleep(0.5 * t_total - 0.01)
    assert ph.read1ByteTxRx(port, 2, 122)[0] == 1
    clock.sleep(0.02)
    assert ph.read1ByteTxRx(port, 2, 122)[0] == 0
    assert ph.read4ByteTxRx(port, 2, 132)[0] == 3072
    assert ph.read1ByteTxRx(port, 2, 123)[0] & 1  # in position


def test_goal_outside_position_limits_is_refused(sdk_bus):
    _, port, ph, _ = sdk_bus
    ph.write4ByteTxRx(port, 3, 48, 3000)
    ph.write1ByteTxRx(port, 3, 64, 1)
    assert ph.write4ByteTxRx(port, 3, 116, 3500)[1] == P.ERR_DATA_LIMIT
    assert ph.write4ByteTxRx(port, 3, 116, 2900)[1] == 0


def test_overload_alarm_reboot_and_power_cycle(sdk_bus):
    bus, port, ph, clock = sdk_bus
    ph.write4ByteTxRx(port, 2, 112, 77)
    ph.write1ByteTxRx(port, 2, 64, 1)
    ph.write4ByteTxRx(port, 2, 116, 2500)
    clock.sleep(0.05)
    bus.servo(2).trip(HW_OVERLOAD)
    value, result, error = ph.read1ByteTxRx(port, 2, 70)
    assert (value, result, error) == (HW_OVERLOAD, sdk.COMM_SUCCESS, P.ERR_ALERT)
    assert ph.read1ByteTxRx(port, 2, 64)[0] == 0  # torque off
    stopped = ph.read4ByteTxRx(port, 2, 132)[0]
    clock.sleep(5.0)
    assert ph.read4ByteTxRx(port, 2, 132)[0] == stopped  # no motion without torque
    assert ph.write1ByteTxRx(port, 2, 64, 1)[1] & 0x7F == P.ERR_RESULT_FAIL  # cannot re-enable
    assert ph.reboot(port, 2) == (sdk.COMM_SUCCESS, P.ERR_ALERT)  # status sent before the reboot
    assert ph.read1ByteTxRx(port, 2, 70) == (0, sdk.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 2, 112)[0] == 0  # RAM back to defaults
    # power cycle: RAM reset, EEPROM kept
    ph.write4ByteTxRx(port, 1, 48, 4000)
    ph.write1ByteTxRx(port, 1, 65, 1)
    bus.power_cycle()
    assert ph.read1ByteTxRx(port, 1, 65)[0] == 0
    assert ph.read4ByteTxRx(port, 1, 48)[0] == 4000


def test_factory_reset_keeps_id_and_baud_with_option_2(sdk_bus):
    _, port, ph, _ = sdk_bus
    ph.write4ByteTxRx(port, 3, 48, 1234)
    assert ph.factoryReset(port, 3, 0x02) == (sdk.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 3, 48)[0] == 4095
    assert ph.ping(port, 3)[1] == sdk.COMM_SUCCESS


def test_status_return_level_zero_answers_only_ping(sdk_bus):
    _, port, ph, _ = sdk_bus
    ph.write1ByteTxRx(port, 2, 68, 0)
    assert ph.read1ByteTxRx(port, 2, 65)[1] == sdk.COMM_RX_TIMEOUT
    port.clearPort()
    assert ph.ping(port, 2)[1] == sdk.COMM_SUCCESS


def test_crc_corrupted_instruction_gets_a_crc_error_status(sdk_bus):
    bus, port, ph, _ = sdk_bus
    pkt = bytearray(P.encode(2, P.INST_READ, bytes([65, 0, 1, 0])))
    pkt[-1] ^= 0xFF
    port.ser.write(bytes(pkt))
    reply = b""
    for _ in range(200):  # bounded: up to ~1 s
        reply += port.ser.read(64)
        if len(reply) >= 11:
            break
        time.sleep(0.005)
    body = reply[7:-2]
    assert reply[4] == 2 and body[0] == P.INST_STATUS and body[1] == P.ERR_CRC


def test_broadcast_ping_lists_every_servo_once(sdk_bus):
    # broadcast ping always waits its full window (~1 s): the only one in the suite.
    _, port, ph, _ = sdk_bus
    data, result = ph.broadcastPing(port)
    assert result == sdk.COMM_SUCCESS
    assert {i: v[0] for i, v in data.items()} == {1: 1120, 2: 1020, 3: 1020}
