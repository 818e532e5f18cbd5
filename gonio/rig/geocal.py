"""Geometric calibration of a rig: its assembly errors (:class:`gonio.rig.chain.ChainErrors`) from what
the camera sees, by least squares over the whole kinematic chain.

Observations (one per pose of a calibration plan, :func:`calibration_plan`):

* :class:`CameraObservation` — the camera's pose in the sample frame from the ChArUco board
  (:mod:`gonio.pipeline.target`) at joints ``j``: position (m) and rotation (rows = camera axes);
* :class:`HighlightObservation` — with a flat mirror (or a glossy black tile) on the stage, the pixel
  direction (normalized image coordinates ``x/z, y/z``) in which the camera sees the light's specular
  reflection, together with the camera's ChArUco pose of the same frame. The mirror plane is the sample
  plane z = 0, so the camera sees the light's mirror image ``(x, y, −z)`` (law of reflection).

The unknowns are :class:`ChainErrors`'s fields (degrees, millimetres). The residuals are weighted by
their scatter, estimated from the data (two reweighting passes, one variance per observation kind),
and solved with :func:`scipy.optimize.least_squares`. The standard uncertainties are the square roots
of the diagonal of ``s² (JᵀJ)⁻¹`` at the solution (the Gauss–Newton covariance; Bates & Watts 1988,
*Nonlinear Regression Analysis*, §2.3.1; ``s²`` = weighted RSS / (m − n)). Parameters the poses
cannot determine — the columns of ``J`` in the null space of its SVD (relative singular value below
:data:`RANK_TOL`) or with an uncertainty above :data:`MAX_SIGMA` — are reported as *not identified*,
kept at their declared value (0), and the fit is repeated without them; they are never guessed.
A pose set that cannot determine the chain at all (too few poses, one azimuth, one elevation) is
refused before solving with a one-line :class:`DegeneratePoses`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from gonio.errors import ConfigError
from gonio.rig.chain import ARM_FIELDS, TURNTABLE_FIELDS, ChainErrors, chain_forward

__all__ = ["CameraObservation", "HighlightObservation", "GeoCalResult", "DegeneratePoses", "calibrate_geometry",
           "calibration_plan", "calibrated_rig_text", "plan_lab_time", "RANK_TOL", "MAX_SIGMA"]

#: Relative singular value below which a direction of parameter space is not determined by the data.
RANK_TOL = 1e-7
#: A parameter whose standard uncertainty exceeds this (deg or mm) is reported as not identified.
MAX_SIGMA = 5.0
#: Not identifiable from images of the sample plane: the sample height is the same as moving both arcs.
ALWAYS_FIXED = {"sample_height_mm": "same effect as both arcs' arc_z_mm (only arc_z − height is observable)"}


class DegeneratePoses(ConfigError):
    """The calibration poses cannot determine the rig's geometry (one line: why)."""


@dataclass(frozen=True)
class CameraObservation:
    joints: np.ndarray      # (4,) rad, the rig's joint order
    position: np.ndarray    # (3,) m, camera centre in the sample frame (ChArUco)
    R: np.ndarray           # (3, 3) rows = camera axes in sample coordinates (ChArUco)


@dataclass(frozen=True)
class HighlightObservation:
    joints: np.ndarray      # (4,) rad
    xy: np.ndarray          # (2,) normalized image coordinates of the light's reflection
    position: np.ndarray    # (3,) camera centre (ChArUco, same frame)
    R: np.ndarray           # (3, 3) camera rotation (ChArUco, same frame)


