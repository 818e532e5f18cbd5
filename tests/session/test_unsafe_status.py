"""Every unsafe controller status (firmware_protocol/SPEC.md §4.2, §4.6) is acted on between poses: the lamp's
heat sink over its limit, the E-stop, the interlock, the controller's watchdog switching the light off. The
session stops before the next move with the light off, keeps what was stored, ends ``safety stop: <cause>`` in
one line with the resume command, and `gonio measure` exits 7."""

from __future__ import annotations

import json

import pytest

from gonio.session.store import scan_samples


def _between_poses(session, pose, act):
    """Run ``act(session)`` right after pose ``pose`` is stored (between two poses)."""
    append = session.store.append

    def append_then(index, samples, meta=None):
        append(index, samples, meta)
        if index == pose:
            act(session)
            session.goals_at = len(session.sim.servo_bus.goal_log)
    session.store.append = append_then


CAUSES = {
    "overtemp": (lambda s: s.sim.controller.set_heat_sink(80.0), "over its temperature limit (80.0 °C)"),
    "estop": (lambda s: s.sim.controller.set_estop(True), "E-stop is pressed"),
    "interlock": (lambda s: s.sim.controller.set_interlock(True), "enclosure interlock is open"),
    # the host goes quiet longer than the watchdog period (open_devices: 30 s) with the light on
    "watchdog": (lambda s: s.sim.clock.sleep(45.0), "watchdog switched the light off"),
}


@pytest.mark.parametrize("cause", sorted(CAUSES))
def test_unsafe_status_between_poses_stops_the_session_with_the_light_off(tmp_path, session_factory, cause):
    act, words = CAUSES[cause]
    s = session_factory(tmp_path / "s")
    _between_poses(s, 2, act)
    emu = s.sim.controller
    result = s.run()
    assert result.status.startswith("safety stop: ") and words in result.status, result.status
    assert "\n" not in result.status and result.error.exit_code == 7
    assert len(s.sim.servo_bus.goal_log) == s.goals_at  # it did not move again
    assert not emu.light_on and emu.light_output() == 0.0
    assert sorted(scan_samples(tmp_path / "s" / "samples.jsonl").records) == [0, 1, 2]
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert manifest["exit_status"] == result.status


def test_a_watchdog_trip_left_by_an_earlier_host_does_not_stop_a_new_session(tmp_path, session_factory):
    """A trip is unsafe once this run switched the light on; one from before is history (SPEC.md §4.6)."""
    s = session_factory(tmp_path / "s")
    ctl = s.devices.controller
    ctl.set_light(True, 1.0)
    s.sim.clock.sleep(45.0)  # the earlier host went quiet: the watchdog cut the light
    st = ctl.status()
    assert not st.light_on and st.unsafe_reason(False) is None and "watchdog" in st.unsafe_reason(True)
    result = s.run()
    assert result.status == "completed"


def test_the_firmware_cuts_the_light_itself_over_its_limit_and_latches_with_hysteresis(tmp_path, session_factory):
    """No request needed: the firmware reads its sensor every 10 ms; the cut stays until the host switches on
    again, and switch-on is refused until the heat sink is 5 °C under the limit."""
    from gonio.errors import SafetyStop

    s = session_factory(tmp_path / "s")
    try:
        emu, ctl, clock = s.sim.controller, s.devices.controller, s.sim.clock
        ctl.set_light(True, 1.0)
        emu.set_heat_sink(90.0)
        clock.sleep(0.02)
        assert not emu.light_on  # cut without a request
        emu.set_heat_sink(67.0)  # under the limit, within the hysteresis
        clock.sleep(0.02)
        st = ctl.status()
        assert not st.light_on and "67.0 °C" in st.unsafe_reason(True)
        with pytest.raises(SafetyStop, match="over its temperature limit"):
            ctl.set_light(True, 1.0)
        emu.set_heat_sink(60.0)
        clock.sleep(0.02)
        assert not emu.light_on and ctl.status().unsafe_reason(True) is None  # cleared, still off (latched)
        ctl.set_light(True, 1.0)
        assert emu.light_on
    finally:
        s.close()


def test_overtemp_through_the_cli_is_one_line_exit_7_with_the_resume_hint(tmp_path, capsys, monkeypatch):
    import sim.rig

    from gonio.cli.main import main

    original = sim.rig.SimRig.begin_pose

    def begin_pose(self, index):
        if index == 2:
            self.controller.set_heat_sink(85.0)
        return original(self, index)

    monkeypatch.setattr(sim.rig.SimRig, "begin_pose", begin_pose)
    code = main(["measure", "--sim", "--plan", "in_plane", "--theta-i", "30", "--theta-o-step", "20",
                 "--out", str(tmp_path / "s"), "--quiet"])
    out, err = capsys.readouterr()
    assert code == 7, (code, err)
    line = [ln for ln in err.splitlines() if ln.startswith("gonio: session ended")]
    assert len(line) == 1 and "safety stop" in line[0] and "85.0 °C" in line[0]
    assert f"gonio resume {tmp_path / 's'}" in line[0] and "Traceback" not in out + err
