"""A serial link that goes away mid-session (USB adapter unplugged, controller board powered off): the
drivers raise gonio's HardwareError naming the port, never the OS's OSError / pyserial's SerialException
(which `gonio measure` printed as a Python traceback, exit 1, without the resume line; found by QA, qa-lab).

Unplugging is the emulator closing its pty: the host's next read or write on the port fails with EIO.
"""

from __future__ import annotations

import pytest

from gonio.errors import HardwareError
from gonio.rig.control_table import load_control_table
from gonio.rig.controller import RigController
from gonio.rig.dynamixel import DynamixelBus
from sim.clock import SimClock
from sim.controller import ControllerEmulator
from sim.servo_bus import ServoBus

XM430 = load_control_table("XM430-W350")


def _no_traceback(call):
    """``call()`` raises HardwareError (not OSError); its message is one line."""
    with pytest.raises(HardwareError) as e:
        call()
    assert not isinstance(e.value, OSError)
    assert "\n" not in str(e.value) and "link lost" in str(e.value), str(e.value)
    return str(e.value)


def test_servo_bus_unplugged_is_a_hardware_error_naming_the_port():
    emu = ServoBus({1: "XM430-W350", 2: "XM430-W350"}, SimClock()).start()
    bus = DynamixelBus(emu.path, 1_000_000, latency_timer_ms=10.0, retries=1)
    bus.open()
    try:
        assert bus.ping(1) == XM430.model_number
        emu.stop()  # unplugged
        msg = _no_traceback(lambda: bus.read(1, XM430, "present_position"))
        assert emu.path in msg
        _no_traceback(lambda: bus.sync_read(XM430, "moving", "present_position", [1, 2]))
        _no_traceback(lambda: bus.scan([1, 2]))
    finally:
        bus.close()  # closing a dead port does not raise either


def test_controller_unplugged_is_a_hardware_error_naming_the_port():
    clock = SimClock(1000.0)
    emu = ControllerEmulator(clock, seed=1).start()
    ctl = RigController.open(emu.path, clock=clock, timeout=0.2)
    try:
        ctl.status()
        emu.stop()  # unplugged
        msg = _no_traceback(lambda: ctl.read_photodiode(4))
        assert emu.path in msg
        _no_traceback(ctl.status)
    finally:
        ctl.close()
