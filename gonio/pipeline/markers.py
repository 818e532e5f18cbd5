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

__all__ = ["BoardPose", "to_gray8", "detect_board_pose", "refine_board_pose", "board_pose_from_points",
           "board_poses_agree", "corner_spread"]

#: Fewest ChArUco corners accepted for a pose.
MIN_CORNERS = 6


#: Floor (pixels) of the corner localisation noise used for the pose covariance: a sub-pixel corner
#: finder is not better than ~0.1 px on real or rendered images, even when the residuals of a few corners
#: happen to be smaller: part of its error (blur footprint, perspective of the squares) is shared by
#: neighbouring corners, which the pose absorbs and the residuals do not show. Measured on the simulated
#: in-plane session (20°/10°, 52 poses): the camera centre's error against the covariance at a 0.05 px
#: floor had a mean Mahalanobis² of 10.8 (3 expected; 4.0 on the default plan), and the samples' χ²_red
#: of the true material 1.19-1.36; at 0.1 px χ²_red 1.02-1.20 and p95 |z| 2.04-2.06 (1.96 Gaussian).
MIN_CORNER_SIGMA_PX = 0.1

#: Smallest RMS distance of the corners from their best-fit line, in squares, for a pose: corners on
#: one row (or diagonal) leave the rotation about that line free (see :func:`corner_spread`).
MIN_SPREAD_SQUARES = 0.2

#: Largest RMS reprojection residual (pixels) of an accepted pose: rendered or real corners fit to
#: ~0.1 px; more means a wrong corner match or a wrong solution.
MAX_RMS_PX = 2.0

#: Largest condition number of JᵀJ (pose parameters (rvec, tvec), pixels) for which the covariance is
#: trusted (simulated sessions: 7e2 … 1.5e4); beyond it the corners leave a pose direction undetermined.
MAX_JTJ_CONDITION = 1e10


@dataclass(frozen=True)
class BoardPose:
    """Camera pose in the sample frame, with the evidence it rests on.

    ``cov`` is the 6×6 covariance of the board pose parameters ``(rvec, tvec)`` (OpenCV's
    board → camera Rodrigues vector and translation) from the PnP fit; :meth:`perturbed` turns it
    into camera poses one standard deviation away along its principal axes. ``corner_ids``: the ChArUco
    corners (OpenCV's ids) the fit rests on, the ones :func:`refine_board_pose` looks for again.
    """

    pose: CameraPose
    n_corners: int
    rms_px: float
    rvec: np.ndarray | None = None
    tvec: np.ndarray | None = None
    cov: np.ndarray | None = None
    board_size: tuple[float, float] = (0.0, 0.0)
    corner_ids: np.ndarray | None = None

    def to_record(self) -> dict | None:
        """The pose as JSON-able lists (a pose record's ``board_pose``, docs/formats.md): OpenCV's ``rvec`` and
        ``tvec``, the 6×6 ``cov``, ``n_corners``, ``rms_px``, the board's ``size_m`` and the ``corner_ids`` (when
        known); None without a PnP
        solution (a pose given directly). :meth:`from_record` rebuilds it bit for bit (float64 ↔ JSON is exact:
        Python writes the shortest repr that reads back to the same double)."""
        if self.rvec is None or self.tvec is None:
            return None
        return {"rvec": [float(v) for v in self.rvec], "tvec": [float(v) for v in self.tvec],
                "cov": None if self.cov is None else np.asarray(self.cov, dtype=np.float64).tolist(),
                "n_corners": int(self.n_corners), "rms_px": float(self.rms_px),
                "size_m": [float(v) for v in self.board_size],
                **({} if self.corner_ids is None else {"corner_ids": [int(i) for i in self.corner_ids]})}

    @classmethod
    def from_record(cls, rec) -> "BoardPose | None":
        """The :class:`BoardPose` of a :meth:`to_record` dict, its camera pose recomputed from ``rvec`` and
        ``tvec``; None when ``rec`` is not such a record (wrong shapes, non-finite values, a covariance that is
        not symmetric positive semi-definite, ``corner_ids`` that are not ``n_corners`` distinct ids): a record
        read from a file is checked before it is used. Records without ``corner_ids`` (sessions written before
        it) give a pose without them."""
        try:
            rvec = np.asarray(rec["rvec"], dtype=np.float64).reshape(3)
            tvec = np.asarray(rec["tvec"], dtype=np.float64).reshape(3)
            size = tuple(float(v) for v in np.asarray(rec["size_m"], dtype=np.float64).reshape(2))
            cov = None if rec.get("cov") is None else np.asarray(rec["cov"], dtype=np.float64).reshape(6, 6)
            n, rms = int(rec["n_corners"]), float(rec["rms_px"])
            ids = rec.get("corner_ids")
            if ids is not None:
                if not (isinstance(ids, list) and all(isinstance(i, int) and not isinstance(i, bool) for i in ids)):
                    return None
                ids = np.asarray(ids, dtype=np.int64)
                if not (len(ids) == n and len(np.unique(ids)) == n and (ids >= 0).all() and (ids < 10**6).all()):
                    return None
        except (TypeError, ValueError, KeyError, AttributeError, OverflowError):
            return None
        values = np.concatenate([rvec, tvec, size, [rms]] + ([] if cov is None else [cov.ravel()]))
        if not (np.isfinite(values).all() and n >= MIN_CORNERS and 0.0 <= rms and min(size) > 0):
            return None
        if cov is not None:  # symmetric positive semi-definite, up to the rounding of (vec / λ) @ vecᵀ
            scale = float(np.abs(cov).max())
            if not (np.abs(cov - cov.T).max() <= 1e-9 * scale and np.linalg.eigvalsh(cov)[0] >= -1e-9 * scale):
                return None
        return cls(_sample_frame_pose(rvec, tvec, size), n_corners=n, rms_px=rms, rvec=rvec, tvec=tvec, cov=cov,
                   board_size=size, corner_ids=ids)

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


