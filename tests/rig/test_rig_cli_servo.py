"""``gonio servo scan|read|move`` against the emulator on a real pty (real time: small moves)."""

from __future__ import annotations

import pytest

from gonio.cli.main import main
from sim.servo_bus import HW_OVERLOAD, ServoBus


@pytest.fixture
def bench():
    with ServoBus({1: "XM540-W270", 2: "XM430-W350"}, noise_ticks=0.0) as bus:  # RealClock
        yield bus


def test_scan_lists_ids_and_models(bench, capsys):
    assert main(["servo", "scan", "--port", bench.path, "--baud", "57600", "--ids", "1-4"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[1].split() == ["1", "XM540-W270", "1120"] and out[2].split() == ["2", "XM430-W350", "1020"]
    assert len(out) == 3


def test_read_prints_raw_angles(bench, capsys):
    assert main(["servo", "read", "--port", bench.path, "--ids", "1,2"]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[1:]]
    assert rows == [["1", "XM540-W270", "2048", "180.00", "off", "-"], ["2", "XM430-W350", "2048", "180.00", "off", "-"]]


def test_move_waits_until_the_servo_arrives(bench, capsys):
    assert main(["servo", "move", "--port", bench.path, "--id", "2", "--deg", "200", "--unmounted"]) == 0
    out = capsys.readouterr().out
    assert "servo 2: at 2276 ticks = 200.04 deg (goal 2276)" in out
    assert bench.servo(2).peek("present_position") == 2276 and bench.servo(2).peek("moving") == 0


def test_one_line_errors(bench, capsys):
    assert main(["servo", "scan", "--port", "/dev/does-not-exist"]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "gonio servo: error: --port: port = '/dev/does-not-exist': no such serial device"
    assert main(["servo", "scan", "--port", bench.path, "--ids", "5-6"]) == 3
    err = capsys.readouterr().err.strip()
    assert err.startswith("gonio servo: error: ") and "no servo answered" in err and "\n" not in err
    bench.servo(2).trip(HW_OVERLOAD)
    assert main(["servo", "move", "--port", bench.path, "--id", "2", "--deg", "90", "--unmounted"]) == 3
    err = capsys.readouterr().err.strip()
    assert "servo 2: hardware error: overload" in err and "\n" not in err
    assert main(["servo", "move", "--port", bench.path, "--id", "1", "--deg", "400", "--unmounted"]) == 2
    assert "raw angle must be in [0, 360]" in capsys.readouterr().err


def test_reboot_clears_an_alarm_and_says_what_it_was(bench, capsys):
    """A servo in alarm ("torque is off until reboot") had no gonio command to reboot it; only starting a session
    did, silently (found by QA, qa-lab)."""
    bench.servo(2).trip(HW_OVERLOAD)
    assert main(["servo", "reboot", "--port", bench.path, "--id", "2"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("servo 2: rebooted") and "hardware error 0x20 (overload" in out and "now clear" in out
    assert "remove the cause" in out and bench.servo(2).peek("hardware_error_status") == 0
    assert bench.servo(2).peek("torque_enable") == 0  # a reboot never moves it
    assert main(["servo", "reboot", "--port", bench.path, "--id", "300"]) == 2  # refused before a byte
