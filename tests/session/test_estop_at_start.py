"""A session started (or resumed) while the E-stop is pressed or the enclosure is open sends not one byte
to the servos: the rig controller is asked first. Before, open_devices scanned and configured the servos
(EEPROM writes, a reboot of any alarmed servo, torque on) and only then met the E-stop at the first pose's
safety check: 634 bytes to the servo bus of the lab bench with the E-stop pressed (found by QA, qa-lab)."""

from __future__ import annotations

import pytest

from gonio.errors import EmergencyStop
from sim.rig import SimRig, SimRigConfig
from sim.servo_bus import HW_OVERLOAD


@pytest.mark.parametrize("cause", ["estop", "interlock"])
def test_no_byte_to_a_servo_when_the_session_opens_with_the_e_stop_pressed(cause):
    with SimRig(config=SimRigConfig(controller="python")) as sim:
        sim.trip("light_el", HW_OVERLOAD)  # an alarmed servo must not be rebooted behind the E-stop either
        (sim.controller.set_estop if cause == "estop" else sim.controller.set_interlock)(True)
        before = sim.servo_bus.bytes_in
        with pytest.raises(EmergencyStop) as e:
            sim.open_devices()
        msg = str(e.value)
        assert "\n" not in msg and ("E-stop" if cause == "estop" else "interlock") in msg, msg
        assert sim.servo_bus.bytes_in == before
        assert sim.servo_bus.servo(2).peek("hardware_error_status") == HW_OVERLOAD  # not rebooted
        sim.controller.set_estop(False)
        sim.controller.set_interlock(False)
        devices = sim.open_devices()
        devices.close()
        assert sim.servo_bus.bytes_in > before
