"""Safety between poses: the E-stop, the enclosure interlock and every servo's hardware-error status are
checked before every move; a session stops within the pose, names the cause in one line with the
resume command, and sends not one more byte to a servo after an E-stop."""

from __future__ import annotations

import pytest

from gonio.session.store import scan_samples
from sim.servo_bus import HW_OVERHEATING


def _press_after_storing(session, pose, what):
    """Press (the E-stop or open the interlock) right after pose ``pose`` is stored: between two poses."""
    append = session.store.append

    def append_then_press(index, samples, meta=None):
        append(index, samples, meta)
        if index == pose:
            getattr(session.sim.controller, what)(True)
            session.pressed_at = len(session.sim.servo_bus.goal_log)
            session.bytes_at = session.sim.servo_bus.bytes_in
    session.store.append = append_then_press


@pytest.mark.parametrize("what, cause", [("set_estop", "E-stop is pressed"),
                                         ("set_interlock", "enclosure interlock is open")])
def test_estop_or_interlock_between_poses_stops_the_session_before_the_next_move(tmp_path, session_factory,
                                                                                  what, cause):
    s = session_factory(tmp_path / "s")
    _press_after_storing(s, 2, what)
    result = s.run()
    assert result.status.startswith("safety stop: ") and cause in result.status and "\n" not in result.status
    assert len(s.sim.servo_bus.goal_log) == s.pressed_at  # no goal packet after the press
    assert s.sim.servo_bus.bytes_in == s.bytes_at  # not one byte to a servo
    assert sorted(scan_samples(tmp_path / "s" / "samples.jsonl").records) == [0, 1, 2]


def test_estop_during_a_capture_keeps_nothing_of_that_pose(tmp_path, session_factory):
    def press(session):
        session.sim.controller.set_estop(True)
        session.goals_at = len(session.sim.servo_bus.goal_log)

    s = session_factory(tmp_path / "s", hooks={3: press})
    result = s.run()
    assert "E-stop is pressed" in result.status
    assert len(s.sim.servo_bus.goal_log) == s.goals_at
    assert sorted(scan_samples(tmp_path / "s" / "samples.jsonl").records) == [0, 1, 2]


def test_servo_alarm_between_poses_stops_the_session_naming_the_servo(tmp_path, session_factory):
    def overheat(session):
        session.sim.servo_bus.servo(4).trip(HW_OVERHEATING)
        session.goals_at = len(session.sim.servo_bus.goal_log)

    s = session_factory(tmp_path / "s", hooks={2: overheat})
    result = s.run()
    assert "overheating" in result.status and "camera_el" in result.status and "\n" not in result.status
    assert len(s.sim.servo_bus.goal_log) == s.goals_at  # it never moved again
    assert sorted(scan_samples(tmp_path / "s" / "samples.jsonl").records) == [0, 1, 2]


def test_estop_through_the_cli_is_one_line_with_the_resume_hint(tmp_path, capsys, monkeypatch):
    """`gonio measure --sim`: the E-stop pressed at the third pose gives one error line and `gonio resume`."""
    import sim.rig

    from gonio.cli.main import main

    original = sim.rig.SimRig.begin_pose

    def begin_pose(self, index):
        if index == 2:
            self.controller.set_estop(True)
        return original(self, index)

    monkeypatch.setattr(sim.rig.SimRig, "begin_pose", begin_pose)
    code = main(["measure", "--sim", "--plan", "in_plane", "--theta-i", "30", "--theta-o-step", "20",
                 "--out", str(tmp_path / "s")])
    out, err = capsys.readouterr()
    assert code != 0
    assert "E-stop is pressed" in out + err and f"gonio resume {tmp_path / 's'}" in out + err
    assert "Traceback" not in out + err