@dataclass
class GeoCalResult:
    """Estimated errors, their standard uncertainties (same units; NaN: not identified), residuals."""

    errors: ChainErrors
    sigma: dict[str, float]
    not_identified: dict[str, str]
    rms: dict[str, float] = field(default_factory=dict)   # per observation kind, in its unit
    n_observations: dict[str, int] = field(default_factory=dict)
    residuals: np.ndarray | None = None

    def table(self) -> list[tuple[str, float, float, str]]:
        """(name, value, standard uncertainty, unit or 'not identified: why') per parameter."""
        v = self.errors.vector()
        out = []
        for name, x in zip(self.errors.names(), v):
            unit = "deg" if name.endswith("_deg") else "mm"
            why = self.not_identified.get(name)
            out.append((name, float(x), self.sigma.get(name, math.nan), f"not identified: {why}" if why else unit))
        return out


def _rotvec(R):
    """Rotation vector (rad) of rotation matrices ``(..., 3, 3)`` near the identity (small angle:
    the antisymmetric part, exact to second order; Murray, Li & Sastry 1994, §2.2)."""
    return 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)


def _residual_blocks(rig, errors: ChainErrors, cams, highs):
    out = {}
    if cams:
        j = np.stack([c.joints for c in cams])
        _, pc, R = chain_forward(rig, errors, j)
        obs_p = np.stack([c.position for c in cams])
        obs_R = np.stack([c.R for c in cams])
        out["camera_mm"] = ((pc - obs_p) * 1e3).ravel()
        out["camera_deg"] = np.degrees(_rotvec(R @ np.swapaxes(obs_R, -1, -2))).ravel()
    if highs:
        j = np.stack([h.joints for h in highs])
        pl, _, _ = chain_forward(rig, errors, j)
        image = pl * np.array([1.0, 1.0, -1.0])  # mirror image in the sample plane z = 0
        c = np.stack([h.position for h in highs])
        R = np.stack([h.R for h in highs])
        v = (R @ (image - c)[..., None])[..., 0]
        xy = v[:, :2] / v[:, 2:3]
        out["highlight_mrad"] = ((xy - np.stack([h.xy for h in highs])) * 1e3).ravel()
    return out


def check_pose_set(rig, cams, highs) -> None:
    """Refuse, in one line, a pose set that cannot determine the chain (before any solving)."""
    names = list(rig.names)

    def spread(obs, joint):
        if joint not in names or not obs:
            return 0.0, 0
        a = np.degrees([o.joints[names.index(joint)] for o in obs])
        return float(np.ptp(a)), len(np.unique(np.round(a, 1)))

    if len(cams) < 8:
        raise DegeneratePoses(f"calibration poses: {len(cams)} camera poses; need at least 8 (the camera arm has "
                              f"{len(ARM_FIELDS)} unknowns)")
    if len(highs) < 8:
        raise DegeneratePoses(f"calibration poses: {len(highs)} views of the light's reflection; need at least 8 "
                              f"(the light arm has {len(ARM_FIELDS)} unknowns)")
    for arm, obs in (("camera", cams), ("light", highs)):
        az = f"{arm}_az" if f"{arm}_az" in names else "sample_az"
        span, n = spread(obs, az)
        if n < 3 or span < 60.0:
            raise DegeneratePoses(f"calibration poses: {arm} observations at {n} azimuth(s) spanning {span:.0f}° of "
                                  f"{az}; need >= 3 spanning >= 60° (axis tilt and offsets are otherwise not separable)")
        span, n = spread(obs, f"{arm}_el")
        if n < 3 or span < 40.0:
            raise DegeneratePoses(f"calibration poses: {arm} observations at {n} elevation(s) spanning {span:.0f}° of "
                                  f"{arm}_el; need >= 3 spanning >= 40° (zero offset and arc centre are otherwise "
                                  f"not separable)")


