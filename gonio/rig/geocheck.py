"""``gonio calibrate check``: how far a rig file's directions are from what the camera really sees.

A few poses are re-measured on the rig (:func:`gonio.session.geocal_session.check_session_plan`, run by the
same session runner and capture as ``gonio calibrate rig``: the board pose in every frame, the light's
highlight in the tile on the stage). For each pose the rig file's kinematics give ``wi`` and ``wo``
(:meth:`gonio.rig.kinematics.Rig.directions`, with its ``[calibration]`` if it has one); what the camera
sees gives them independently:

* **wo**: the camera centre from the ChArUco board pose, as a direction from the sample centre;
* **wi**: the light's highlight is its mirror image in the sample plane (law of reflection), which lies
  on the camera ray through the highlight's pixel: ``m = c + s·d`` (``c`` the board's camera centre,
  ``d = Rᵀ·(x, y, 1)/|·|``). Its distance from the sample centre is taken from the rig file (the ray
  meets that sphere; one view cannot give a distance): the rig file's distance error ``δρ`` enters
  ``wi`` only through the angle between the ray and the radius through the tile's centre (a few degrees),
  ``δρ·sin(·)/ρ`` — < 0.01° for a calibrated rig (``δρ`` ≲ 0.2 mm), ~0.05° for a declared one with a 5 mm error.
  Then ``wi = (mx, my, −mz)/|m|``.

The angle between each pair (:func:`gonio.rig.chain.angle_between_deg`) is the error left, plus the
observation's own noise. That noise is known per pose: the board pose's covariance (and the highlight
centroid's) propagated to the observed direction (first order, by finite differences; GUM, JCGM 100 §5.1),
its standard uncertainty the square root of the largest eigenvalue. A pose whose own uncertainty exceeds a
third of the threshold (a board seen too obliquely or too small) cannot tell a good rig from a bad one: it is
counted and left out of the verdict, which compares the 95th percentile of the errors of the other poses
with the threshold (default :data:`THRESHOLD_DEG`, issue 15's goal after calibration).

A few re-measured poses near the mirror configuration cannot vouch for the whole workspace, so the verdict also
follows every other number the report shows (:meth:`GeoCheck.failures`): the wi error the rig file's own
calibration covariance allows over random reachable poses (:func:`gonio.rig.geocov.wi_error_p95`) and, on the
simulator, the true errors over those poses. ``OK`` only when all of them are within the threshold.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.rig.chain import angle_between_deg

__all__ = ["THRESHOLD_DEG", "GeoCheck", "check_geometry", "observed_wi", "observed_wo", "wi_sigma", "wo_sigma"]

#: Default verdict threshold (degrees) on the 95th percentile of the wi and wo errors.
THRESHOLD_DEG = 0.25
#: What helps a calibration whose own uncertainty is too large (said by the verdict and by `gonio calibrate rig`).
CALIBRATION_HELP = ("calibrate again with more poses (the full plan, not --quick), a larger ChArUco board or the "
                    "camera closer (a smaller board pose σ), and the tile centred so fewer highlights are lost")


def observed_wo(cams) -> np.ndarray:
    """Unit directions from the sample centre to the camera centres of board poses ``(n, 3)``."""
    p = np.stack([c.position for c in cams])
    return p / np.linalg.norm(p, axis=-1, keepdims=True)


def observed_wi(highs, light_distance) -> np.ndarray:
    """Unit light directions from highlights (module docstring): the camera ray through each highlight meets the
    sphere of radius ``light_distance`` (m, per observation) about the sample centre at the light's mirror image."""
    o = np.stack([h.position for h in highs])
    xy = np.stack([h.xy for h in highs])
    R = np.stack([h.R for h in highs])
    v = np.concatenate([xy, np.ones((len(highs), 1))], axis=1)
    d = (np.swapaxes(R, -1, -2) @ v[..., None])[..., 0]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = np.sum(o * d, axis=-1)
    rho = np.asarray(light_distance, dtype=np.float64)
    disc = b ** 2 - np.sum(o * o, axis=-1) + rho ** 2
    s = -b + np.sqrt(np.clip(disc, 0.0, None))   # the far root: past the mirror
    m = o + s[:, None] * d
    wi = m * np.array([1.0, 1.0, -1.0])
    return wi / np.linalg.norm(wi, axis=-1, keepdims=True)


