"""The board pose is found once per camera position: a pose whose camera has not moved since the last stored pose
(same goal, same encoder readings) reuses that pose's board pose instead of searching its metering frame; a
resumed run confirms the stored one against a fresh search first, and a pose that does not qualify searches.
A resumed session still gives the uninterrupted one's samples bit for bit."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from gonio.pipeline.markers import BoardPose, board_poses_agree
from gonio.plan.plan import CaptureSettings, Plan
from gonio.rig.kinematics import load_rig
from gonio.session.store import load_session, scan_samples
from tests.session.test_bit_identical_resume import assert_bit_identical, run_session

#: (θi, φi, θo, φo) degrees: the camera stays at θo 30° for poses 0-2 and at 40° for poses 3-4
POSES_DEG = [(30, 0, 30, 180), (45, 0, 30, 180), (20, 0, 30, 180), (60, 0, 40, 180), (10, 0, 40, 180)]


def plan() -> Plan:
    return Plan(poses=np.radians(np.asarray(POSES_DEG, dtype=float)), capture=CaptureSettings(), generator="custom")


def run(directory, *, stop_after=None, resume=False, edit_last_board=None, edit_last_meta=None, on_pose=None):
    """Run (or resume) the plan on a fresh simulated rig (the bit-identity tests' run_session);
    ``edit_last_board(board record)`` / ``edit_last_meta(meta)`` change the store's last record's board pose / meta
    as the resumed runner reads it."""
    def edit(store):
        store.last_meta = copy.deepcopy(store.last_meta)
        if edit_last_board is not None:
            edit_last_board(store.last_meta["board_pose"])
        if edit_last_meta is not None:
            edit_last_meta(store.last_meta)

    return run_session(directory, stop_after=stop_after, resume=resume, plan=plan(),
                       on_store=None if edit_last_board is edit_last_meta is None else edit, on_pose=on_pose)


class Bumped:
    """The simulator's geometry with the camera ``shift`` metres off in the sample frame and looking as before:
    to the camera, the board and sample holder were pushed by −``shift`` while the servos stood still."""

    def __init__(self, geometry, shift):
        self.geometry, self.shift = geometry, np.asarray(shift, dtype=np.float64)

    def camera_pose(self, joints):
        position, R = self.geometry.camera_pose(joints)
        return position + self.shift, R

    def __getattr__(self, name):
        return getattr(self.geometry, name)


def metas(directory) -> dict[int, dict]:
    return {k: m for k, (_s, m) in scan_samples(directory / "samples.jsonl").records.items()}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    d = tmp_path_factory.mktemp("reuse") / "ref"
    assert run(d).status == "completed"
    return d


def test_a_camera_that_has_not_moved_reuses_the_board_pose_of_the_pose_before(reference):
    m = metas(reference)
    assert [m[k]["board_source"] for k in range(5)] == ["detected", "reused", "reused", "detected", "reused"]
    assert m[1]["board_pose"] == m[0]["board_pose"] == m[2]["board_pose"]
    assert m[4]["board_pose"] == m[3]["board_pose"] != m[0]["board_pose"]
    # the pose whose frame each board pose came from: the samples of a group share that pose error
    assert [m[k]["board_from"] for k in range(5)] == [0, 0, 0, 3, 3]
    cam = [(m[k]["joints_rad"]["camera_az"], m[k]["joints_rad"]["camera_el"]) for k in range(5)]
    assert cam[0] == cam[1] == cam[2] != cam[3] == cam[4]  # the plan keeps the camera still within each group
    _, s = load_session(reference)
    assert not np.any(s.flags & 4)  # NO_BOARD: every pose has a board pose


def test_a_board_bumped_while_the_camera_stands_still_is_found_again(tmp_path, reference):
    def bump(sim, index):  # between poses 1 and 2: the camera's servos have not moved, the board has
        if index == 2:
            sim.geometry = Bumped(sim.geometry, [0.002, 0.0, 0.0])

    d = tmp_path / "s"
    assert run(d, on_pose=bump).status == "completed"
    m = metas(d)
    assert [m[k]["board_source"] for k in range(5)] == ["detected", "reused", "replaced", "detected", "reused"]
    assert [m[k]["board_from"] for k in range(5)] == [0, 0, 2, 3, 3]
    # pose 2's own board pose: it disagrees with pose 0's, and puts the camera where the bump did (within the
    # ~1.5 mm a board pose at 320×240 is good for: its rvec's σ ≈ 1.7 mrad at 0.6 m)
    before, after = (BoardPose.from_record(m[k]["board_pose"]) for k in (0, 2))
    assert not board_poses_agree(before, after)
    rig = load_rig()
    truth = rig.camera_pose(rig.as_array(m[2]["joints_rad"]))[0] + [0.002, 0.0, 0.0]
    assert np.linalg.norm(after.pose.centre - truth) < 2e-3
    assert_bit_identical(reference, d, poses=[0, 1])  # before the bump: the same bits


def test_a_resumed_run_confirms_the_stored_board_pose_and_measures_the_same_bits(tmp_path, reference):
    d = tmp_path / "s"
    assert run(d, stop_after=1).status == "interrupted"
    assert sorted(metas(d)) == [0, 1]
    assert run(d, resume=True).status == "completed"
    m = metas(d)
    assert m[2]["board_source"] == "confirmed"  # searched once, agreed with pose 1's: kept
    assert m[4]["board_source"] == "reused"
    assert m[2]["board_pose"] == m[1]["board_pose"]
    assert [m[k]["board_from"] for k in range(5)] == [0, 0, 0, 3, 3]  # across the two runs
    assert_bit_identical(reference, d)


def test_a_stored_board_pose_that_disagrees_with_the_frame_is_replaced(tmp_path, reference):
    d = tmp_path / "s"
    assert run(d, stop_after=1).status == "interrupted"

    def moved(board):  # as if the sample holder had been pushed 5 mm along the optical axis meanwhile
        board["tvec"][2] += 0.005

    assert run(d, resume=True, edit_last_board=moved).status == "completed"
    m, ref = metas(d), metas(reference)
    assert m[2]["board_source"] == "replaced"
    # this pose's own search: the same frame as the uninterrupted run's, searched where that run reused pose 0's
    assert m[2]["board_pose"] != ref[2]["board_pose"]
    assert np.allclose(m[2]["board_pose"]["tvec"], ref[2]["board_pose"]["tvec"], atol=2e-3)
    assert m[4]["board_source"] == "reused"
    assert [m[k]["board_from"] for k in range(5)] == [0, 0, 2, 3, 3]


def test_a_stored_board_record_that_is_not_one_is_ignored_and_the_board_searched(tmp_path, reference):
    d = tmp_path / "s"
    assert run(d, stop_after=1).status == "interrupted"
    assert run(d, resume=True, edit_last_board=lambda b: b.update(cov="not a matrix")).status == "completed"
    assert metas(d)[2]["board_source"] == "detected"
    assert metas(d)[2]["board_from"] == 2


def test_a_board_pose_reused_from_a_record_that_does_not_name_its_origin_says_so(tmp_path, reference):
    d = tmp_path / "s"  # a session written before board_from, or a value that is not a pose index
    assert run(d, stop_after=1).status == "interrupted"
    assert run(d, resume=True, edit_last_meta=lambda m: m.update(board_from="pose 0")).status == "completed"
    m = metas(d)
    assert m[2]["board_source"] == "confirmed" and m[2]["board_from"] is None  # unknown, not a guess
    assert [m[k]["board_from"] for k in (3, 4)] == [3, 3]


def _board() -> BoardPose:
    from gonio.pipeline.markers import _sample_frame_pose

    rvec, tvec = np.array([2.9, 0.05, -0.1]), np.array([-0.01, 0.02, 0.45])
    cov = np.diag([1e-6, 1e-6, 1e-6, 1e-8, 1e-8, 4e-8])
    cov[0, 1] = cov[1, 0] = 3e-7
    return BoardPose(_sample_frame_pose(rvec, tvec, (0.2, 0.15)), n_corners=24, rms_px=0.12, rvec=rvec, tvec=tvec,
                     cov=cov, board_size=(0.2, 0.15))


def test_a_board_record_reads_back_bit_for_bit_through_json():
    import json

    b = _board()
    back = BoardPose.from_record(json.loads(json.dumps(b.to_record())))
    assert back.pose.R.tobytes() == b.pose.R.tobytes() and back.pose.t.tobytes() == b.pose.t.tobytes()
    assert back.cov.tobytes() == b.cov.tobytes() and (back.n_corners, back.rms_px) == (24, 0.12)


@pytest.mark.parametrize("edit", [
    lambda r: r.pop("rvec"), lambda r: r.update(tvec=[0.0, 0.0]), lambda r: r.update(tvec=[0.0, float("nan"), 1.0]),
    lambda r: r.update(cov=[[1.0]]), lambda r: r["cov"][0].__setitem__(1, 1.0),  # not symmetric
    lambda r: r["cov"][0].__setitem__(0, -1.0),  # not positive semi-definite
    lambda r: r.update(n_corners=2), lambda r: r.update(rms_px=-1.0), lambda r: r.update(size_m=[0.2, 0.0]),
    lambda r: r.update(n_corners="many"),
])
def test_a_board_record_that_is_not_one_reads_as_none(edit):
    rec = _board().to_record()
    edit(rec)
    assert BoardPose.from_record(rec) is None
    assert BoardPose.from_record("board") is None and BoardPose.from_record(None) is None


def test_two_estimates_agree_within_their_noise_and_not_beyond():
    a = _board()
    sd = np.sqrt(np.diag(a.cov))
    near = BoardPose(a.pose, 24, 0.1, rvec=a.rvec + 1.0 * sd[:3] * [1, 0, 0], tvec=a.tvec, cov=a.cov,
                     board_size=a.board_size)
    far = BoardPose(a.pose, 24, 0.1, rvec=a.rvec, tvec=a.tvec + 10 * sd[3:] * [0, 0, 1], cov=a.cov,
                    board_size=a.board_size)
    assert board_poses_agree(a, near) and board_poses_agree(near, a)
    assert not board_poses_agree(a, far)
    assert not board_poses_agree(a, BoardPose(a.pose, 24, 0.1))  # nothing to compare with
