"""Host client against the controller emulator over a real pseudo-terminal (no mocks of our code)."""

import math
import time

import pytest

from firmware_protocol import codec as fp
from gonio.errors import ChecksumError, ControllerError, EmergencyStop, HardwareTimeout
from gonio.rig.controller import RigController
from sim.clock import SimClock
from sim.faults import LinkFaults


@pytest.fixture
def rig(Emulator):
    """(emulator, client, clock) on a fresh pty; everything is closed afterwards."""
    clock = SimClock(1000.0)
    emu = Emulator(clock, seed=7).start()
    ctl = RigController.open(emu.path, clock=clock, timeout=0.3)
    yield emu, ctl, clock
    ctl.close()
    emu.stop()


def test_connect_reports_version_capabilities_and_watchdog(rig):
    emu, ctl, clock = rig
    assert (ctl.info.major, ctl.info.minor, ctl.info.watchdog_s) == (2, 2, 10.0) and ctl.session_minor == 2
    st = ctl.status()
    assert not st.flags & fp.FLAG_NOT_CONFIGURED and not st.light_on and st.temperature_c == 25.0


def test_version_mismatch_and_missing_capability_are_refused(Emulator):
    clock = SimClock()
    with Emulator(clock, major=3) as emu:
        with pytest.raises(ControllerError, match="VERSION") as e:
            RigController.open(emu.path, clock=clock)
        assert e.value.code == fp.ERR_VERSION
    with Emulator(clock, capabilities=fp.CAP_TRIGGER) as emu:
        with pytest.raises(ControllerError, match="lacks capabilities: photodiode"):
            RigController.open(emu.path, clock=clock)


def test_open_bad_path_names_it():
    from gonio.errors import ConfigError
    with pytest.raises(ConfigError, match="/dev/does-not-exist"):
        RigController.open("/dev/does-not-exist")


def test_photodiode_follows_warm_up_drift_and_light_output(rig):
    emu, ctl, clock = rig
    ctl.set_light(True, 0.8)
    m0, u0 = ctl.read_photodiode(64)
    true0 = emu.light_output()
    assert true0 == pytest.approx(0.8 * 0.95)  # switch-on: output deficit d = 5 %
    assert abs(m0 - true0) < 5 * u0 + 1e-6 and u0 == pytest.approx(0.002 / 8, rel=0.3)
    ctl.wait(600.0)  # 5 τ of warm-up, watchdog kept fed
    m1, u1 = ctl.read_photodiode(64)
    true1 = emu.light_output()
    assert true1 == pytest.approx(0.8 * (1 - 0.05 * math.exp(-5.0)), rel=1e-4)  # I = L(1 - d e^(-t/τ))
    assert abs(m1 - true1) < 5 * u1 + 1e-6
    assert m1 / m0 == pytest.approx(true1 / true0, abs=0.01) and true1 / true0 > 1.04
    st = ctl.status()
    assert st.light_on and st.temperature_c > 30.0  # lamp heats the box


def test_photodiode_noise_is_seeded(Emulator):
    def readings(seed):
        clock = SimClock()
        with Emulator(clock, seed=seed) as emu, RigController.open(emu.path, clock=clock) as ctl:
            ctl.set_light(True, 1.0)
            return [ctl.read_photodiode(1)[0] for _ in range(5)]
    a, b, c = readings(3), readings(3), readings(4)
    assert a == b and a != c and len(set(a)) == 5


def test_watchdog_switches_light_off_after_silence_on_the_sim_clock(rig):
    emu, ctl, clock = rig
    ctl.set_light(True, 1.0)
    clock.sleep(9.0)
    assert ctl.status().light_on  # 9 s < 10 s: still on (and the STATUS fed the watchdog)
    clock.sleep(10.5)  # host silent longer than the period
    assert emu.light_output() == 0.0
    st = ctl.status()
    assert not st.light_on and st.flags & fp.FLAG_WATCHDOG_TRIPPED
    ctl.set_light(True, 1.0)  # switching on again clears the flag
    assert not ctl.status().flags & fp.FLAG_WATCHDOG_TRIPPED


def test_wait_keeps_the_watchdog_fed_and_period_is_configurable(rig):
    emu, ctl, clock = rig
    ctl.set_watchdog(0.5)
    assert emu.watchdog_period == 0.5 and ctl.status().flags == 0
    ctl.set_light(True, 1.0)
    t0 = clock.now()
    ctl.wait(30.0)
    assert clock.now() - t0 == pytest.approx(30.0) and emu.light_on
    clock.sleep(0.6)
    assert not emu.light_on


