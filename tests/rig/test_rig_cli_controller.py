"""``gonio controller status|light|photodiode|trigger`` against the emulator on a real pty (real time)."""

from __future__ import annotations

import pytest

from gonio.cli.main import main
from gonio.rig.clock import RealClock
from sim.controller import ControllerEmulator


@pytest.fixture
def bench():
    with ControllerEmulator(RealClock(), pd_noise=0.0, warmup_depth=0.0) as emu:
        yield emu


def test_status_reports_protocol_capabilities_and_inputs(bench, capsys):
    assert main(["controller", "status", "--port", bench.path]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"{bench.path}: protocol 2.") and "watchdog 10 s" in out[0]
    assert out[1] == "capabilities dimming, photodiode, trigger, temperature, interlock"
    assert out[2].split() == ["E-stop", "released"] and out[4].split()[:2] == ["light", "off"]
    assert out[-1].split() == ["last", "reset", "power-on"]  # protocol 2.2: the cause of the last reset
    bench.inject_reset()  # a brown-out at the next request
    assert main(["controller", "status", "--port", bench.path]) == 0
    assert "last reset  brown-out" in capsys.readouterr().out
    bench.set_estop(True)
    assert main(["controller", "status", "--port", bench.path]) == 0
    assert "E-stop      PRESSED" in capsys.readouterr().out


def test_light_follows_level_on_the_photodiode_and_is_switched_off(bench, capsys):
    assert main(["controller", "light", "--port", bench.path, "--level", "0.5", "--seconds", "0.3",
                 "--every", "0.1"]) == 0
    out = capsys.readouterr().out.splitlines()
    readings = [float(line.split()[1]) for line in out[1:-1]]
    assert len(readings) >= 3 and out[-1] == "light off"
    assert readings == pytest.approx([0.5] * len(readings), rel=1e-3)  # gain 1, no warm-up, no noise
    assert bench.executed["SET_LIGHT"] >= 2
    assert main(["controller", "photodiode", "--port", bench.path, "--samples", "4"]) == 0
    assert capsys.readouterr().out.startswith("photodiode 0.000000")  # left off


def test_trigger_fires_one_pulse(bench, capsys):
    assert main(["controller", "trigger", "--port", bench.path, "--exposure", "0.002"]) == 0
    assert "trigger pulse of 0.002 s started" in capsys.readouterr().out
    assert len(bench.trigger_times) == 1


def test_one_line_errors(bench, capsys):
    assert main(["controller", "status", "--port", "/dev/does-not-exist"]) == 2
    assert capsys.readouterr().err.strip() == ("gonio controller: error: --port: port = '/dev/does-not-exist': "
                                               "no such serial device")
    assert main(["controller", "light", "--port", bench.path, "--level", "1.5"]) == 2
    assert "--level: level = 1.5: must be in [0, 1]" in capsys.readouterr().err
    bench.set_estop(True)
    code = main(["controller", "light", "--port", bench.path, "--seconds", "0.1"])
    err = capsys.readouterr().err.strip()
    assert code != 0 and "light refused: E-stop pressed" in err and "\n" not in err
    assert main(["controller", "trigger", "--port", bench.path, "--exposure", "0"]) == 2
    assert "trigger exposure" in capsys.readouterr().err


def test_python_m_sim_controller_serves_a_pty_for_the_bench_tools(capsys):
    import subprocess
    from gonio import childproc  # children die with this process
    import sys

    proc = childproc.popen([sys.executable, "-m", "sim.controller", "--seconds", "20", "--estop"],
                            stdout=subprocess.PIPE, text=True)
    try:
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/pts/")
        assert main(["controller", "status", "--port", path]) == 0
        assert "E-stop      PRESSED" in capsys.readouterr().out
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_status_says_when_the_watchdog_switched_the_light_off(bench, capsys):
    """A host that stopped talking with the light on: the controller's watchdog switched it off and says so
    in STATUS (WATCHDOG_TRIPPED); `gonio controller status` printed only 'light off' (found by QA, qa-lab)."""
    from gonio.rig.controller import RigController

    ctl = RigController.open(bench.path)
    ctl._transact("SET_WATCHDOG", period_ms=200)
    ctl.set_light(True, 0.5)
    ctl._port.close()  # the host goes away without switching the light off
    ctl._port = None
    import time

    time.sleep(0.6)
    assert main(["controller", "status", "--port", bench.path]) == 0
    out = capsys.readouterr().out
    assert "light       off" in out and "watchdog    TRIPPED" in out, out


def test_light_stops_in_one_line_when_the_e_stop_is_pressed_while_it_is_on(bench, capsys):
    """E-stop pressed during `gonio controller light`: the command printed photodiode readings of ~0 for the
    rest of --seconds, then 'light off' and exit 0, never naming the E-stop (found by QA, qa-lab)."""
    code, err, lines = _light_with(bench, capsys, bench.set_estop, True)
    assert code == 7 and "E-stop pressed" in err and "\n" not in err, (code, err)  # SafetyStop: exit 7
    assert lines < 15  # it stopped, not after --seconds
    assert not bench.light_on


def _light_with(bench, capsys, event, *args):
    """Run `gonio controller light` for 3 s with ``event(*args)`` happening 0.35 s in: ``(exit code, stderr,
    stdout lines)``."""
    import threading

    timer = threading.Timer(0.35, event, args=args)
    timer.start()
    try:
        code = main(["controller", "light", "--port", bench.path, "--level", "0.5", "--seconds", "3",
                     "--every", "0.1"])
    finally:
        timer.cancel()
    captured = capsys.readouterr()
    return code, captured.err.strip(), len(captured.out.splitlines())


@pytest.mark.parametrize("baud", ["0", "-5", "123456789012"])
def test_a_baud_rate_out_of_range_is_one_line_before_the_port_is_opened(bench, capsys, baud):
    """--baud 123456789012 was an OverflowError traceback from termios and --baud 0 (B0: hang up on a real
    serial port) was accepted (found by QA, qa-lab)."""
    assert main(["controller", "status", "--port", bench.path, "--baud", baud]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"gonio controller: error: --baud: baud = {baud}") and "\n" not in err, err
    assert bench.bytes_in == 0


def test_light_stops_in_one_line_when_the_lamp_overheats_while_it_is_on(bench, capsys):
    """The heat sink passes the controller's limit during `gonio controller light`: the controller cuts the light
    and the command says why in one line (exit 7), not after --seconds."""
    code, err, lines = _light_with(bench, capsys, bench.set_heat_sink, 82.0)
    assert code == 7 and "over its temperature limit (82.0 °C)" in err and "\n" not in err, (code, err)
    assert lines < 15 and not bench.light_on
