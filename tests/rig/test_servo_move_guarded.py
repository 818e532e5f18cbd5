"""``gonio servo move`` on a rig: the E-stop is asked first (not one byte to the servo while it is pressed), the
joint must stay within the rig's limits and the arms clear of each other along the whole move, the other joints
where they are; a servo on the bench says ``--unmounted``. It moved a mounted arm with the E-stop pressed, past
the rig's limits and into the other arm (found by QA, qa-lab). Emulators on real ptys, real time."""

from __future__ import annotations

import pytest

from gonio.cli.main import main
from gonio.rig.clock import RealClock
from gonio.rig.kinematics import load_rig
from sim.controller import ControllerEmulator
from sim.servo_bus import ServoBus

RIG = load_rig("default")
#: raw ticks of the default rig's joints parked at light_el 30°, camera_el −20° (gear ratio 2 on the elevations)
PARK = {1: 2048.0, 2: 2048.0 + 2 * 30 / 360 * 4096, 3: 2048.0, 4: 2048.0 - 2 * 20 / 360 * 4096}


@pytest.fixture
def rig():
    with ServoBus({j.servo_id: j.model for j in RIG.joints}, noise_ticks=0.0, positions=PARK) as bus, \
            ControllerEmulator(RealClock(), pd_noise=0.0, warmup_depth=0.0) as ctl:
        yield bus, ctl


def move(bus, ctl, deg, *extra):
    return main(["servo", "move", "--port", bus.path, "--baud", str(RIG.baud), "--id", "4", "--deg", str(deg),
                 "--controller-port", ctl.path, "--rig", "default", *extra])


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_mounted_servo_needs_the_controller_and_the_rig_or_unmounted(rig, capsys):
    bus, _ = rig
    assert main(["servo", "move", "--port", bus.path, "--baud", str(RIG.baud), "--id", "4", "--deg", "150"]) == 2
    assert "--controller-port" in one_line(capsys) and bus.bytes_in == 0


def test_nothing_goes_to_the_servo_while_the_e_stop_is_pressed(rig, capsys):
    bus, ctl = rig
    ctl.set_estop(True)
    assert move(bus, ctl, 150) == 7  # a safety stop (gonio.errors.SafetyStop)
    assert "E-stop is pressed: nothing was sent to the servo" in one_line(capsys)
    assert bus.bytes_in == 0


def test_a_move_within_the_limits_and_clear_of_the_other_arm_arrives(rig, capsys):
    bus, ctl = rig
    assert move(bus, ctl, 100) == 0  # camera_el −40°
    assert abs(bus.servo(4).peek("present_position") - round(100 / 360 * 4096)) <= 3


@pytest.mark.parametrize("deg, says", [(240, "the arms would collide at"), (352, "outside the rig's limits")])
def test_a_move_into_the_other_arm_or_past_the_limits_is_refused_before_it_starts(rig, capsys, deg, says):
    bus, ctl = rig
    before = bus.servo(4).peek("goal_position")
    assert move(bus, ctl, deg) == 2  # camera_el +30° (where the light arm is), +86° (limit 85°)
    line = one_line(capsys)
    assert "joint camera_el" in line and says in line, line
    assert bus.servo(4).peek("goal_position") == before and bus.servo(4).peek("torque_enable") == 0
