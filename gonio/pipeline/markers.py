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


#: Floor (pixels) of the corner localisation noise used for the pose covariance: a sub-pixel corner
#: finder is not better than ~0.05 px on real or rendered images, even when the residuals of a
#: few corners happen to be smaller.
MIN_CORNER_SIGMA_PX = 0.05


@dataclass(frozen=True)
class BoardPose:
    """Camera pose in the sample frame, with the evidence it rests on.

    ``cov`` is the 6×6 covariance of the board pose parameters ``(rvec, tvec)`` (OpenCV's
    board → camera Rodrigues vector and translation) from the PnP fit; :meth:`perturbed` turns it
    into camera poses one standard deviation away along its principal axes.
    """

    pose: CameraPose
    n_corners: int
    rms_px: float
    rvec: np.ndarray | None = None
    tvec: np.ndarray | None = None
    cov: np.ndarray | None = None
    board_size: tuple[float, float] = (0.0, 0.0)

    def perturbed(self) -> list[CameraPose]:
        """Camera poses at ``θ + √λ_j e_j`` for the eigenpairs (λ_j, e_j) of :attr:`cov` (linear error
        propagation: Σ_j (g(θ + √λ_j e_j) − g(θ))² ≈ ∇gᵀ Σ ∇g for any smooth g; JCGM 101 / GUM §5.1.2)."""
        if self.cov is None:
            return []
        lam, vec = np.linalg.eigh(self.cov)
        out = []
        for k in range(6):
            if not lam[k] > 0:
                continue
            step = np.sqrt(lam[k]) * vec[:, k]
            out.append(_sample_frame_pose(self.rvec + step[:3], self.tvec + step[3:], self.board_size))
        return out


def _sample_frame_pose(rvec, tvec, board_size) -> CameraPose:
    """Camera pose in the sample frame from OpenCV's board pose (board = R_bs · sample + t_bs)."""
    import cv2

    R_cb, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))
    w, h = board_size
    t_bs = np.array([w / 2, h / 2, 0.0])
    return CameraPose(R_cb @ BOARD_TO_SAMPLE_R, R_cb @ t_bs + np.asarray(tvec, dtype=np.float64).reshape(3))


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
    proj, jac = cv2.projectPoints(obj, rvec, tvec, calib.K, calib.dist)
    res = proj.reshape(-1, 2) - img
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1))))
    # Pose covariance of a least-squares fit: s² (JᵀJ)⁻¹, s² = Σr² / (2N − 6) (Hartley & Zisserman,
    # "Multiple View Geometry", 2nd ed., §5.2.3), with s floored at MIN_CORNER_SIGMA_PX.
    J = jac[:, :6]
    s2 = max(float(np.sum(res**2)) / max(res.size - 6, 1), MIN_CORNER_SIGMA_PX**2)
    JtJ = J.T @ J
    cov = s2 * np.linalg.pinv(JtJ) if np.isfinite(JtJ).all() and np.isfinite(s2) else None
    # board = R_bs · sample + t_bs  (R_bs = BOARD_TO_SAMPLE_R is its own inverse)
    pose = _sample_frame_pose(rvec, tvec, spec.size)
    return BoardPose(pose, n_corners=len(obj), rms_px=rms, rvec=rvec.reshape(3).copy(), tvec=tvec.reshape(3).copy(),
                     cov=cov, board_size=spec.size)