#: χ²₆ quantile 0.999 (scipy.stats.chi2.ppf(0.999, 6)): two estimates of one board pose whose difference lies
#: beyond it differ by more than their noise (probability 0.1 % for the same pose)
AGREE_CHI2_6 = 22.4577


def board_poses_agree(a: BoardPose, b: BoardPose, threshold: float = AGREE_CHI2_6) -> bool:
    """Two independent estimates of the same board pose: the Mahalanobis distance (Mahalanobis 1936) of their
    parameter difference ``Δ = (rvec, tvec)_a − (rvec, tvec)_b``, ``d² = Δᵀ (Σ_a + Σ_b)⁻¹ Δ``, is at most
    ``threshold`` (a χ² with 6 degrees of freedom when both are unbiased with covariances Σ_a, Σ_b).
    The Rodrigues vectors are subtracted directly: for rotations that differ by a small angle this is their
    difference to first order. False when either has no covariance (nothing to compare with)."""
    if a.cov is None or b.cov is None or a.rvec is None or b.rvec is None:
        return False
    d = np.concatenate([np.asarray(a.rvec) - np.asarray(b.rvec), np.asarray(a.tvec) - np.asarray(b.tvec)])
    try:
        d2 = float(d @ np.linalg.solve(np.asarray(a.cov) + np.asarray(b.cov), d))
    except np.linalg.LinAlgError:
        return False
    return bool(np.isfinite(d2) and d2 <= threshold)


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
        # the channels' mean as ``img.mean(axis=2)`` computes it (float32, summed in channel order, divided by
        # the count), bit for bit, in whole-plane operations: numpy's reduction over a short last axis is ~15×
        # slower on a frame
        acc = img[..., 0].copy()
        for k in range(1, img.shape[2]):
            acc += img[..., k]
        acc /= np.float32(img.shape[2])
        img = acc
    img = img - np.float32(black_level)
    hi = float(np.percentile(img[::4, ::4], 99.0))
    scale = 230.0 / hi if hi > 0 else 1.0
    return np.clip(img * np.float32(scale), 0, 255).astype(np.uint8)


