"""Geometric calibration of a rig: its assembly errors (:class:`gonio.rig.chain.ChainErrors`) from what
the camera sees, by least squares over the whole kinematic chain.

Observations (one per pose of a calibration plan, :func:`calibration_plan`):

* :class:`CameraObservation` — the camera's pose in the sample frame from the ChArUco board
  (:mod:`gonio.pipeline.target`) at joints ``j``: position (m) and rotation (rows = camera axes);
* :class:`HighlightObservation` — with a flat mirror (or a glossy black tile) on the stage, the pixel
  direction (normalized image coordinates ``x/z, y/z``) in which the camera sees the light's specular
  reflection (:mod:`gonio.pipeline.highlight`). The mirror plane is the sample plane z = 0, so the camera
  sees the light's mirror image ``(x, y, −z)`` (law of reflection). It is projected with the camera pose
  of the chain being estimated (the board poses of the same frames are camera observations too), not
  with each frame's own board pose, whose rotation error (~0.05° at 320 px) would enter the light's
  triangulation one frame at a time.

The unknowns are :class:`ChainErrors`'s fields (degrees, millimetres). When every observation has a
covariance (the board pose's PnP covariance, the highlight centroid's: what a session records), each
frame's residuals are whitened together by the frame's covariance — the detectors' own plus the joints'
scatter propagated through the chain, which couples a frame's board pose and highlight — whose sizes are
variance components estimated from the residuals (:mod:`gonio.rig.geocal_noise`; re-estimated at each of
three passes). Without covariances each kind is whitened by its own covariance where it has one and
rescaled by its scatter. The problem is solved with :func:`scipy.optimize.least_squares`, its forward-difference
Jacobian taken with all columns in one batched evaluation (:mod:`gonio.rig.geocal_residuals`: scipy's own steps). The standard
uncertainty of a parameter is the larger of the Gauss–Newton one, ``s² (JᵀJ)⁻¹`` (Bates & Watts 1988,
*Nonlinear Regression Analysis*, §2.3.1), and the cluster-robust sandwich one (one cluster per frame;
White 1980, Liang & Zeger 1986), plus the effect of errors common to every observation that no scatter
shows — the board's printed scale, the board frame's origin and orientation as the detector sees them
against the tile's surface, the principal point (:data:`BOARD_SCALE_SIGMA`, :data:`BOARD_ORIGIN_SIGMA_MM`,
:data:`BOARD_ROTATION_SIGMA_DEG`, :data:`PRINCIPAL_POINT_SIGMA`). Parameters the poses cannot determine — the columns of ``J`` in the null
space of its SVD (relative singular value below :data:`RANK_TOL`) or with an uncertainty above
:data:`MAX_SIGMA` — are reported as *not identified*, kept at their declared value (0), and the fit is
repeated without them; they are never guessed.
A frame whose whitened residuals are improbable under its covariance (χ² probability below :data:`OUTLIER_P`: a
misdetected board pose or highlight) is left out and the estimate repeated, at most twice (robust to outlier
frames; Förstner's data snooping, Baarda 1968); the frames left out are listed (:attr:`GeoCalResult.rejected`).
A pose set that cannot determine the chain at all (too few poses, one azimuth, one elevation) is
refused before solving with a one-line :class:`DegeneratePoses`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from gonio.errors import ConfigError
from gonio.rig.chain import ARM_FIELDS, CAMERA_FIELDS, TURNTABLE_FIELDS, ChainErrors
from gonio.rig.geocal_noise import FrameNoise, cholesky
from gonio.rig.geocal_residuals import Observed, errors_at, forward_jacobian, residual_blocks
from gonio.rig.geocal_residuals import extended_source_shift, rotvec  # noqa: F401  (their home before; re-exported)

__all__ = ["CameraObservation", "HighlightObservation", "extended_source_shift", "GeoCalResult", "DegeneratePoses", "calibrate_geometry",
           "calibration_plan", "calibrated_rig_text", "RANK_TOL", "MAX_SIGMA"]

#: Relative singular value below which a direction of parameter space is not determined by the data.
RANK_TOL = 1e-7
#: A parameter whose standard uncertainty exceeds this (deg or mm) is reported as not identified.
MAX_SIGMA = 5.0
#: A frame whose whitened residual χ² is this improbable under its covariance is an outlier (a misdetection):
#: left out and the estimate repeated. 1e-4 over ~200 frames drops a good frame once in ~50 calibrations.
OUTLIER_P = 1e-4
#: Relative standard uncertainty of the ChArUco board's scale (a laser print's square length, measured with
#: calipers over the whole board: ~0.05 %): a systematic error of every camera position.
BOARD_SCALE_SIGMA = 5e-4
#: Standard uncertainty of the camera's principal point in normalized image units (0.1 px at a 400 px focal
#: length: what a careful OpenCV intrinsic calibration states): a systematic turn of every board pose.
PRINCIPAL_POINT_SIGMA = 2.5e-4
#: Standard uncertainty (mm) of the board's origin as the corner detector sees it, per sample axis: a sub-pixel
#: corner finder's bias common to all corners (~0.02 px at 0.4 m and a 400 px focal length) in x and y; in z
#: the height of the board's printed surface against the tile's (the mirror plane, the sample surface that
#: wi and wo refer to), a step measured with calipers to ~0.02 mm.
BOARD_ORIGIN_SIGMA_MM = 0.02
#: Standard uncertainty (degrees, about each sample axis) of the board's orientation as the detector sees it,
#: against the sample surface: the corner finder's bias varying across the board (the origin's 0.02 mm over
#: the board's half width, 135 mm: 0.0085°) and the board's mounting against the tile's plane (0.05 mm over
#: 270 mm: 0.01°). A systematic turn of every board pose about the sample centre.
BOARD_ROTATION_SIGMA_DEG = 0.01
#: Not identifiable from images of the sample plane: the sample height is the same as moving both arcs.
ALWAYS_FIXED = {"sample_height_mm": "same effect as both arcs' arc_z_mm (only arc_z − height is observable)"}


class DegeneratePoses(ConfigError):
    """The calibration poses cannot determine the rig's geometry (one line: why)."""