def calibrate_geometry(rig, cams, highs, *, check: bool = True) -> GeoCalResult:
    """Estimate the rig's :class:`ChainErrors` from camera and highlight observations (module docstring)."""
    cams, highs = list(cams), list(highs)
    if check:
        check_pose_set(rig, cams, highs)
    names = ChainErrors().names()
    free = [i for i, n in enumerate(names) if n not in ALWAYS_FIXED
            and not (rig.layout != "turntable" and n.startswith("turntable."))]
    not_identified = {n: why for n, why in ALWAYS_FIXED.items()}
    if rig.layout != "turntable":
        not_identified.update({f"turntable.{k}": "no turntable on this rig" for k in TURNTABLE_FIELDS})
    if rig.layout == "turntable":
        not_identified["light.d_az_deg"] = "same effect as the turntable's zero offset (the light arm has no azimuth joint)"
        free.remove(names.index("light.d_az_deg"))
    scale = {k: 1.0 for k in _residual_blocks(rig, ChainErrors(), cams, highs)}
    x = np.zeros(len(names))

    def fun(p, idx, scale):
        v = x.copy()
        v[idx] = p
        blocks = _residual_blocks(rig, ChainErrors.from_vector(v), cams, highs)
        return np.concatenate([blocks[k] / scale[k] for k in sorted(blocks)])

    idx = list(free)
    for _ in range(3):  # solve, drop what the data cannot determine, reweight by each kind's scatter
        sol = least_squares(fun, x[idx], args=(idx, scale), method="lm", x_scale=1.0)
        x[idx] = sol.x
        J = sol.jac
        col = np.linalg.norm(J, axis=0)
        col[col == 0] = 1.0
        _, s, vt = np.linalg.svd(J / col, full_matrices=False)
        null = vt[s < RANK_TOL * s[0]]
        bad = [idx[i] for i in range(len(idx)) if null.size and np.max(np.abs(null[:, i])) > 0.1]
        blocks = _residual_blocks(rig, ChainErrors.from_vector(x), cams, highs)
        scale = {k: max(float(np.sqrt(np.mean(r ** 2))), 1e-12) for k, r in blocks.items()}
        if bad:
            for i in bad:
                not_identified[names[i]] = "not determined by these poses (rank-deficient Jacobian)"
                x[i] = 0.0
            idx = [i for i in idx if i not in bad]
    sol = least_squares(fun, x[idx], args=(idx, scale), method="lm")
    x[idx] = sol.x
    r = sol.fun
    m, n = len(r), len(idx)
    s2 = float(r @ r) / max(m - n, 1)
    cov = s2 * np.linalg.pinv(sol.jac.T @ sol.jac)
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    sigma = {names[i]: math.nan for i in range(len(names))}
    for k, i in enumerate(idx):
        if sig[k] > MAX_SIGMA:
            not_identified[names[i]] = f"uncertainty {sig[k]:.3g} too large (poorly conditioned by these poses)"
            x[i] = 0.0
        else:
            sigma[names[i]] = float(sig[k])
    blocks = _residual_blocks(rig, ChainErrors.from_vector(x), cams, highs)
    return GeoCalResult(ChainErrors.from_vector(x), sigma, not_identified,
                        rms={k: float(np.sqrt(np.mean(v ** 2))) for k, v in blocks.items()},
                        n_observations={"camera": len(cams), "highlight": len(highs)}, residuals=r)


def calibration_plan(rig, *, quick: bool = False) -> dict[str, np.ndarray]:
    """Joint angles (rad) of a calibration session on ``rig``'s (arms) layout.

    ``camera``: the camera arm over 6 azimuths × 4 signed elevations (board in view), light parked out of
    the way; ``highlight``: the light arm over 8 azimuths × 5 elevations (10° to 78°), the camera at the light's mirror
    direction and 6° either side of it in elevation (parallax to triangulate the light's distance).
    Poses that are out of limits or in a collision zone are dropped (the same ``solve_many`` checks).
    """
    d = math.radians
    az = np.radians(np.arange(-150.0, 180.0, 60.0 if not quick else 90.0))
    laz = np.radians(np.arange(-157.5, 180.0, 45.0 if not quick else 90.0))
    cam = []
    for a in az:
        for e in (-55.0, -25.0, 25.0, 55.0):
            cam.append((0.0, d(70.0) if e < 0 else d(-70.0), a, d(e)))  # light far from the camera
    cam = np.array(cam)
    hi = []
    for a in laz:
        for e in (10.0, 30.0, 50.0, 65.0, 78.0):
            for de in (-6.0, 0.0, 6.0):
                hi.append((a, d(e), a, -d(e + de)))  # camera past the pole: the mirror direction, ± parallax
    hi = np.array(hi)

    def keep(j):
        wi, wo = rig.directions(j)
        code = rig.check_directions(wi, wo)
        ok = np.all((j >= rig.lower) & (j <= rig.upper), axis=-1) & (code == 0)
        return j[ok]

    return {"camera": keep(cam), "highlight": keep(hi)}


