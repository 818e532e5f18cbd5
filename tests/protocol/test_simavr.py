"""The reference firmware's AVR build, run in simavr (an emulated ATmega328P) with its UART on a pty:
`gonio controller status`, the protocol's error codes, the duplicate rule, BUSY, silent drops, the
soft start and the latching E-stop cut — the same bytes a real Uno would see. Emulated time is real
CPU cycles, so these tests keep to a few requests each."""

import subprocess
import sys
import time

import pytest

from firmware_protocol import codec as fp
from gonio.errors import EmergencyStop
from gonio.rig.controller import RigController
from protocol.test_emulator_spec import Raw, err
from sim.simavr import DEBIAN_PACKAGES, SimavrController, avr_size, build
from tests.debian import require


@pytest.fixture(scope="module")
def built():
    require("the firmware's AVR build in simavr", *DEBIAN_PACKAGES)
    return build()


@pytest.fixture
def avr(built):
    with SimavrController() as s:
        yield s


def test_avr_build_fits_the_atmega328p(built):
    flash, ram = avr_size()
    assert 1000 < flash <= 32 * 1024 - 512 and 100 < ram <= 1536


def test_gonio_controller_status_through_simavr(avr):
    r = subprocess.run([sys.executable, "-m", "gonio.cli.main", "controller", "status", "--port", avr.path],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "protocol 2.2, firmware 0x00000202" in r.stdout and "E-stop      released" in r.stdout


def test_error_codes_duplicates_busy_and_silent_drops(avr):
    r = Raw(avr.path)
    try:
        [m] = r.ask(fp.encode_message("HEARTBEAT", 1))
        assert err(m) == ("ERROR", fp.ERR_NOT_READY, fp.HEARTBEAT)
        [m] = r.ask(fp.encode_message("HELLO", 2, major=2, minor=0))  # a 2.0 host
        assert (m.name, m["capabilities"], m["firmware"], m["watchdog_ms"]) == ("HELLO_REPLY", 0x1F, 0x0202, 10_000)
        [m] = r.ask(fp.encode_message("READ_PHOTODIODE", 10, samples=2))
        assert set(m.values) == {"samples", "mean", "sem"}  # the 2.0 reply, without the 2.1 timestamp
        [m] = r.ask(fp.encode_frame(0x42, 3, b"\x01"))
        assert err(m) == ("ERROR", fp.ERR_UNKNOWN_TYPE, 0x42)
        [m] = r.ask(fp.encode_frame(fp.SET_LIGHT, 4, b"\x01\xff"))
        assert err(m) == ("ERROR", fp.ERR_BAD_LENGTH, fp.SET_LIGHT)
        [m] = r.ask(fp.encode_frame(fp.SET_WATCHDOG, 5, (99).to_bytes(4, "little")))
        assert err(m) == ("ERROR", fp.ERR_BAD_VALUE, fp.SET_WATCHDOG)
        trig = fp.encode_message("TRIGGER", 6, exposure_us=500_000)
        [a] = r.ask(trig)
        [b] = r.ask(trig)  # a retry: answered from the cache, not executed again
        assert a == b and a["count"] == 1
        [m] = r.ask(fp.encode_message("TRIGGER", 7, exposure_us=10))
        assert err(m) == ("ERROR", fp.ERR_BUSY, fp.TRIGGER)
        bad = bytearray(fp.encode_message("HEARTBEAT", 8))
        bad[2] ^= 0x01
        assert r.ask(bytes(bad), expect=0) == []
        [m] = r.ask(fp.encode_message("STATUS", 9))
        assert m["flags"] & fp.FLAG_TRIGGER_ACTIVE and m["temperature"] == pytest.approx(2500, abs=100)
    finally:
        r.port.close()


def test_soft_start_photodiode_and_latching_estop(avr):
    with RigController.open(avr.path) as ctl:
        # The soft start ramps the light linearly over 50 ms of the controller's time from switch-on
        # (fw.c soft_start). Every early reading must lie on that ramp, judged by its own timestamp; one
        # must land inside it. On a loaded machine the host may be late by more than 50 emulated ms, so
        # switch on again (up to 20 times) until a reading falls inside the ramp.
        inside = 0
        for _ in range(20):
            ctl.set_light(False)
            before = ctl.status().uptime_s
            ctl.set_light(True, 0.5)
            early = ctl.read_photodiode(1)
            elapsed = early.uptime - before  # >= the time since switch-on
            assert early.mean <= 0.5 * min(1.0, elapsed / 0.05) + 0.01, (early, elapsed)
            if elapsed < 0.04:
                inside += 1
                break
        assert inside, "no reading within the soft start in 20 tries"
        deadline = time.monotonic() + 30
        while ctl.status().uptime_s < early.uptime + 0.1 and time.monotonic() < deadline:
            time.sleep(0.05)  # > the 50 ms soft start in emulated time (slower than real time under load)
        mean, sem = ctl.read_photodiode(16)
        assert mean == pytest.approx(0.5, abs=0.003)
        up0 = ctl.status().uptime_s
        pd = ctl.read_photodiode(255)
        up1 = ctl.status().uptime_s
        # 255 conversions of 13 ADC clocks at 125 kHz (104 us) each plus the soft-float sums (~35 us; measured
        # 137 us a sample), timed by Timer0 in emulated cycles (SPEC.md §4.4)
        assert 254 * 104e-6 < pd.span < 254 * 200e-6 and up0 <= pd.uptime <= up1, (pd, up0, up1)
        avr.set_estop(True)
        deadline = time.monotonic() + 5
        while not ctl.status().estop and time.monotonic() < deadline:
            time.sleep(0.05)
        st = ctl.status()
        assert st.estop and not st.light_on and ctl.read_photodiode(4)[0] == 0.0
        with pytest.raises(EmergencyStop):
            ctl.set_light(True, 0.5)
        avr.set_estop(False)
        time.sleep(0.2)
        st = ctl.status()
        assert not st.estop and not st.light_on  # the cut latches: off until the host switches it on
        ctl.set_light(True, 0.5)
        assert ctl.status().light_on


def test_short_simulated_session_runs_against_the_avr_binary(built, tmp_path):
    import json

    out = tmp_path / "s"
    r = subprocess.run([sys.executable, "-W", "error::ResourceWarning", "-m", "gonio.cli.main", "measure", "--sim",
                        "--sim-controller", "simavr", "--plan", "grid", "--theta-step", "45", "--phi-step", "180",
                        "--theta-max", "45", "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "6/6 poses" in r.stdout and "warning" not in r.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sim"]["controller"] == "simavr"


def test_trigger_pulse_length_on_the_pin_is_the_exposure(avr):
    with RigController.open(avr.path) as ctl:
        for exposure_us in (7, 300, 1000, 25_000):
            ctl.trigger_camera(exposure_us * 1e-6)
            deadline = time.monotonic() + 5
            while len(avr.pulses_us) < 1 and time.monotonic() < deadline:
                time.sleep(0.02)
            [pulse] = avr.pulses_us
            avr.pulses_us.clear()
            # Timer2 counts the exposure in 0.5 us ticks, its constant ISR latency compensated
            assert pulse == pytest.approx(exposure_us, abs=0.5), (exposure_us, pulse)