@dataclass(frozen=True)
class CameraObservation:
    joints: np.ndarray      # (4,) rad, the rig's joint order
    position: np.ndarray    # (3,) m, camera centre in the sample frame (ChArUco)
    R: np.ndarray           # (3, 3) rows = camera axes in sample coordinates (ChArUco)
    #: (6, 6) covariance of (centre in mm, rotation vector of R_true R_obsᵀ in degrees), or None (unknown)
    cov: np.ndarray | None = None


@dataclass(frozen=True)
class HighlightObservation:
    joints: np.ndarray      # (4,) rad
    xy: np.ndarray          # (2,) normalized image coordinates of the light's reflection
    position: np.ndarray    # (3,) camera centre (ChArUco, same frame)
    R: np.ndarray           # (3, 3) camera rotation (ChArUco, same frame)
    #: (2, 2) covariance of ``xy`` (normalized image units), or None (unknown)
    cov: np.ndarray | None = None
    #: the reflector's reflectance at normal incidence (Schlick's f0; 1: a reflectance that does not vary) and
    #: the radius (m) of the light's emitting disc: together they shift the highlight's centroid off the
    #: mirror image of the light's centre (:func:`extended_source_shift`); 0: a point source
    f0: float = 1.0
    source_radius_m: float = 0.0


@dataclass
class GeoCalResult:
    """Estimated errors, their standard uncertainties (same units; NaN: not identified), residuals."""

    errors: ChainErrors
    sigma: dict[str, float]
    not_identified: dict[str, str]
    rms: dict[str, float] = field(default_factory=dict)   # per observation kind, in its unit
    n_observations: dict[str, int] = field(default_factory=dict)
    residuals: np.ndarray | None = None
    #: where the least squares started: "hand-eye" (:mod:`gonio.rig.handeye`) or "declared" (and why)
    start: str = "declared"
    #: residual evaluations the least squares needed (all passes)
    nfev: int = 0
    #: the observations' noise (:mod:`gonio.rig.geocal_noise`), when every observation has a covariance:
    #: ``scale_*`` the factor on each group's stated standard deviations, ``joint_sigma_deg`` the joints'
    #: scatter, ``chi2_*`` the mean whitened residual² of each group at the estimate (≈ 1)
    noise: dict = field(default_factory=dict)
    #: covariance of the identified parameters (deg², mm², deg·mm; order :attr:`cov_names`): the standard
    #: uncertainties' squares on its diagonal, the Gauss–Newton correlations, the systematic errors' outer products
    cov: np.ndarray | None = None
    cov_names: tuple = ()
    #: frames left out as outliers (:data:`OUTLIER_P`), one description each
    rejected: list = field(default_factory=list)

    def table(self) -> list[tuple[str, float, float, str]]:
        """(name, value, standard uncertainty, unit or 'not identified: why') per parameter."""
        v = self.errors.vector()
        out = []
        for name, x in zip(self.errors.names(), v):
            unit = "deg" if name.endswith("_deg") else "mm"
            why = self.not_identified.get(name)
            out.append((name, float(x), self.sigma.get(name, math.nan), f"not identified: {why}" if why else unit))
        return out


