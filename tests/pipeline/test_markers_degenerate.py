"""ChArUco poses that the corners cannot determine give no pose (→ NO_BOARD samples), never NaN or a crash.

Regression: the isotropic 10°/30° plan of benchmarks/bench_tradeoffs.py (391 poses, 320×240 camera)
crashed with ``LinAlgError: SVD did not converge`` in ``detect_board_pose``. At pose 31
(θi 20°, φi 0°, θo 70°, φo 90°) the grazing view decoded 8 markers whose interpolated ChArUco
corners all lie on ONE board row (ids 2…7, y = 0.03 m). Collinear points leave the rotation about
their line free: IPPE returned NaN rvec/tvec, projectPoints a NaN Jacobian and ``pinv(JᵀJ)`` failed
(after a finiteness guard was added it no longer crashed, but the NaN pose made the pose a skipped
"outside the image" pose instead of a flagged sample). The frame is kept as a fixture
(data/grazing_one_row_320x240.png, the exact 8-bit detection image).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gonio import samples as S
from gonio.pipeline.markers import MAX_RMS_PX, board_pose_from_points, corner_spread, detect_board_pose
from gonio.pipeline.target import CameraCalibration, CameraPose, CharucoSpec

DATA = Path(__file__).parent / "data"
#: The simulated rig's camera at 320×240 (sim.rig.SimRigConfig, focal 380 px).
CALIB = CameraCalibration.pinhole(320, 240, 380.0)
SPEC = CharucoSpec()

#: The failing frame's corners: board points (m) and image points (px), as OpenCV matched them.
OBJ_ONE_ROW = np.array([[0.09, 0.03, 0], [0.12, 0.03, 0], [0.15, 0.03, 0], [0.18, 0.03, 0], [0.21, 0.03, 0],
                        [0.24, 0.03, 0]])
IMG_ONE_ROW = np.array([[211.47595, 149.22856], [176.83418, 149.19093], [142.29623, 149.23036],
                        [107.59964, 149.25893], [73.00345, 149.29434], [38.378746, 149.34192]])


def _frame():
    import cv2

    gray = cv2.imread(str(DATA / "grazing_one_row_320x240.png"), cv2.IMREAD_UNCHANGED)
    assert gray is not None and gray.shape == (240, 320)
    return gray


def test_the_failing_frame_has_only_collinear_corners_and_gives_no_pose():
    import cv2

    gray = _frame()
    board = SPEC.board()
    _, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    assert ids is not None and len(ids) >= 6  # enough corners to pass the count check ...
    obj, _ = board.matchImagePoints(*cv2.aruco.CharucoDetector(board).detectBoard(gray)[:2])
    assert corner_spread(obj) < 1e-6  # ... but all on one line
    assert detect_board_pose(gray, CALIB, SPEC, board) is None


def test_collinear_corner_set_gives_no_pose():
    assert corner_spread(OBJ_ONE_ROW) == pytest.approx(0.0, abs=1e-9)
    assert board_pose_from_points(OBJ_ONE_ROW, IMG_ONE_ROW, CALIB, SPEC) is None


def _synthetic_corners(pose: CameraPose, rows=(1, 2, 3), cols=range(2, 8)):
    """Board corners of the given rows/cols projected by a camera ``pose`` (sample frame)."""
    obj = np.array([[c * SPEC.square_length, r * SPEC.square_length, 0.0] for r in rows for c in cols])
    img = pose.project(SPEC.board_to_sample(obj), CALIB)
    return obj, img


def test_a_well_spread_corner_set_gives_the_true_pose_with_a_finite_covariance():
    truth = CameraPose.look_at([0.3, 0.1, 0.45])
    obj, img = _synthetic_corners(truth)
    bp = board_pose_from_points(obj, img, CALIB, SPEC)
    assert bp is not None
    assert np.allclose(bp.pose.centre, truth.centre, atol=1e-6)
    assert np.isfinite(bp.cov).all() and np.all(np.linalg.eigvalsh(bp.cov) > 0)
    # two rows are enough: not collinear
    obj2, img2 = _synthetic_corners(truth, rows=(1, 2))
    assert board_pose_from_points(obj2, img2, CALIB, SPEC) is not None
    # one row is not, whatever the view
    obj1, img1 = _synthetic_corners(truth, rows=(2,))
    assert board_pose_from_points(obj1, img1, CALIB, SPEC) is None


@pytest.mark.parametrize("how", ["nan", "inf", "outlier", "too_few", "mismatched"])
def test_bad_corner_input_gives_no_pose(how):
    obj, img = _synthetic_corners(CameraPose.look_at([0.3, 0.1, 0.45]))
    if how == "nan":
        img[3, 0] = np.nan
    elif how == "inf":
        obj[0, 1] = np.inf
    elif how == "outlier":  # a mismatched corner: the fit cannot explain it
        img[5] += 20 * MAX_RMS_PX
    elif how == "too_few":
        obj, img = obj[:5], img[:5]
    else:
        img = img[:-1]
    assert board_pose_from_points(obj, img, CALIB, SPEC) is None


def test_the_grazing_pose_through_the_runner_gives_flagged_samples_not_a_skip(tmp_path):
    """The failing pose's angles on the simulated rig (320×240, the bench's material): measured,
    flagged NO_BOARD (camera pose from the kinematics), with finite values — not skipped, no crash."""
    from gonio.plan.plan import CaptureSettings, Plan
    from gonio.session.runner import SessionRunner
    from gonio.session.store import SessionStore, load_session
    from sim.rig import SimRig, SimRigConfig

    plan = Plan(poses=np.radians([[20.0, 0.0, 70.0, 90.0]]), capture=CaptureSettings())
    with SimRig(config=SimRigConfig(width=320, height=240, focal_px=380.0)) as sim:
        devices = sim.open_devices()
        try:
            store = SessionStore.create(tmp_path / "s", {"plan": plan, "mode": "test"})
            result = SessionRunner(plan, store, devices, sim.calibration, sim.layout, before_pose=sim.begin_pose,
                                   stream=None).run()
        finally:
            devices.close()
    assert not result.skipped
    s = load_session(tmp_path / "s")[1]
    assert len(s) > 0 and np.all(s.flags & S.NO_BOARD)
    assert np.isfinite(s.wi).all() and np.isfinite(s.wo).all()
