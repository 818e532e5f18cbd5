"""A session (or calibration) whose poses are mostly unusable does not say "completed": it stops or ends
``unusable: ...`` naming the causes, exit status 8; a calibration that lost many poses warns with the causes
(gonio.session.usability)."""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import pytest

from gonio.errors import ConfigError
from gonio.plan.plan import CaptureSettings, Plan
from gonio.rig.kinematics import load_rig, read_rig_text
from gonio.samples import NO_BOARD, SATURATED, SampleSet
from gonio.session import usability as U
from gonio.session.geocal_session import calibration_session_plan
from gonio.session.store import load_session, _read_manifest


def _samples(flags):
    n = len(flags)
    z = np.zeros((n, 3))
    z[:, 2] = 1.0
    return SampleSet(z, z, np.ones((n, 3)), np.ones((n, 3)), flags=np.asarray(flags))


def test_a_pose_is_unusable_when_none_of_its_samples_is_and_the_cause_is_the_flag_most_carry():
    assert U.sample_cause(_samples([0, NO_BOARD])) is None
    assert U.sample_cause(_samples([NO_BOARD, NO_BOARD | SATURATED, NO_BOARD])) == "board not found (every sample NO_BOARD)"
    assert U.sample_cause(_samples([SATURATED, SATURATED, NO_BOARD])) == "saturated"
    assert "no samples" in U.sample_cause(SampleSet.empty())


def test_the_counts_stop_a_run_end_it_unusable_or_warn_at_their_fractions():
    u = U.Usability()
    for _ in range(U.STOP_AFTER - 1):
        u.add("camera frame: ChArUco board not found (fewer than 6 corners)")
    assert u.should_stop() is None  # too few poses tried to judge
    u.add("highlight at pixel (3.0, 4.5) is 1.2 px from the tile's edge (2.0 needed)")
    stop = u.should_stop()
    assert stop.startswith("unusable: stopped after 10 poses") and "board not found: 9" in stop
    assert "highlight too near the tile's edge: 1" in stop
    u = U.Usability()
    for k in range(20):
        u.add("saturated" if k % 3 else None)  # 13 of 20 unusable: goes on (< 90 %), ends unusable (> 50 %)
    assert u.should_stop() is None and u.final_status() == "unusable: 13 of 20 poses tried gave nothing usable (saturated: 13)"
    u = U.Usability()
    for k in range(10):
        u.add("ChArUco board not found" if k < 3 else None)  # 30 %: completed, with a warning
    assert u.final_status() is None and u.warning() == "warning: 3 of 10 poses (30 %) gave nothing usable: board not found: 3"
    assert U.Usability.from_dict(u.to_dict()) == u


def test_a_session_that_never_sees_the_board_stops_unusable_and_says_why(tmp_path):
    """The host's board is not the one on the stage (another ArUco dictionary): every sample would be NO_BOARD.
    The run stops after 10 poses of 14 with the cause, recorded in the manifest; the samples measured stay."""
    from sim.rig import SimRig, SimRigConfig

    from gonio.pipeline.target import CharucoSpec
    from gonio.session.runner import SessionRunner
    from gonio.session.store import SessionStore

    deg = [(t, 0, t, 180) for t in (10, 15, 20, 25, 30, 35, 40)] + [(t, 90, t, 270) for t in (10, 15, 20, 25, 30, 35, 40)]
    plan = Plan(poses=np.radians(np.asarray(deg, float)), capture=CaptureSettings(), generator="custom")
    sim = SimRig(config=SimRigConfig(seed=1)).start()
    devices = None
    try:
        devices = sim.open_devices()
        store = SessionStore.create(tmp_path / "s", {"plan": plan, "mode": "test"})
        wrong = replace(sim.layout, charuco=replace(sim.layout.charuco, dictionary="DICT_6X6_250"))
        assert wrong.charuco.dictionary != sim.layout.charuco.dictionary
        result = SessionRunner(plan, store, devices, sim.calibration, wrong, before_pose=sim.begin_pose,
                               stream=None).run()
    finally:
        if devices is not None:
            devices.close()
        sim.stop()
    assert not result.ok
    assert result.status == ("unusable: stopped after 10 poses, 10 of them gave nothing usable (board not found "
                             "(every sample NO_BOARD): 10)")
    assert result.usability == {"tried": 10, "unusable": 10, "causes": {"board not found (every sample NO_BOARD)": 10}}
    m = _read_manifest(tmp_path / "s")
    assert m["exit_status"] == result.status and m["last_run"]["usability"]["unusable"] == 10
    _, s = load_session(tmp_path / "s")
    assert len(np.unique(s.pose)) == 10 and np.all(s.flags & NO_BOARD)


def _calibration_args(d):
    return argparse.Namespace(out=str(d / "cal.toml"), session=None, sim=True, sim_as_built="3", seed=0, quiet=True)


def test_a_calibration_that_loses_poses_warns_with_the_causes(tmp_path, capsys):
    """Four board poses, two highlight poses whose light is parked away (no reflection in the tile): a third of
    the poses lost, said with the cause (the estimate is then refused: too few poses)."""
    from gonio.cli.calibrate import _new_session

    rig = load_rig("default")
    plan = calibration_session_plan(rig, quick=True)
    kinds = plan.params["kinds"]
    idx = [0, 3, 5, 7, 1, 4]
    plan = replace(plan, poses=plan.poses[idx], joints=plan.joints[idx],
                   params={**plan.params, "kinds": ["camera"] * 4 + ["highlight"] * 2})
    assert [kinds[i] for i in idx] == ["camera"] * 6
    text, src = read_rig_text("default")
    with pytest.raises(ConfigError, match="camera poses"):
        _new_session(_calibration_args(tmp_path), rig, text, src, plan)
    err = capsys.readouterr().err
    assert "warning: 2 of 6 poses (33 %) gave nothing usable: no highlight (too faint): 2" in err
    assert "the tile centred and flush" in err


def test_a_calibration_whose_highlights_never_come_writes_nothing_and_exits_8(tmp_path, capsys):
    """Every highlight pose has the light parked away (no reflection in the tile): the session stops after 10
    poses, ``unusable``, naming the cause, exit status 8, no calibrated rig file."""
    from gonio.cli import calibrate as C

    rig = load_rig("default")
    plan = calibration_session_plan(rig, quick=True)
    idx = [i for i, k in enumerate(plan.params["kinds"]) if k == "camera"][:12]
    plan = replace(plan, poses=plan.poses[idx], joints=plan.joints[idx], params={**plan.params, "kinds": ["highlight"] * 12})
    text, src = read_rig_text("default")
    code = C._new_session(_calibration_args(tmp_path), rig, text, src, plan)
    err = capsys.readouterr().err
    assert code == U.UNUSABLE_EXIT == 8
    assert ("calibration session unusable: stopped after 10 poses, 10 of them gave nothing usable (no highlight "
            "(too faint): 10)") in err
    assert "no calibrated rig file written" in err and not (tmp_path / "cal.toml").exists()


def test_a_run_of_fewer_poses_than_min_judged_is_not_judged():
    """A resume that measured one grazing pose (NO_BOARD) is not an unusable session; it warns."""
    u = U.Usability()
    for _ in range(U.MIN_JUDGED - 1):
        u.add("board not found")
    assert u.final_status() is None and u.warning().startswith(f"warning: {U.MIN_JUDGED - 1} of {U.MIN_JUDGED - 1}")
    u.add("board not found")
    assert u.final_status().startswith("unusable: 3 of 3 poses")