def _whiteners(obs, unit: float):
    """(N, n, n) matrices W with Wᵀ W = cov⁻¹ (so W r has unit covariance), or None if any observation has
    no covariance (then the block is weighted by its scatter alone). ``unit`` scales cov to the residual's unit."""
    if not obs or any(o.cov is None for o in obs):
        return None
    covs = np.stack([np.asarray(o.cov, dtype=np.float64) * unit ** 2 for o in obs])
    return np.linalg.inv(cholesky(covs))


def _clusters(keys, n_cam: int, n_high: int) -> np.ndarray:
    """Observation index of every residual row, in :func:`gonio.rig.geocal_residuals.residual_blocks`'s sorted block order."""
    per = {"camera_w": 6, "camera_mm": 3, "camera_deg": 3, "highlight_w": 2, "highlight_mrad": 2}
    out = []
    for k in keys:
        base, count = (0, n_cam) if k.startswith("camera") else (n_cam, n_high)
        out.append(base + np.repeat(np.arange(count), per[k]))
    return np.concatenate(out)


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
                              f"{len(CAMERA_FIELDS)} unknowns)")
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


def calibrate_geometry(rig, cams, highs, *, check: bool = True, highlight_camera: str = "chain",
                       weighted: bool = True, start: str = "hand-eye", board_scale_sigma: float = BOARD_SCALE_SIGMA,
                       principal_point_sigma: float = PRINCIPAL_POINT_SIGMA,
                       board_origin_sigma_mm: float = BOARD_ORIGIN_SIGMA_MM,
                       board_rotation_sigma_deg: float = BOARD_ROTATION_SIGMA_DEG,
                       reject_outliers: int = 2, jacobian: str = "batched") -> GeoCalResult:
    """Estimate the rig's :class:`ChainErrors` from camera and highlight observations (module docstring).

    ``weighted``: residuals whitened by each frame's covariance (detectors + joints, sized by variance
    components: :mod:`gonio.rig.geocal_noise`) when every observation has one and ``highlight_camera`` is
    ``"chain"``; else by each observation's own covariance where every observation of a kind has one (then
    rescaled by the kind's scatter); ``highlight_camera``: see :func:`gonio.rig.geocal_residuals.residual_blocks`.
    ``reject_outliers``: rounds of outlier rejection (per-frame covariances only): frames whose whitened χ² has
    a probability below :data:`OUTLIER_P` are dropped and the estimate repeated (:attr:`GeoCalResult.rejected`).
    ``start``: ``"hand-eye"`` starts the camera arm from the closed-form robot-world/hand-eye solution of the
    board poses (:func:`gonio.rig.handeye.camera_arm_start`; arms layout), ``"declared"`` from the declared
    geometry (all errors 0). ``jacobian``: ``"batched"`` takes the least squares' forward differences with all
    columns in one evaluation (:func:`gonio.rig.geocal_residuals.forward_jacobian`), ``"2-point"`` lets scipy take
    them one column at a time: the same Jacobian, the same result bit for bit, slower (the reference
    ``benchmarks calibration_solver`` and tests/rig/test_geocal_batch.py compare with)."""
    if jacobian not in ("batched", "2-point"):
        raise ConfigError(f"jacobian = {jacobian!r}: expected 'batched' or '2-point'")
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
    x = np.zeros(len(names))
    started = "declared"
    if start == "hand-eye" and rig.layout == "arms" and cams:
        started = _hand_eye_start(rig, cams, x, names)
    nfev = 0
    has_cov = all(o.cov is not None for o in cams + highs)
    observed = Observed.of(cams, highs)
    noise = FrameNoise(rig, cams, highs) if weighted and has_cov and highlight_camera == "chain" else None
    # fun(p, idx): the residual vector at x with x[idx] = p (n,), or one row per row of p (K, n) (a batch:
    # forward_jacobian's columns); ``obs``: perturbed observations (the systematic errors' propagation below)
    if noise is not None:
        # per-frame covariances: the detectors' own plus the joints' scatter, sized by variance components
        # (gonio.rig.geocal_noise); refreshed at every pass
        state = {"W": noise.whiteners(ChainErrors.from_vector(x))}

        def fun(p, idx, obs=None):
            return noise.whitened(errors_at(x, idx, p), state["W"], obs)

        def refresh():
            e = ChainErrors.from_vector(x)
            noise.estimate_components(e)
            state["W"] = noise.whiteners(e)

        cid = noise.clusters()
    else:
        # each observation whitened by its own covariance (if every one of its kind has one), each kind then
        # rescaled by its scatter
        white = {"camera": _whiteners(cams, 1.0), "highlight": _whiteners(highs, 1e3)} if weighted else {}
        kw = {"highlight_camera": highlight_camera, "white": white}
        state = {"scale": {k: 1.0 for k in residual_blocks(rig, ChainErrors(), observed, **kw)}}

        def fun(p, idx, obs=None):
            blocks = residual_blocks(rig, errors_at(x, idx, p), observed if obs is None else obs, **kw)
            return np.concatenate([blocks[k] / state["scale"][k] for k in sorted(blocks)], axis=-1)

        def refresh():
            blocks = residual_blocks(rig, ChainErrors.from_vector(x), observed, **kw)
            state["scale"] = {k: max(float(np.sqrt(np.mean(r ** 2))), 1e-12) for k, r in blocks.items()}

        cid = _clusters(sorted(residual_blocks(rig, ChainErrors(), observed, **kw)), len(cams), len(highs))

    def batched(p, idx):  # scipy's own '2-point' Jacobian, all columns in one batch (gonio.rig.geocal_residuals)
        return forward_jacobian(fun, p, idx)

    jac = batched if jacobian == "batched" else "2-point"

    idx = list(free)
    for _ in range(3):  # solve, drop what the data cannot determine, re-estimate the observations' noise
        sol = least_squares(fun, x[idx], jac=jac, args=(idx,), method="lm", x_scale=1.0)
        x[idx] = sol.x
        nfev += sol.nfev
        J = sol.jac
        col = np.linalg.norm(J, axis=0)
        col[col == 0] = 1.0
        _, s, vt = np.linalg.svd(J / col, full_matrices=False)
        null = vt[s < RANK_TOL * s[0]]
        bad = [idx[i] for i in range(len(idx)) if null.size and np.max(np.abs(null[:, i])) > 0.1]
        if bad:
            for i in bad:
                not_identified[names[i]] = "not determined by these poses (rank-deficient Jacobian)"
                x[i] = 0.0
            idx = [i for i in idx if i not in bad]
        refresh()
    sol = least_squares(fun, x[idx], jac=jac, args=(idx,), method="lm")
    x[idx] = sol.x
    nfev += sol.nfev
    r = sol.fun
    m, n = len(r), len(idx)
    s2 = float(r @ r) / max(m - n, 1)
    A = np.linalg.pinv(sol.jac.T @ sol.jac)
    cov = s2 * A
    # cluster-robust ("sandwich") covariance, one cluster per frame (one per observation without the noise
    # model): honest when the observations' covariances (the weights) are wrong in shape or size
    # (White 1980, Econometrica 48(4); Liang & Zeger 1986, Biometrika 73(1)); the larger of the two variances
    # is reported
    g = np.zeros((int(cid.max()) + 1 if len(cid) else 0, n))
    np.add.at(g, cid, sol.jac * r[:, None])
    cov_s = A @ (g.T @ g) @ A * m / max(m - n, 1)
    var = np.maximum(np.diag(cov), np.diag(cov_s))
    # the full covariance: the Gauss–Newton correlations with the larger of the two variances, plus the systematic
    # errors' outer products below (what gonio.rig.geocov propagates into wi, wo and every sample's σ)
    sd = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    full = cov / np.outer(sd, sd) * np.sqrt(np.outer(var, var))
    from dataclasses import replace as _replace

    def rotated(obs, axis, eps):  # the camera frame turned by eps (rad) about its own axis (0: x, 1: y)
        from gonio.rig.chain import _rx, _ry

        D = (_rx if axis == 0 else _ry)(np.asarray(eps))
        return _replace(obs, R=D @ obs.R)

    def shifted(obs, axis, eps):  # a principal-point error seen as a shift of the normalized coordinates
        xy = np.array(obs.xy, dtype=np.float64)
        xy[1 - axis] += eps if axis == 0 else -eps
        return _replace(rotated(obs, axis, eps), xy=xy)

    # Systematic errors common to all observations, which no scatter shows, propagated by their effect on
    # the solution, dx/dε = −A Jᵀ ∂r/∂ε (implicit function theorem at the least-squares optimum), adding
    # (dx/dε · σ_ε)² to the variances (GUM, JCGM 100 §5.2, fully correlated inputs):
    # the board's printed scale (every ChArUco position scales with it), the corner detector's common bias
    # (the board's origin as the detector sees it, x, y and its height against the tile: z), the board frame's
    # orientation (every board pose turned about the sample's x, y, z axes) and the principal point (x and y:
    # every board pose turns about the camera's y / x axis, every highlight shifts the same way).
    systematics = []
    if board_scale_sigma > 0 and cams:
        systematics.append(([_replace(c, position=c.position * (1.0 + 1e-4)) for c in cams], highs, 1e-4,
                            board_scale_sigma))
    if board_origin_sigma_mm > 0 and cams:
        for axis in (0, 1, 2):
            e = np.eye(3)[axis] * 1e-6
            systematics.append(([_replace(c, position=c.position + e) for c in cams], highs, 1e-3, board_origin_sigma_mm))
    if board_rotation_sigma_deg > 0 and cams:
        from gonio.rig.chain import _rx, _ry, _rz

        for turn in (_rx, _ry, _rz):
            e = 1e-5
            D = turn(np.asarray(math.radians(e)))
            systematics.append(([_replace(c, position=D @ c.position, R=c.R @ D.T) for c in cams], highs, e,
                                board_rotation_sigma_deg))
    if principal_point_sigma > 0:
        for axis in (0, 1):
            e = 1e-5
            systematics.append(([rotated(c, axis, e) for c in cams], [shifted(h, axis, e) for h in highs], e,
                                principal_point_sigma))
    for cams_e, highs_e, h, sigma_e in systematics:
        dr = (fun(sol.x, idx, Observed.of(cams_e, highs_e)) - r) / h
        dx = -A @ (sol.jac.T @ dr)
        var = var + (dx * sigma_e) ** 2
        full = full + np.outer(dx * sigma_e, dx * sigma_e)
    sig = np.sqrt(np.clip(var, 0, None))
    sigma = {names[i]: math.nan for i in range(len(names))}
    kept = []
    for k, i in enumerate(idx):
        if sig[k] > MAX_SIGMA:
            not_identified[names[i]] = f"uncertainty {sig[k]:.3g} too large (poorly conditioned by these poses)"
            x[i] = 0.0
        else:
            sigma[names[i]] = float(sig[k])
            kept.append(k)
    blocks = residual_blocks(rig, ChainErrors.from_vector(x), observed, highlight_camera=highlight_camera)
    info = {}
    if noise is not None:
        c = noise.components
        info = {"scale_board_frontal": math.sqrt(c[0]), "scale_board_oblique": math.sqrt(c[1]),
                "scale_highlight": math.sqrt(c[2]), "joint_sigma_deg": math.sqrt(c[3])}
        info.update({f"chi2_{k}": v for k, (v, _) in noise.chi2_by_group(ChainErrors.from_vector(x), state["W"]).items()})
    if noise is not None and reject_outliers > 0:
        bad = noise.outlier_frames(r, OUTLIER_P)
        if bad and noise.n_frames - len(bad) >= 16:
            cams2, highs2, what = noise.without(bad)
            res = calibrate_geometry(rig, cams2, highs2, check=False, highlight_camera=highlight_camera,
                                     weighted=weighted, start=start, board_scale_sigma=board_scale_sigma,
                                     principal_point_sigma=principal_point_sigma,
                                     board_origin_sigma_mm=board_origin_sigma_mm,
                                     board_rotation_sigma_deg=board_rotation_sigma_deg,
                                     reject_outliers=reject_outliers - 1, jacobian=jacobian)
            res.rejected = what + res.rejected
            res.nfev += nfev
            return res
    return GeoCalResult(ChainErrors.from_vector(x), sigma, not_identified,
                        rms={k: float(np.sqrt(np.mean(v ** 2))) for k, v in blocks.items()},
                        n_observations={"camera": len(cams), "highlight": len(highs)}, residuals=r,
                        start=started, nfev=nfev, noise=info, cov=full[np.ix_(kept, kept)],
                        cov_names=tuple(names[idx[k]] for k in kept))


