"""A session's geometric-calibration error, per pose, for a fit's σ (:mod:`gonio.fit.geometry`).

The session's manifest holds the rig file it measured with — for a calibrated rig, its
``[calibration.covariance]`` ``Σ_g`` (:class:`gonio.rig.geocov.GeometryCovariance`) — and every pose's record
the joints it measured at. :func:`session_modes` turns them into :class:`gonio.fit.geometry.CalibrationModes`:
the light's position at each pose ``S_G`` (what the host computed the pose's samples with) and its offsets
``δS_kG = (∂S/∂g)(joints_G) · √λ_k v_k`` along the principal axes of ``Σ_g`` (first order, GUM JCGM 100:2008 §5.2;
principal perturbations, JCGM 102:2011 §6.2.1; ``∂S/∂g`` by central differences of the kinematic chain,
:func:`gonio.rig.geocov.light_jacobian`), and the turns of the sample frame the board defines, one
:data:`gonio.rig.geocal.BOARD_ROTATION_SIGMA_DEG` about each axis (shared by every pose; the calibration states
that uncertainty of the board's orientation against the sample surface).
"""

from __future__ import annotations

import numpy as np

__all__ = ["session_modes"]


def session_modes(manifest: dict, pose_meta: dict, where: str = "session"):
    """:class:`gonio.fit.geometry.CalibrationModes` of a session (module docstring), or ``None`` when its rig has
    no calibration covariance, its sample is not the flat patch (a tilted mount or a sphere: the samples' frame
    is not the plane the light's offsets are computed in) or no pose record has joints."""
    from gonio.errors import ConfigError, DataError
    from gonio.fit.geometry import CalibrationModes
    from gonio.pipeline.target import TargetLayout
    from gonio.rig.geocal import BOARD_ROTATION_SIGMA_DEG
    from gonio.rig.geocov import light_jacobian
    from gonio.rig.kinematics import load_rig

    rec = manifest.get("rig") if isinstance(manifest, dict) else None
    text = rec.get("toml") if isinstance(rec, dict) else None
    if not isinstance(text, str) or "[calibration.covariance]" not in text:
        return None
    try:
        rig = load_rig(text=text, source=f"{where} rig", strict=False)
        layout = TargetLayout.from_dict(manifest.get("target") or {}, source=f"{where} target")
    except (ConfigError, DataError):
        return None
    cov = getattr(rig, "geometry_covariance", None)
    if cov is None or layout.sphere is not None or not layout.mount.is_flat:
        return None
    poses, joints = [], []
    for pose, meta in sorted(pose_meta.items()):
        j = meta.get("joints_rad") if isinstance(meta, dict) else None
        try:
            a = rig.as_array(j)
        except (ConfigError, DataError, TypeError, ValueError, KeyError):
            continue
        if np.all(np.isfinite(a)):
            poses.append(int(pose))
            joints.append(a)
    if not poses:
        return None
    joints = np.array(joints)
    light = np.asarray(rig.light_position(joints), dtype=np.float64)
    J = light_jacobian(rig, joints)                      # (G, 3, P) per degree or millimetre
    L = cov.factor()                                     # (P, P): columns √λ v
    L = L[:, np.linalg.norm(L, axis=0) > 0]
    offsets = np.einsum("gip,pk->kgi", J, L)
    w = layout.white  # a session's values are relative to its white reference (gonio.pipeline.reflectance)
    white = np.array([(w.x0 + w.x1) / 2, (w.y0 + w.y1) / 2, 0.0])
    turns = np.radians(BOARD_ROTATION_SIGMA_DEG) * np.eye(3)  # the board's frame against the sample, per axis
    return CalibrationModes(np.array(poses), light, offsets, white, tuple(cov.names),
                            f"the calibration covariance of {len(cov.names)} chain parameters in the session's rig "
                            f"file, the board's orientation {BOARD_ROTATION_SIGMA_DEG:g}° per axis", frame_turns=turns)