def _sigma_deg(f, x0, cov) -> float:
    """Standard uncertainty (degrees; largest principal axis) of the unit vector ``f(x0)`` for inputs ``x0``
    with covariance ``cov`` (first-order propagation, central differences)."""
    x0 = np.asarray(x0, dtype=np.float64)
    J = np.empty((3, len(x0)))
    for k in range(len(x0)):
        h = 1e-3 * max(np.sqrt(cov[k, k]), 1e-9)
        e = np.zeros(len(x0))
        e[k] = h
        J[:, k] = (f(x0 + e) - f(x0 - e)) / (2 * h)
    return float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(J @ cov @ J.T)[-1], 0.0))))


def _turned(R, rv_deg):
    """``exp([rv]×)·R`` (Rodrigues; the covariance's convention: rotation vector of R_true R_obsᵀ)."""
    import cv2

    return cv2.Rodrigues(np.radians(np.asarray(rv_deg, dtype=np.float64)).reshape(3, 1))[0] @ R


def wo_sigma(cam) -> float:
    """Standard uncertainty (deg) of :func:`observed_wo` of one board pose from its covariance (NaN: none)."""
    if cam.cov is None:
        return float("nan")

    def f(x):
        p = cam.position + x[:3] * 1e-3
        return p / np.linalg.norm(p)

    return _sigma_deg(f, np.zeros(3), np.asarray(cam.cov)[:3, :3])


def wi_sigma(high, cam_cov, light_distance) -> float:
    """Standard uncertainty (deg) of :func:`observed_wi` of one highlight from its board pose's covariance
    ``cam_cov`` (6 × 6) and its centroid's (NaN if either is unknown)."""
    if cam_cov is None or high.cov is None:
        return float("nan")
    from dataclasses import replace

    def f(x):
        h = replace(high, position=high.position + x[:3] * 1e-3, R=_turned(high.R, x[3:6]), xy=high.xy + x[6:8])
        return observed_wi([h], np.array([light_distance]))[0]

    cov = np.zeros((8, 8))
    cov[:6, :6], cov[6:, 6:] = cam_cov, high.cov
    return _sigma_deg(f, np.zeros(8), cov)


