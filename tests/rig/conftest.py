"""Fixtures of the servo tests: an emulated bus on a real pty, the real SDK / our driver on top."""

from __future__ import annotations

import pytest

from gonio.rig.dynamixel import DynamixelAxes, DynamixelBus
from gonio.rig.kinematics import load_rig
from sim.clock import SimClock
from sim.faults import LinkFaults
from sim.servo_bus import ServoBus

#: Generous latency term: reply timeout ~ 2*40+2 ms, robust on a loaded 2-core CI machine.
LATENCY_MS = 40.0
#: Lateness of a "late" reply: well past the reply timeout, well inside the driver's late-reply window.
LATE_S = 0.2
WINDOW_S = 0.4


@pytest.fixture
def rig():
    return load_rig()


@pytest.fixture
def clock():
    return SimClock()


@pytest.fixture
def servo_bus(rig, clock):
    with ServoBus({j.servo_id: j.model for j in rig.joints}, clock, seed=1,
                  faults=LinkFaults(seed=2, delay_s=LATE_S)) as bus:
        yield bus


@pytest.fixture
def bus(servo_bus):
    b = DynamixelBus(servo_bus.path, 1_000_000, latency_timer_ms=LATENCY_MS, retries=3, late_reply_window_s=WINDOW_S)
    with b:
        yield b


@pytest.fixture
def axes(rig, bus, clock):
    ax = DynamixelAxes.from_rig(rig, bus, clock)
    yield ax
    ax.close()