def test_wait_sends_heartbeats_only_where_silence_would_pass_half_the_period(rig):
    """Between steps always; after the last one only when the last request is more than period/2 ago: a short
    settle right after a request costs no round trip, and the watchdog is fed within period/2 either way."""
    emu, ctl, clock = rig  # watchdog 10 s
    ctl.set_light(True, 1.0)
    beats = lambda: emu.executed["HEARTBEAT"]  # noqa: E731
    n = beats()
    ctl.wait(0.3)  # a settle: 0.3 s after SET_LIGHT
    assert beats() == n and emu.light_on
    clock.sleep(4.9)
    ctl.wait(0.3)  # 5.2 s of silence > 5 s: fed
    assert beats() == n + 1
    ctl.wait(12.0)  # steps of 5 s: 5 (beat) 5 (beat) 2 (2 s since the last beat: none)
    assert beats() == n + 3 and emu.light_on
    clock.sleep(9.9)  # 11.9 s since the last request: the watchdog trips
    assert not emu.light_on


def test_trigger_pulses_back_to_back_wait_on_the_clock(rig):
    emu, ctl, clock = rig
    t0 = clock.now()
    for _ in range(3):
        ctl.trigger_camera(2.0)
    assert emu.trigger_times == pytest.approx([t0, t0 + 2.0, t0 + 4.0])
    assert ctl.status().flags & fp.FLAG_TRIGGER_ACTIVE


def test_estop_refuses_light_and_reports(rig):
    emu, ctl, clock = rig
    ctl.set_light(True, 1.0)
    emu.set_estop(True)
    assert emu.light_output() == 0.0
    st = ctl.status()
    assert st.estop and not st.light_on
    with pytest.raises(EmergencyStop) as e:
        ctl.set_light(True, 1.0)
    assert e.value.code == fp.ERR_ESTOP
    emu.set_estop(False)
    emu.set_interlock(True)
    with pytest.raises(EmergencyStop):
        ctl.set_light(True, 1.0)
    assert ctl.status().interlock_open
    emu.set_interlock(False)
    ctl.set_light(True, 1.0)
    assert ctl.status().light_on


@pytest.mark.parametrize("kind", ["drop", "corrupt", "truncate", "delay"])
def test_retried_command_executes_once(rig, kind):
    emu, ctl, clock = rig
    emu.faults.delay_s = 0.45  # later than the 0.3 s reply timeout
    emu.faults.inject_next(kind)
    ctl.trigger_camera(0.01)
    assert emu.executed["TRIGGER"] == 1 and emu.duplicates == 1 and ctl.retry_count == 1
    if kind == "delay":
        time.sleep(0.3)  # the late original reply arrives now, after the retry's answer
    clock.sleep(1.0)
    assert ctl.status().flags & fp.FLAG_TRIGGER_ACTIVE == 0  # the answer to STATUS, not a stale TRIGGER reply
    ctl.heartbeat()
    assert ctl.retry_count == 1


def test_garbage_before_a_reply_costs_no_retry(rig):
    emu, ctl, clock = rig
    emu.faults.inject_next("garbage", times=5)
    for _ in range(5):
        ctl.heartbeat()
    assert ctl.retry_count == 0 and emu.faults.counts["garbage"] == 5


def test_late_reply_is_never_the_answer_to_the_next_request(rig):
    emu, ctl, clock = rig
    ctl.retries = 0
    emu.faults.delay_s = 0.4
    emu.faults.inject_next("delay")
    with pytest.raises(HardwareTimeout):
        ctl.set_light(True, 1.0)  # executed by the controller; its reply comes too late
    time.sleep(0.2)  # the late SET_LIGHT_REPLY is now in the host's input buffer
    st = ctl.status()
    assert st.light_on and st.temperature_c == 25.0  # a STATUS_REPLY, not the stale SET_LIGHT_REPLY