@dataclass
class GeoCheck:
    """Errors (degrees) of the rig file's wi (one per highlight) and wo (one per board pose), each observation's
    own standard uncertainty (degrees; NaN: unknown), and the verdict (module docstring)."""

    wi_deg: np.ndarray
    wo_deg: np.ndarray
    threshold_deg: float
    wi_sigma: np.ndarray | None = None
    wo_sigma: np.ndarray | None = None
    #: p95 (degrees) of the wi error the rig file's calibration covariance allows over the reachable poses
    #: (:func:`gonio.rig.geocov.wi_error_p95`; ``None``: the file states no covariance)
    bound_wi_p95: float | None = None
    #: p95 (degrees) of the true wi and wo errors over the reachable poses, when a truth is known (the simulator)
    truth_p95: dict | None = None

    def judged(self, which: str) -> np.ndarray:
        """The errors of the poses whose own uncertainty is at most a third of the threshold (or unknown)."""
        x, s = (self.wi_deg, self.wi_sigma) if which == "wi" else (self.wo_deg, self.wo_sigma)
        if s is None:
            return x
        return x[~(np.asarray(s) > self.threshold_deg / 3.0)]

    def failures(self) -> list[tuple[str, float, str]]:
        """Every number over the threshold: ``(what, degrees, what to do)``; the verdict follows all of them — the
        re-measured poses, the calibration's own uncertainty over the reachable poses, the truth when known."""
        out = []
        for k in ("wi", "wo"):
            if len(self.judged(k)) and self.p95(k) > self.threshold_deg:
                out.append((f"{k} is off by {self.p95(k):.3f}° (p95 of the re-measured poses)", self.p95(k),
                            "run `gonio calibrate rig` from the declared rig file"))
        if self.bound_wi_p95 is not None and self.bound_wi_p95 > self.threshold_deg:
            out.append((f"calibration's own uncertainty allows wi errors of {self.bound_wi_p95:.3f}° (p95 over the "
                        f"reachable poses)", self.bound_wi_p95, CALIBRATION_HELP))
        for k, v in (self.truth_p95 or {}).items():
            if v > self.threshold_deg:
                out.append((f"{k} is off by {v:.3f}° from the simulated truth (p95 over the reachable poses)", v,
                            "run `gonio calibrate rig` from the declared rig file"))
        return out

    @property
    def ok(self) -> bool:
        return bool(len(self.judged("wi")) and len(self.judged("wo")) and not self.failures())

    def p95(self, which: str) -> float:
        x = self.judged(which)
        return float(np.percentile(x, 95)) if len(x) else float("nan")

    def lines(self, source: str) -> list[str]:
        """The report: one line per direction, then the one-line verdict."""
        out = []
        for name, x, s, what in (("wi", self.wi_deg, self.wi_sigma, "light's reflection"),
                                 ("wo", self.wo_deg, self.wo_sigma, "ChArUco board")):
            j = self.judged(name)
            left = x[np.asarray(s) > self.threshold_deg / 3.0] if s is not None else x[:0]
            extra = (f"; {len(left)} more too uncertain to judge (own σ > {self.threshold_deg / 3:.3g}°; their "
                     f"errors {', '.join(f'{v:.2f}' for v in left[:4])}{'…' if len(left) > 4 else ''}°)"
                     if len(left) else "")
            if len(j):
                out.append(f"  {name} vs the {what} ({len(j)} poses): median {np.median(j):.3f}°, "
                           f"p95 {self.p95(name):.3f}°, max {j.max():.3f}°{extra}")
            else:
                out.append(f"  {name}: no pose gave a usable {what}{extra}")
        if self.bound_wi_p95 is not None:
            out.append(f"  wi the rig file's calibration uncertainty allows over the reachable poses: p95 "
                       f"{self.bound_wi_p95:.3f}°")
        else:
            out.append("  the rig file states no calibration covariance: only the re-measured poses judge it")
        for k, v in (self.truth_p95 or {}).items():
            out.append(f"  {k} vs the simulated truth over the reachable poses: p95 {v:.3f}°")
        if not (len(self.judged("wi")) and len(self.judged("wo"))):
            out.append(f"verdict: NOT CHECKED: no pose measured {'wi' if not len(self.judged('wi')) else 'wo'} "
                       f"precisely enough to judge {source} against {self.threshold_deg:g}° (is the tile on the "
                       f"stage, the board in view?)")
        elif self.ok:
            out.append(f"verdict: OK: {source}'s wi and wo are within {self.threshold_deg:g}° of what the camera sees "
                       f"(p95 {self.p95('wi'):.3f}° and {self.p95('wo'):.3f}°)")
        else:
            what, deg, todo = max(self.failures(), key=lambda f: f[1])
            out.append(f"verdict: RECALIBRATE: {source}'s {what} > {self.threshold_deg:g}°; {todo}")
        return out


def check_geometry(rig, cams, highs, *, threshold_deg: float = THRESHOLD_DEG, truth=None) -> GeoCheck:
    """The error of ``rig``'s directions against the observations (module docstring), with the wi error its
    calibration covariance allows over the reachable poses (:func:`gonio.rig.geocov.wi_error_p95`) and, when
    ``truth`` (true :class:`gonio.rig.chain.ChainErrors`, the simulator's) is given, the true errors there."""
    from gonio.rig.geocov import wi_error_p95, workspace_joints

    wo, wi, so, si = (np.zeros(0) for _ in range(4))
    if cams:
        j = np.stack([c.joints for c in cams])
        wo = angle_between_deg(rig.directions(j)[1], observed_wo(cams))
        so = np.array([wo_sigma(c) for c in cams])
    if highs:
        j = np.stack([h.joints for h in highs])
        rho = np.linalg.norm(rig.light_position(j), axis=-1)
        wi = angle_between_deg(rig.directions(j)[0], observed_wi(highs, rho))
        # a highlight's board pose is the camera observation of the same frame (same joints, same centre)
        covs = {(tuple(c.joints), tuple(c.position)): c.cov for c in cams}
        si = np.array([wi_sigma(h, covs.get((tuple(h.joints), tuple(h.position))), r) for h, r in zip(highs, rho)])
    truth_p95 = None
    if truth is not None:
        from dataclasses import replace

        from gonio.rig.chain import true_directions

        jw = workspace_joints(rig, 2000)
        twi, two = true_directions(replace(rig, geometry_errors=None), truth, jw)
        hwi, hwo = rig.directions(jw)
        truth_p95 = {"wi": float(np.percentile(angle_between_deg(hwi, twi), 95)),
                     "wo": float(np.percentile(angle_between_deg(hwo, two), 95))}
    return GeoCheck(wi, wo, float(threshold_deg), si, so, bound_wi_p95=wi_error_p95(rig), truth_p95=truth_p95)
