"""``gonio servo setup`` (gonio.rig.provision) over real ptys with the servo emulator, through the real
dynamixel-sdk: a scan finds servos at different baud rates; a factory servo (ID 1 at 57,600) is given the rig
file's ID and 1 Mbps and read back; a bus with two servos (or two sharing an ID) is refused for a change with
nothing changed; factory reset; the same guards as ``servo move`` (E-stop, --unmounted) and a confirmation.
Issue 28: gonio had no scan across baud rates, no ID/baud change, no factory reset."""

from __future__ import annotations

import pytest

from gonio.cli.main import main
from gonio.rig.clock import RealClock
from gonio.rig.dynamixel import DynamixelBus
from gonio.rig.kinematics import load_rig
from sim.controller import ControllerEmulator
from sim.servo_bus import ServoBus, parse_servos

RIG = load_rig("default")
FAST = ["--max-id", "10"]  # broadcast pings wait for IDs 0..10 only: ~0.1 s per rate instead of ~1 s


def setup(bus, *extra):
    return main(["servo", "setup", "--port", bus.path, *FAST, *extra])


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_the_emulator_serves_the_shipped_mixed_rig_at_its_rate():
    with ServoBus(parse_servos(rig="default")) as emu:
        with DynamixelBus(emu.path, RIG.baud) as bus:
            assert {j.servo_id: bus.ping(j.servo_id) for j in RIG.joints} == {1: 1120, 2: 1020, 3: 1120, 4: 1020}
        with DynamixelBus(emu.path, 57600, retries=0) as bus:  # the servos hear only their own rate
            assert bus.broadcast_ping(10) == ({}, 0)


def test_the_scan_finds_servos_at_every_standard_rate(capsys):
    units = [(1, "XM540-W270", 57600), (2, "XM430-W350", 1000000), (5, "XM430-W350", 4500000),
             (9, "XM540-W270", 9600)]
    with ServoBus(units) as emu:
        assert setup(emu) == 0
    rows = {tuple(line.split()[:3]) for line in capsys.readouterr().out.splitlines()[1:]}
    assert rows == {("57600", "1", "XM540-W270"), ("1000000", "2", "XM430-W350"), ("4500000", "5", "XM430-W350"),
                    ("9600", "9", "XM540-W270")}


def test_a_factory_servo_gets_the_rig_files_id_and_rate_and_is_read_back(capsys):
    with ServoBus([(1, "XM540-W270", 57600)]) as emu:
        emu.servo(1).poke("torque_enable", 1)  # torque on: the EEPROM is locked until it goes off
        assert setup(emu, "--rig", "default", "--joint", "camera_az", "--yes", "--unmounted") == 0
        out = capsys.readouterr().out
        assert "read back: ID 3 at 1000000 baud (XM540-W270)" in out, out
        s = emu.servo(3)
        assert s.peek("id") == 3 and ServoBus.baud_of(s) == 1000000 and s.peek("torque_enable") == 0
        with DynamixelBus(emu.path, 1000000) as bus:
            assert bus.ping(3) == 1120
        with DynamixelBus(emu.path, 57600) as bus:
            assert bus.broadcast_ping(10) == ({}, 0)  # nothing left at the factory ID and rate


def test_a_model_that_is_not_the_joints_is_refused():
    with ServoBus([(1, "XM430-W350", 57600)]) as emu:
        assert setup(emu, "--rig", "default", "--joint", "camera_az", "--yes", "--unmounted") == 2
        assert emu.servo(1).peek("id") == 1


@pytest.mark.parametrize("units, says", [
    ([(1, "XM540-W270", 57600), (2, "XM430-W350", 1000000)], "2 servos answer"),
    ([(1, "XM540-W270", 57600), (1, "XM430-W350", 57600)], "colliding replies at 57600 baud"),
])
def test_a_change_with_more_than_one_servo_on_the_bus_is_refused_and_nothing_changes(units, says, capsys):
    with ServoBus(units) as emu:
        assert setup(emu, "--set-id", "7", "--yes", "--unmounted") == 3
        line = one_line(capsys)
        assert says in line and "connect one servo at a time" in line, line
        assert [(s.dxl_id, ServoBus.baud_of(s)) for s in emu.units] == [(u[0], u[2]) for u in units]


def test_id_and_rate_by_hand_then_factory_reset_all_brings_back_id_1_at_57600(capsys):
    with ServoBus([(1, "XM430-W350", 57600)]) as emu:
        assert setup(emu, "--set-id", "4", "--set-baud", "4500000", "--yes", "--unmounted") == 0
        s = emu.units[0]
        assert (s.dxl_id, ServoBus.baud_of(s)) == (4, 4500000)
        s.poke("max_position_limit", 3000)  # a setting of the rig's, in EEPROM
        assert setup(emu, "--factory-reset", "keep-id-baud", "--yes", "--unmounted") == 0
        assert (s.dxl_id, ServoBus.baud_of(s), s.peek("max_position_limit")) == (4, 4500000, 4095)
        assert setup(emu, "--factory-reset", "all", "--yes", "--unmounted") == 0
        assert (s.dxl_id, ServoBus.baud_of(s)) == (1, 57600)
        assert "read back: ID 1 at 57600 baud (XM430-W350)" in capsys.readouterr().out


def test_the_emulator_locks_the_eeprom_while_torque_is_on():
    from gonio.errors import HardwareError
    from gonio.rig.control_table import load_control_table

    table = load_control_table("XM430-W350")
    with ServoBus([(1, "XM430-W350", 57600)]) as emu, DynamixelBus(emu.path, 57600) as bus:
        bus.write(1, table, "torque_enable", 1)
        with pytest.raises(HardwareError, match="access error"):
            bus.write(1, table, "baud_rate", 3)
        assert ServoBus.baud_of(emu.servo(1)) == 57600


def test_guards_nothing_changes_without_the_e_stop_checked_or_a_confirmation(capsys):
    with ServoBus([(1, "XM540-W270", 57600)]) as emu, ControllerEmulator(RealClock(), pd_noise=0.0) as ctl:
        assert setup(emu, "--set-id", "3", "--yes") == 2  # mounted: needs the controller (or --unmounted)
        assert "--controller-port" in one_line(capsys) and emu.bytes_in == 0
        ctl.set_estop(True)
        assert setup(emu, "--set-id", "3", "--yes", "--controller-port", ctl.path) == 7  # a safety stop
        assert "E-stop" in one_line(capsys) and emu.bytes_in == 0
        ctl.set_estop(False)
        assert setup(emu, "--set-id", "3", "--controller-port", ctl.path) == 2  # stdin is no terminal: --yes
        assert "--yes" in one_line(capsys) and emu.servo(1).peek("id") == 1
        assert setup(emu, "--set-id", "3", "--yes", "--controller-port", ctl.path) == 0
        assert emu.units[0].dxl_id == 3