#: Seconds per calibration pose besides the move: settling and one exposure set (the runner's defaults).
POSE_OVERHEAD_S = 1.5


def plan_lab_time(rig, plan: dict, *, overhead_s: float = POSE_OVERHEAD_S) -> float:
    """Lab time (s) of :func:`calibration_plan`'s poses in order: the trapezoidal moves
    (:meth:`gonio.rig.kinematics.Rig.move_time`) plus ``overhead_s`` per pose."""
    j = np.concatenate([plan["camera"], plan["highlight"]])
    if len(j) == 0:
        return 0.0
    moves = rig.move_time(j[:-1], j[1:]) if len(j) > 1 else np.zeros(0)
    return float(np.sum(moves) + overhead_s * len(j))


def calibrated_rig_text(declared_text: str, result: GeoCalResult, *, note: str = "") -> str:
    """The declared rig file's text plus a ``[calibration]`` table of the estimated assembly errors (degrees,
    millimetres; what :func:`gonio.rig.kinematics.load_rig` reads into ``Rig.geometry_errors``), their
    standard uncertainties (``[calibration.uncertainty]``), the parameters not identified (kept at 0, with
    why) and the residuals' RMS. Refuses an already calibrated file (calibrate from the declared one)."""
    import tomllib

    if "calibration" in tomllib.loads(declared_text):
        raise ConfigError("rig file already has a [calibration] table: calibrate from the declared rig file")
    e = result.errors
    lines = ["", "# ---- geometric calibration (gonio calibrate rig) ----",
             "# Estimated assembly errors of this rig (gonio/rig/chain.py: angles in degrees, lengths in mm) and",
             "# their standard uncertainties (Gauss-Newton covariance). Parameters listed in not_identified were not",
             "# determined by the calibration poses and are kept at 0 (declared).",
             *(f"# {line}" for line in note.splitlines() if line),
             "[calibration]", f"sample_height_mm = {e.sample_height_mm:.6g}"]
    sig = result.sigma

    def table(prefix, fields, values):
        out = [f"[calibration.{prefix}]"]
        for k in fields:
            out.append(f"{k} = {values[k]:.6g}")
        return out

    def sigma_table(prefix, fields):
        out = [f"[calibration.uncertainty.{prefix}]"]
        for k in fields:
            s = sig.get(f"{prefix}.{k}", math.nan)
            if math.isfinite(s):
                out.append(f"{k} = {s:.3g}")
        return out

    lines += ["[calibration.rms]", *(f"{k} = {v:.4g}" for k, v in result.rms.items())]
    lines += ["[calibration.not_identified]", *(f'"{k}" = "{v}"' for k, v in result.not_identified.items())]
    for prefix, fields in (("light", ARM_FIELDS), ("camera", ARM_FIELDS), ("turntable", TURNTABLE_FIELDS)):
        lines += table(prefix, fields, getattr(e, prefix))
    for prefix, fields in (("light", ARM_FIELDS), ("camera", ARM_FIELDS), ("turntable", TURNTABLE_FIELDS)):
        lines += sigma_table(prefix, fields)
    return declared_text.rstrip("\n") + "\n" + "\n".join(lines) + "\n"