def _hand_eye_start(rig, cams, x, names) -> str:
    """Put the hand-eye solution's camera arm fields into ``x`` (in place) if it is finite and within
    :class:`ChainErrors`'s bounds; returns the start's name (or why it was not used)."""
    from gonio.rig.handeye import camera_arm_start

    try:
        start = camera_arm_start(rig, cams)
    except (np.linalg.LinAlgError, ValueError) as exc:
        return f"declared (hand-eye failed: {exc})"
    for k, v in start.items():
        if not (math.isfinite(v) and abs(v) <= (180.0 if k.endswith("_deg") else 100.0)):
            return f"declared (hand-eye gave camera.{k} = {v:.3g})"
    for k, v in start.items():
        x[names.index(f"camera.{k}")] = v
    return "hand-eye"


def calibration_plan(rig, *, quick: bool = False) -> dict[str, np.ndarray]:
    """Joint angles (rad) of a calibration session on ``rig``'s (arms) layout.

    ``camera``: the camera arm over 6 azimuths × 4 signed elevations (board in view), light parked out of
    the way; ``highlight``: the light arm over 12 azimuths (``quick``: 6) × 5 elevations (10° to 78°), the
    camera at the light's mirror direction and 3° either side of it in elevation (parallax to triangulate
    the light's distance; more parallax sends the reflection off an 80 mm tile at high elevations).
    Poses that are out of limits or in a collision zone are dropped (the same ``solve_many`` checks).
    """
    d = math.radians
    az = np.radians(np.arange(-150.0, 180.0, 60.0 if not quick else 90.0))
    step = 30.0 if not quick else 60.0
    laz = np.radians(np.arange(-180.0 + step / 2, 180.0, step))
    cam = []
    for a in az:
        for e in (-55.0, -25.0, 25.0, 55.0):
            cam.append((0.0, d(70.0) if e < 0 else d(-70.0), a, d(e)))  # light far from the camera
    cam = np.array(cam)
    hi = []
    for a in laz:
        for e in (10.0, 30.0, 50.0, 65.0, 78.0):
            for de in (-3.0, 0.0, 3.0):
                hi.append((a, d(e), a, -d(e + de)))  # camera past the pole: the mirror direction, ± parallax
    hi = np.array(hi)

    def keep(j):
        wi, wo = rig.directions(j)
        code = rig.check_directions(wi, wo)
        ok = np.all((j >= rig.lower) & (j <= rig.upper), axis=-1) & (code == 0)
        return j[ok]

    return {"camera": keep(cam), "highlight": keep(hi)}


