"""Device faults gonio recovers from on its own are still said (one line each).

A servo found with a hardware error (overload, overheating, ...) when a session starts is rebooted so the
session can run (DynamixelAxes.configure, clear_alarms); the person running it must be told, since an
overload means something blocked the arm. Before, the reboot was silent: nothing on the terminal, nothing
anywhere (DynamixelAxes.cleared_alarms was filled and never read; found by QA, qa-lab). The manifest's
``last_run.recovered_faults`` records them too."""

from __future__ import annotations

import json

from gonio.cli.main import main
from sim.rig import SimRig
from sim.servo_bus import HW_OVERLOAD


def test_a_servo_alarm_cleared_at_start_is_said(tmp_path, monkeypatch, capfd):
    start = SimRig.start

    def start_with_a_tripped_servo(self):
        out = start(self)
        self.trip("light_el", HW_OVERLOAD)
        return out

    monkeypatch.setattr(SimRig, "start", start_with_a_tripped_servo)
    assert main(["measure", "--sim", "--plan", "in_plane", "--theta-i-step", "40", "--theta-o-step", "40",
                 "--quiet", "--out", str(tmp_path / "s")]) == 0
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if "light_el" in line]
    assert len(lines) == 1 and "overload" in lines[0] and "0x20" in lines[0] and "reboot" in lines[0], err
    run = json.loads((tmp_path / "s" / "manifest.json").read_text())["last_run"]
    assert run["recovered_faults"] == {"servo_alarms_cleared": {"light_el": 0x20}}  # the record says it too


def test_a_controller_reset_during_the_session_is_said(tmp_path, monkeypatch, capfd):
    """A brown-out of the rig controller mid-session is recovered (re-handshake, light switched on again) and
    the samples are good, but it was silent (RigController.resets_seen never read; lab bench: the session
    took 83 s instead of 43 s without a word; found by QA, qa-lab)."""
    begin = SimRig.begin_pose

    def begin_with_a_reset(self, index):
        begin(self, index)
        if index == 1:
            self.reset_controller()

    monkeypatch.setattr(SimRig, "begin_pose", begin_with_a_reset)
    assert main(["measure", "--sim", "--plan", "in_plane", "--theta-i-step", "40", "--theta-o-step", "40",
                 "--quiet", "--out", str(tmp_path / "s")]) == 0
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if "reset" in line]
    assert len(lines) == 1 and "rig controller" in lines[0] and "1 time" in lines[0], err
    run = json.loads((tmp_path / "s" / "manifest.json").read_text())["last_run"]
    assert run["recovered_faults"] == {"controller_resets": 1}


def test_a_run_without_faults_records_none(measured):
    assert json.loads((measured / "manifest.json").read_text())["last_run"]["recovered_faults"] == {}
