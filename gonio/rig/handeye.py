"""A closed-form start for the camera arm's geometry: robot-world / hand-eye calibration.

The camera arm is a two-joint "robot" whose "gripper" frame is the declared arm frame
``G = Rz(az)·Ry(el)`` at the sample centre, holding the camera; the ChArUco board is the "world".
Every board pose ``A_i`` (world → camera) and arm pose ``B_i = Gᵢᵀ`` (base → gripper) satisfy

    A_i · Y = Z · B_i,      Y = base → world (how the arm's base sits: azimuth zero, axis tilts and miss),
                            Z = gripper → camera (elevation zero, lateral offset, distance, mounting rotation)

(Zhuang, Roth & Sudhakar 1994, the "AX = ZB" robot-world/hand-eye problem). :func:`robot_world_hand_eye`
solves it in closed form by Shah's Kronecker-product method (Shah 2013, "Solving the robot-world/hand-eye
calibration problem using the Kronecker product", J. Mechanisms Robotics 5(3)): the rotations from the
null vector of ``[I ⊗ R_A, −R_Bᵀ ⊗ I]`` (stacked over the poses), each made orthonormal, then the
translations by linear least squares. OpenCV's ``cv2.calibrateRobotWorldHandEye`` (method
``CALIB_ROBOT_WORLD_HAND_EYE_SHAH``) is the same method and is used when the installed OpenCV exposes it
(OpenCV 5.0.0's Python package does not: opencv/opencv#29565, fixed in #29584).

:func:`camera_arm_start` turns ``Y`` and ``Z`` into :data:`gonio.rig.chain.CAMERA_FIELDS` values: the start of
the joint least squares (:func:`gonio.rig.geocal.calibrate_geometry`), which then also fits what a
two-frame model cannot hold (non-orthogonality, the arc centre's offset in the arm plane).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["robot_world_hand_eye", "camera_arm_start"]

_N = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # camera rows in the arm frame (declared)


def _orthonormal(M):
    """The rotation nearest to ``M`` (Frobenius norm; Horn, Hilden & Negahdaripour 1988): U Vᵀ with det +1."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _shah(RA, tA, RB, tB):
    n = len(RA)
    I3 = np.eye(3)
    K = np.concatenate([np.concatenate([np.kron(I3, RA[i]), -np.kron(RB[i].T, I3)], axis=1) for i in range(n)])
    v = np.linalg.svd(K, full_matrices=False)[2][-1]  # Vt alone: the thin SVD gives the same Vt, without U (9n × 9n)
    Y = v[:9].reshape(3, 3, order="F")  # vec() is column-major in the Kronecker identity
    Z = v[9:].reshape(3, 3, order="F")
    s = np.sign(np.linalg.det(Y)) * abs(np.linalg.det(Y)) ** (-1.0 / 3.0)
    RY, RZ = _orthonormal(s * Y), _orthonormal(s * Z)
    # R_A t_Y + t_A = R_Z t_B + t_Z  →  [R_A, −I] [t_Y; t_Z] = R_Z t_B − t_A
    M = np.concatenate([np.concatenate([RA[i], -I3], axis=1) for i in range(n)])
    b = np.concatenate([RZ @ tB[i] - tA[i] for i in range(n)])
    t = np.linalg.lstsq(M, b, rcond=None)[0]
    return RY, t[:3], RZ, t[3:]


def robot_world_hand_eye(RA, tA, RB, tB, *, use_opencv: bool = True):
    """``(R_Y, t_Y, R_Z, t_Z)`` with ``A_i Y = Z B_i`` (module docstring) from ``(n, 3, 3)`` rotations and
    ``(n, 3)`` translations. OpenCV's implementation when available (``use_opencv``), else Shah's in NumPy."""
    RA, tA, RB, tB = (np.asarray(a, dtype=np.float64) for a in (RA, tA, RB, tB))
    if use_opencv:
        import cv2

        fn = getattr(cv2, "calibrateRobotWorldHandEye", None)
        if fn is not None:
            # OpenCV: world2cam (A), base2gripper (B) → base2world (Y), gripper2cam (Z)
            RY, tY, RZ, tZ = fn(list(RA), list(tA.reshape(-1, 3, 1)), list(RB), list(tB.reshape(-1, 3, 1)),
                                method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH)
            return np.asarray(RY), np.asarray(tY).ravel(), np.asarray(RZ), np.asarray(tZ).ravel()
    return _shah(RA, tA, RB, tB)


def _xyz_angles(R):
    """Degrees (x, y, z) with ``R = Rx(x)·Ry(y)·Rz(z)`` (|y| < 90°)."""
    return (math.degrees(math.atan2(-R[1, 2], R[2, 2])), math.degrees(math.asin(float(np.clip(R[0, 2], -1, 1)))),
            math.degrees(math.atan2(-R[0, 1], R[0, 0])))


def camera_arm_start(rig, cams) -> dict:
    """Camera arm fields (:data:`gonio.rig.chain.CAMERA_FIELDS`, deg and mm) from the board poses ``cams``
    (:class:`gonio.rig.geocal.CameraObservation`) by :func:`robot_world_hand_eye` (module docstring);
    ``nonorth_deg`` and ``arc_x_mm`` are 0 (not in a two-frame model)."""
    from gonio.rig.chain import _ry, _rz

    j = np.stack([c.joints for c in cams])
    _, _, az, el = rig.arm_angles(j)
    G = _rz(az) @ _ry(el)                                  # arm frame in the base (declared), at the sample centre
    RA = np.stack([c.R for c in cams])                     # world → camera
    tA = -(RA @ np.stack([c.position for c in cams])[..., None])[..., 0]
    RB = np.swapaxes(G, -1, -2)                            # base → gripper
    tB = np.zeros((len(cams), 3))
    RY, tY, RZ, tZ = robot_world_hand_eye(RA, tA, RB, tB)
    tilt_x, tilt_y, d_az = _xyz_angles(RY)
    p = -RZ.T @ tZ                                         # camera centre in the arm frame: Ry(δel)·(0, lat, r + δr)
    d_el = math.atan2(p[0], p[2])
    M = RZ @ _ry(np.asarray(d_el)) @ _N                    # R_Z = M · N · Ry(δel)ᵀ
    mx, my, mz = _xyz_angles(M)
    return {"d_az_deg": d_az, "d_el_deg": math.degrees(d_el), "tilt_x_deg": tilt_x, "tilt_y_deg": tilt_y,
            "nonorth_deg": 0.0, "axis_x_mm": tY[0] * 1e3, "axis_y_mm": tY[1] * 1e3, "arc_x_mm": 0.0,
            "arc_z_mm": tY[2] * 1e3, "d_radius_mm": (math.hypot(p[0], p[2]) - rig.camera_radius) * 1e3,
            "lateral_mm": p[1] * 1e3, "mount_x_deg": mx, "mount_y_deg": my, "mount_z_deg": mz}