def detect_board_pose(gray: np.ndarray, calib: CameraCalibration, spec: CharucoSpec, board=None, *,
                      covers=None, flat_field: bool = False) -> BoardPose | None:
    """Camera pose (sample frame) from the ChArUco board in ``gray``, or ``None`` if not found.

    ``covers``: what lies on the board (:func:`gonio.pipeline.covers.cover_points` of the target layout: the white
    patch, the sample or tile). The corners whose finder's window a cover reaches, seen with the pose from all the
    corners, are not the board's (:func:`gonio.pipeline.covers.covered_corners`): they are left out and the pose
    is fitted again from the others.

    ``flat_field``: the board is found again in the frame divided by its illumination
    (:func:`gonio.pipeline.shading.flat_fielded`, fitted with the first pose): a point light's shading moves the
    corners towards the light by ~0.01 px, the same way in every frame of a calibration plan (a bias of the
    calibration, not of one frame: 2·10⁻⁵ rad, nothing for a measurement's own pose). The first pose is kept when
    the illumination cannot be fitted or the board is not found again. Costs a second detection.

    ``None`` when fewer than :data:`MIN_CORNERS` corners are found (or left), or when they do not determine a
    pose (:func:`board_pose_from_points`): the caller then falls back on the kinematics and flags
    the samples ``NO_BOARD``.
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
    ids = np.asarray(ch_ids).reshape(-1)
    bp = board_pose_from_points(obj, img, calib, spec, ids=ids)
    if flat_field and bp is not None:
        from gonio.pipeline.covers import COVER_MARGIN_PX, cover_hulls, near_hulls, pose_projector
        from gonio.pipeline.shading import flat_fielded

        hulls = cover_hulls(pose_projector(bp.rvec, bp.tvec, calib), spec, covers)
        flat = flat_fielded(gray, bp.rvec, bp.tvec, calib, spec,
                            exclude=lambda xy: near_hulls(xy, hulls, COVER_MARGIN_PX + 1.0))
        again = None if flat is None else detect_board_pose(flat, calib, spec, board, covers=covers)
        if again is not None:
            return again
    if bp is None or not covers:
        return bp
    from gonio.pipeline.covers import covered_corners

    obj = np.asarray(obj, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(img, dtype=np.float64).reshape(-1, 2)
    keep = ~covered_corners(obj, bp.rvec, bp.tvec, calib, spec, covers, img=img)
    if keep.all():
        return bp
    return board_pose_from_points(obj[keep], img[keep], calib, spec, ids=ids[keep])


#: The corner refinement's window half-size in projected squares, and its bounds in pixels. Measured on 200
#: metering frames of the simulated dense plan (~22 px squares): half-sizes 2, 3, 4, 5 px gave a refit that
#: agrees with the detected pose in the same frame 200, 200, 199, 191 times, and one that disagrees once the
#: image is shifted by 1 px 200, 200, 198, 175 times (wider windows reach the markers' edges): 3 px, 1/7 square
REFINE_WINDOW_SQUARES = 1.0 / 7.0
REFINE_WINDOW_PX = (2, 10)


def refine_board_pose(gray: np.ndarray, prior: BoardPose, calib: CameraCalibration, spec: CharucoSpec,
                      board=None) -> BoardPose | None:
    """The board pose from ``prior``'s corners found again in ``gray`` where ``prior`` puts them: each of
    ``prior.corner_ids`` projected with ``prior``'s pose, refined by ``cv2.cornerSubPix`` (the point where the
    window's image gradients are orthogonal to the lines to it, in least squares: Förstner & Gülch, "A fast
    operator for detection and precise location of distinct points, corners and centres of circular
    features", ISPRS 1987) in a window of :data:`REFINE_WINDOW_SQUARES` of the projected square, then
    :func:`board_pose_from_points`. Its covariance is its own; :func:`board_poses_agree` with ``prior`` tells
    whether the board is still where ``prior`` says (a camera that has not moved sees the board's corners
    where it saw them, whatever the light does to their contrast).

    None when ``prior`` has no corner ids or pose parameters, an id is not a corner of ``spec``'s board, fewer
    than :data:`MIN_CORNERS` project inside the image, or :func:`board_pose_from_points` finds no pose."""
    import cv2

    if prior.corner_ids is None or prior.rvec is None or prior.tvec is None:
        return None
    board = spec.board() if board is None else board
    corners = np.asarray(board.getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
    ids = np.asarray(prior.corner_ids, dtype=np.int64)
    if len(ids) < MIN_CORNERS or ids.max() >= len(corners):
        return None
    obj = corners[ids]
    L = spec.square_length
    pts = np.concatenate([obj, obj + [L, 0.0, 0.0], obj + [0.0, L, 0.0]])
    try:
        proj, _ = cv2.projectPoints(pts, prior.rvec, prior.tvec, calib.K, calib.dist)
    except cv2.error:
        return None
    p = proj.reshape(3, -1, 2)
    if not np.isfinite(p).all():
        return None
    side = min(np.median(np.linalg.norm(p[1] - p[0], axis=1)), np.median(np.linalg.norm(p[2] - p[0], axis=1)))
    win = int(np.clip(round(side * REFINE_WINDOW_SQUARES), *REFINE_WINDOW_PX))
    h, w = gray.shape[:2]
    inside = ((p[0, :, 0] >= win + 1) & (p[0, :, 0] <= w - win - 2) & (p[0, :, 1] >= win + 1)
              & (p[0, :, 1] <= h - win - 2))
    if inside.sum() < MIN_CORNERS:
        return None
    img = np.ascontiguousarray(p[0, inside], dtype=np.float32).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    try:
        img = cv2.cornerSubPix(gray, img, (win, win), (-1, -1), criteria)
    except cv2.error:
        return None
    return board_pose_from_points(obj[inside], img.reshape(-1, 2), calib, spec, ids=ids[inside])


def corner_spread(obj: np.ndarray) -> float:
    """RMS distance (metres) of planar board points from their best-fit line.

    The smaller singular value of the centred (x, y) coordinates over √N (principal component
    analysis; Golub & Van Loan, *Matrix Computations*, §2.5.3). Zero for collinear points: a planar
    pose from collinear points is undetermined (free rotation about the line; the plane-to-image
    homography has rank 2, Hartley & Zisserman §4.1.3), and IPPE then returns NaN.
    """
    xy = np.asarray(obj, dtype=np.float64).reshape(-1, 3)[:, :2]
    if len(xy) < 3 or not np.isfinite(xy).all():
        return 0.0
    sv = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)
    return float(sv[-1] / np.sqrt(len(xy)))


def board_pose_from_points(obj, img, calib: CameraCalibration, spec: CharucoSpec, *, ids=None) -> BoardPose | None:
    """Camera pose (sample frame) from matched board points ``obj`` (N, 3) and image points ``img`` (N, 2)
    (``ids``: their ChArUco corner ids, kept as the pose's ``corner_ids``).

    IPPE (Collins & Bartoli 2014) then Levenberg–Marquardt refinement, and the pose covariance
    ``s² (JᵀJ)⁻¹``, ``s² = Σr² / (2N − 6)`` (Hartley & Zisserman, "Multiple View Geometry", 2nd ed.,
    §5.2.3), with ``s`` floored at :data:`MIN_CORNER_SIGMA_PX`.

    Returns ``None`` — never NaN, never a guess — when the points cannot determine a pose: fewer than
    :data:`MIN_CORNERS`, non-finite input, corners (nearly) collinear (:func:`corner_spread` below
    :data:`MIN_SPREAD_SQUARES` squares: e.g. a grazing view that decodes one row of markers), a
    solver result that is not finite or puts the board behind the camera, residuals above
    :data:`MAX_RMS_PX`, or a singular normal matrix ``JᵀJ`` (condition number above
    :data:`MAX_JTJ_CONDITION`).
    """
    import cv2

    obj = np.asarray(obj, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(img, dtype=np.float64).reshape(-1, 2)
    if len(obj) < MIN_CORNERS or len(obj) != len(img) or not (np.isfinite(obj).all() and np.isfinite(img).all()):
        return None
    if corner_spread(obj) < MIN_SPREAD_SQUARES * spec.square_length:
        return None
    try:
        ok, rvec, tvec = cv2.solvePnP(obj, img, calib.K, calib.dist, flags=cv2.SOLVEPNP_IPPE)
        if not ok or not (np.isfinite(rvec).all() and np.isfinite(tvec).all()):
            return None
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, calib.K, calib.dist, rvec, tvec)
        proj, jac = cv2.projectPoints(obj, rvec, tvec, calib.K, calib.dist)
    except cv2.error:
        return None
    if not (np.isfinite(rvec).all() and np.isfinite(tvec).all() and np.isfinite(proj).all() and np.isfinite(jac).all()):
        return None
    R_cb, _ = cv2.Rodrigues(rvec)
    if not np.all(obj @ R_cb.T[:, 2] + float(tvec.reshape(3)[2]) > 0):  # every corner in front of the camera
        return None
    res = proj.reshape(-1, 2) - img
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1))))
    if not rms <= MAX_RMS_PX:
        return None
    J = jac[:, :6]
    s2 = max(float(np.sum(res**2)) / max(res.size - 6, 1), MIN_CORNER_SIGMA_PX**2)
    JtJ = J.T @ J
    # the covariance is (JᵀJ)⁻¹ with JᵀJ symmetric positive semi-definite: an eigen-decomposition, not
    # pinv's SVD; a singular JᵀJ means some pose direction is not constrained by the corners
    lam, vec = np.linalg.eigh(JtJ)
    if not (lam[0] > 0 and lam[-1] / lam[0] < MAX_JTJ_CONDITION):
        return None
    cov = s2 * (vec / lam) @ vec.T
    # board = R_bs · sample + t_bs  (R_bs = BOARD_TO_SAMPLE_R is its own inverse)
    pose = _sample_frame_pose(rvec, tvec, spec.size)
    return BoardPose(pose, n_corners=len(obj), rms_px=rms, rvec=rvec.reshape(3).copy(), tvec=tvec.reshape(3).copy(),
                     cov=cov, board_size=spec.size,
                     corner_ids=None if ids is None else np.asarray(ids, dtype=np.int64).reshape(-1).copy())