def calibrated_rig_text(declared_text: str, result: GeoCalResult, *, note: str = "") -> str:
    """The declared rig file's text plus a ``[calibration]`` table of the estimated assembly errors (degrees,
    millimetres; what :func:`gonio.rig.kinematics.load_rig` reads into ``Rig.geometry_errors``), their
    standard uncertainties (``[calibration.uncertainty]``), their covariance (``[calibration.covariance]``,
    :class:`gonio.rig.geocov.GeometryCovariance`), the parameters not identified (kept at 0, with
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
    for prefix, fields in (("light", ARM_FIELDS), ("camera", CAMERA_FIELDS), ("turntable", TURNTABLE_FIELDS)):
        lines += table(prefix, fields, getattr(e, prefix))
    for prefix, fields in (("light", ARM_FIELDS), ("camera", CAMERA_FIELDS), ("turntable", TURNTABLE_FIELDS)):
        lines += sigma_table(prefix, fields)
    if result.cov is not None and len(result.cov_names):  # gonio.rig.geocov: propagated into wi and samples' σ
        from gonio.rig.geocov import GeometryCovariance

        lines += GeometryCovariance(tuple(result.cov_names), np.asarray(result.cov)).toml_lines()
    return declared_text.rstrip("\n") + "\n" + "\n".join(lines) + "\n"