def test_persistent_faults_raise_typed_errors_after_bounded_retries(rig):
    emu, ctl, clock = rig
    ctl.retries, ctl.timeout = 2, 0.1
    emu.faults.inject_next("drop", times=3)
    with pytest.raises(HardwareTimeout, match="after 3 attempts"):
        ctl.heartbeat()
    emu.faults.inject_next("corrupt", times=3)
    with pytest.raises(ChecksumError, match="corrupted reply to HEARTBEAT"):
        ctl.heartbeat()
    ctl.heartbeat()  # the link is fine again
    emu.silent = True
    with pytest.raises(HardwareTimeout):
        ctl.status()


def test_reset_that_forgets_state_is_recovered(rig):
    emu, ctl, clock = rig
    ctl.set_watchdog(30.0)
    ctl.set_light(True, 0.5)
    clock.sleep(20.0)
    emu.inject_reset()
    m, u = ctl.read_photodiode(16)  # NOT_READY -> re-handshake, watchdog and light restored, retried
    assert ctl.resets_seen == 1 and emu.resets == 1
    assert emu.watchdog_period == 30.0 and emu.light_on
    assert m == pytest.approx(0.5 * 0.95, abs=0.01)  # the lamp restarted cold
    st = ctl.status()
    assert st.uptime_s == 0.0 and not st.flags & fp.FLAG_NOT_CONFIGURED


def test_unconfigured_controller_answers_not_ready_without_executing(Emulator):
    clock = SimClock()
    with Emulator(clock) as emu:
        ctl = RigController.open(emu.path, clock=clock, connect=False)
        assert ctl.status().flags & fp.FLAG_NOT_CONFIGURED
        assert emu.executed["SET_LIGHT"] == 0
        ctl.close()


def test_soak_with_random_faults_every_command_executes_exactly_once(Emulator):
    clock = SimClock()
    faults = LinkFaults(drop_rate=0.05, corrupt_rate=0.05, garbage_rate=0.05, truncate_rate=0.05, seed=11)
    with Emulator(clock, faults=faults, seed=1) as emu:
        with RigController.open(emu.path, clock=clock, timeout=0.1, retries=8) as ctl:
            for _ in range(40):
                ctl.trigger_camera(0.001)
            assert emu.executed["TRIGGER"] == 40 and len(emu.trigger_times) == 40
            assert ctl.retry_count > 3 and emu.duplicates > 0
    assert not emu.light_on  # close() switched the light off


def test_photodiode_reading_is_timestamped_on_the_controllers_clock(rig):
    """SPEC.md §4.4 over the pty: time_ms is the uptime (STATUS's clock) of the samples; successive
    readings differ by the simulated time between them; the host places the reading on its Clock."""
    emu, ctl, clock = rig
    ctl.set_light(True, 1.0)
    up0 = ctl.status().uptime_s
    a = ctl.read_photodiode(8)
    clock.sleep(2.345)
    b = ctl.read_photodiode(8)
    assert a.uptime == pytest.approx(up0, abs=0.0015) and a.span == 0.0 and a.samples == 8
    assert b.uptime - a.uptime == pytest.approx(2.345, abs=0.0015)
    assert b.time == clock.now() and b.time - a.time == pytest.approx(2.345)
    mean, sem = b  # the (mean, sem) pair it always was
    assert (mean, sem) == (b.mean, b.sem) and mean == pytest.approx(emu.light_output(), abs=5 * sem)


def test_a_2_0_controller_and_a_2_0_host_still_talk(Emulator):
    """Minor versions are compatible both ways (SPEC.md §3): this host with a 2.0 controller reads
    photodiode values without timestamp; a 2.0 host (raw bytes) gets the 9-byte 2.0 reply."""
    clock = SimClock(3.0)
    with Emulator(clock, minor=0) as emu:
        with RigController.open(emu.path, clock=clock, timeout=0.3) as ctl:
            assert (ctl.info.minor, ctl.session_minor) == (0, 0)
            pd = ctl.read_photodiode(4)
            assert pd.uptime is None and pd.span is None and pd.time == 3.0 and 0 <= pd.mean < 0.05
    from protocol.test_emulator_spec import Raw
    with Emulator(clock) as emu:
        r = Raw(emu.path)
        try:
            [m] = r.ask(fp.encode_message("HELLO", 1, major=2, minor=0))
            assert (m["minor"], emu.session_minor) == (2, 0)  # the controller is 2.2, the session 2.0
            [m] = r.ask(fp.encode_message("READ_PHOTODIODE", 2, samples=4))
            assert set(m.values) == {"samples", "mean", "sem"}  # the 9-byte reply of 2.0
        finally:
            r.port.close()
