"""Camera pose from the ChArUco board around the sample (OpenCV 5 API, FIELD-NOTES.md).

``cv2.aruco.CharucoDetector(board).detectBoard`` finds the interpolated chessboard corners;
``board.matchImagePoints`` pairs them with board coordinates; ``cv2.solvePnP`` with
``SOLVEPNP_IPPE`` (Collins & Bartoli, "Infinitesimal Plane-Based Pose Estimation", IJCV 2014 —
exact for planar targets) gives the board pose, refined by Levenberg–Marquardt
(``cv2.solvePnPRefineLM``). The pose is then expressed in the sample frame (gonio.pipeline.target).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.pipeline.target import BOARD_TO_SAMPLE_R, CameraCalibration, CameraPose, CharucoSpec

__all__ = ["BoardPose", "to_gray8", "detect_board_pose"]

#: Fewest ChArUco corners accepted for a pose.
MIN_CORNERS = 6


@dataclass(frozen=True)
class BoardPose:
    """Camera pose in the sample frame, with the evidence it rests on."""

    pose: CameraPose
    n_corners: int
    rms_px: float


def to_gray8(pixels: np.ndarray, bit_depth: int, black_level: float = 0.0) -> np.ndarray:
    """An 8-bit grey image for marker detection, stretched so the 99th percentile maps to 230.

    Works on (H, W) or (H, W, 3) integer frames of any bit depth.
    """
    img = np.asarray(pixels, dtype=np.float32)
    if img.ndim == 3:
        img = img.mean(axis=2)
    img = img - np.float32(black_level)
    hi = float(np.percentile(img[::4, ::4], 99.0))
    scale = 230.0 / hi if hi > 0 else 1.0
    return np.clip(img * np.float32(scale), 0, 255).astype(np.uint8)


def detect_board_pose(gray: np.ndarray, calib: CameraCalibration, spec: CharucoSpec, board=None) -> BoardPose | None:
    """Camera pose (sample frame) from the ChArUco board in ``gray``, or ``None`` if not found.

    ``None`` when fewer than :data:`MIN_CORNERS` corners are found or PnP fails.
    """
    import cv2

    board = spec.board() if board is None else board
    detector = cv2.aruco.CharucoDetector(board)
    ch_corners, ch_ids, _, _ = detector.detectBoard(gray)
    if ch_ids is None or len(ch_ids) < MIN_CORNERS:
        return None
    obj, img = board.matchImagePoints(ch_corners, ch_ids)
    if obj is None or len(obj) < MIN_CORNERS:
        return None
    obj = obj.reshape(-1, 3).astype(np.float64)
    img = img.reshape(-1, 2).astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(obj, img, calib.K, calib.dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return None
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, calib.K, calib.dist, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, calib.K, calib.dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    R_cb, _ = cv2.Rodrigues(rvec)
    # board = R_bs · sample + t_bs  (R_bs = BOARD_TO_SAMPLE_R is its own inverse)
    w, h = spec.size
    t_bs = np.array([w / 2, h / 2, 0.0])
    R = R_cb @ BOARD_TO_SAMPLE_R
    t = R_cb @ t_bs + tvec.reshape(3)
    return BoardPose(CameraPose(R, t), n_corners=len(obj), rms_px=rms)
