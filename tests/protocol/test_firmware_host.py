"""What only the firmware's host build shows: its soft start, photodiode timestamp and trigger timing
under simulated time (the SimClock drives the firmware's timer HAL), through the real pty path."""

import pytest

from gonio.rig.controller import RigController
from sim.clock import SimClock
from sim.firmware import FirmwareController


@pytest.fixture
def fw():
    clock = SimClock(50.0)
    with FirmwareController(clock, seed=3, soft_start_ms=100, pd_noise=0.0, warmup_depth=0.0) as emu:
        with RigController.open(emu.path, clock=clock, timeout=0.3) as ctl:
            yield emu, ctl, clock


def test_soft_start_ramps_the_pwm_linearly_then_holds(fw):
    emu, ctl, clock = fw
    ctl.set_light(True, 0.8)
    assert emu.light_output() == 0.0  # switch-on instant: the ramp starts at 0
    clock.sleep(0.050)
    assert emu.light_output() == pytest.approx(0.4, abs=0.01)  # half way through 100 ms
    mean, _ = ctl.read_photodiode(8)
    assert mean == pytest.approx(0.4, abs=0.01)  # the photodiode sees the ramp, not the set level
    clock.sleep(0.060)
    assert emu.light_output() == pytest.approx(0.8, abs=1e-4)
    ctl.set_light(True, 0.2)  # a level change while on is not ramped
    assert emu.light_output() == pytest.approx(0.2, abs=1e-4)


def test_photodiode_timestamp_and_trigger_pulse_in_simulated_time(fw):
    emu, ctl, clock = fw
    clock.sleep(2.5)
    pd = ctl.read_photodiode(4)
    assert emu.photodiode_time == pytest.approx(2.5, abs=0.002)  # uptime at the reading, from the timer HAL
    assert (pd.uptime, pd.span, pd.time) == (emu.photodiode_time, 0.0, clock.now())  # as the reply carried it
    ctl.trigger_camera(0.020)
    assert ctl.status().flags & 0x40  # TRIGGER_ACTIVE
    clock.sleep(0.0199)
    assert ctl.status().flags & 0x40
    clock.sleep(0.0002)
    assert not ctl.status().flags & 0x40  # the pulse lasted exactly 20 ms of simulated time
    assert emu.trigger_times and emu.executed["TRIGGER"] == 1


def test_watchdog_cuts_the_light_after_host_silence(fw):
    emu, ctl, clock = fw
    ctl.set_light(True, 1.0)
    period = emu.watchdog_period
    clock.sleep(period * 0.9)
    assert emu.light_on
    clock.sleep(period * 0.2)
    assert not emu.light_on and ctl.status().flags & 0x08  # WATCHDOG_TRIPPED


def test_without_a_c_compiler_the_simulated_rig_falls_back_to_the_python_emulator(tmp_path, monkeypatch):
    """A new machine without make/gcc still runs `gonio measure --sim`: one warning naming what to install,
    and the Python emulator of the same protocol instead of the firmware's host build."""
    import sim.firmware as fw
    from sim.controller import ControllerEmulator
    from sim.rig import controller_class

    monkeypatch.setattr(fw, "_lib", None)
    monkeypatch.setattr(fw, "LIBRARY", tmp_path / "build" / "libgoniofw.so")  # not built yet
    monkeypatch.setenv("PATH", str(tmp_path))  # no make, no gcc
    with pytest.warns(UserWarning, match="apt-get install gcc make"):
        cls = controller_class("firmware")
    assert cls is ControllerEmulator
    assert not (tmp_path / "build" / "libgoniofw.so").exists()
