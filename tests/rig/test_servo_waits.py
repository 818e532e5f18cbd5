"""How the servo driver waits for replies: in the kernel, not in a loop of reads (issue 17).

The SDK's receive loops read the port back to back until the packet is complete or its timeout passes;
on a non-blocking port that is a busy loop (one core at 100 % per transaction, and an emulator in the same
process starved of the interpreter lock). gonio's port waits in select() for the next byte instead.
"""

from __future__ import annotations

import pytest

from gonio.errors import HardwareTimeout
from gonio.rig.control_table import load_control_table
from gonio.rig.dynamixel import DynamixelAxes

XM430 = load_control_table("XM430-W350")


def _count_reads(bus) -> list[int]:
    calls = [0]
    ser = bus._port.ser
    real = ser.read

    def counting(n=1):
        calls[0] += 1
        return real(n)

    ser.read = counting
    return calls


def test_a_silent_servo_times_out_after_a_few_reads_not_a_busy_loop(bus, servo_bus):
    servo_bus.servo(2).unplug()
    calls = _count_reads(bus)
    with pytest.raises(HardwareTimeout, match="no answer"):
        bus.read(2, XM430, "moving_threshold")
    # every attempt: one read finds nothing, select() waits out the packet timeout, one more read finds nothing
    assert calls[0] <= 4 * (bus.retries + 1)


def test_a_sync_read_of_four_servos_takes_a_few_reads_and_returns_every_value(bus, servo_bus):
    ids = sorted(servo_bus.servos)
    for i in ids:
        servo_bus.servo(i).poke("goal_position", 1000 + 7 * i)
    calls = _count_reads(bus)
    got = bus.sync_read(XM430, "goal_position", "goal_position", ids)
    assert {i: got[i]["goal_position"] for i in ids} == {i: 1000 + 7 * i for i in ids}
    # four status packets of 15 bytes, sent in one write by the emulator: a few reads per packet at most
    assert calls[0] <= 4 * len(ids)


def test_a_settle_poll_is_one_sync_read(rig, bus, servo_bus, clock):
    axes = DynamixelAxes.from_rig(rig, bus, clock)
    try:
        before = servo_bus.packets
        state = axes._state()
        assert servo_bus.packets - before == 1
        for s in state.values():
            assert {"torque_enable", "hardware_error_status", "moving", "present_position"} <= set(s)
            assert s["torque_enable"] == 1 and s["hardware_error_status"] == 0
    finally:
        axes.close()
