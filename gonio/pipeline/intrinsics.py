"""Camera intrinsics and lens distortion from ChArUco views (``gonio camera calibrate``).

* :func:`detect_view`: the interpolated ChArUco corners of one frame (OpenCV 5: ``cv2.aruco.CharucoDetector``
  ``.detectBoard``, ``CharucoBoard.matchImagePoints``; FIELD-NOTES.md), with their board coordinates;
* :func:`calibrate_intrinsics`: Zhang's method ("A flexible new technique for camera calibration", IEEE PAMI
  22(11), 2000) with Brown–Conrady distortion (k1, k2, p1, p2[, k3]), as OpenCV's
  ``cv2.calibrateCameraExtended`` implements it (Levenberg–Marquardt over intrinsics and every view's pose). It
  returns each intrinsic parameter's standard deviation, ``σ_i = s √((JᵀJ)⁻¹)_ii`` with ``s² = Σr² / (2N − p)``
  (the reprojection residuals' variance: Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., §5.2.3), the
  RMS reprojection error and each view's;
* :func:`coverage`: which views are missing — image regions no corner reached (the distortion there is
  extrapolated), too few views tilted against the optical axis or all tilted about one axis (Zhang §3.3: with
  fronto-parallel views only, focal length and principal point are not identified), parameters whose σ says
  they are not determined.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from gonio.errors import ConfigError

__all__ = ["CharucoView", "IntrinsicsResult", "Coverage", "detect_view", "calibrate_intrinsics", "coverage",
           "DIST_MODELS", "PARAMS"]

#: Distortion models: name → (OpenCV flags, coefficients estimated). ``4``: k1, k2, p1, p2 (k3 held at 0: a
#: lens of moderate field of view; Brown 1971's first terms); ``5``: plus k3; ``2``: k1, k2 only. ``auto``
#: (:func:`calibrate_intrinsics`): ``4``, then ``2`` if neither tangential term is significant.
DIST_MODELS = {"2": ("CALIB_FIX_K3|CALIB_ZERO_TANGENT_DIST", ("k1", "k2")), "4": ("CALIB_FIX_K3", ("k1", "k2", "p1", "p2")),
               "5": ("", ("k1", "k2", "p1", "p2", "k3"))}
#: The intrinsic parameters in the order of OpenCV's ``stdDeviationsIntrinsics`` (first nine).
PARAMS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: Fewest corners of a usable view, and fewest views of a calibration.
MIN_CORNERS, MIN_VIEWS = 8, 4
#: A view counts as tilted beyond this angle between the board's normal and the optical axis (degrees).
TILT_DEG = 15.0
#: Largest σ of a parameter still called identified: principal point / focal length (px), distortion (unitless).
IDENTIFIED = {"fx": 2.0, "fy": 2.0, "cx": 1.0, "cy": 1.0, "k1": 0.05, "k2": 0.2, "p1": 0.005, "p2": 0.005, "k3": 0.5}


@dataclass(frozen=True)
class CharucoView:
    """One view's ChArUco corners: board coordinates ``obj`` (N, 3, metres, z = 0), pixels ``img`` (N, 2)."""

    obj: np.ndarray
    img: np.ndarray
    ids: np.ndarray
    source: str = ""


def detect_view(gray: np.ndarray, spec, *, source: str = "", board=None, covers=None) -> CharucoView | None:
    """The ChArUco corners of an 8-bit grey frame (:func:`gonio.pipeline.markers.to_gray8`), or None with fewer
    than :data:`MIN_CORNERS` or (nearly) collinear corners (they constrain no homography). ``covers``: what lies
    on the board (:func:`gonio.pipeline.covers.cover_points`; the target on a rig's stage): the corners whose
    finder window it reaches are left out (:func:`gonio.pipeline.covers.covered_in_plane`)."""
    import cv2

    from gonio.pipeline.markers import MIN_SPREAD_SQUARES, corner_spread

    board = spec.board() if board is None else board
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    if ids is None or len(ids) < MIN_CORNERS:
        return None
    obj, img = board.matchImagePoints(corners, ids)
    if obj is None or len(obj) < MIN_CORNERS:
        return None
    obj, img, ids = np.asarray(obj, np.float64).reshape(-1, 3), np.asarray(img, np.float64).reshape(-1, 2), \
        np.asarray(ids).reshape(-1)
    if covers:
        from gonio.pipeline.covers import covered_in_plane

        keep = ~covered_in_plane(obj, img, spec, covers)
        obj, img, ids = obj[keep], img[keep], ids[keep]
    if len(obj) < MIN_CORNERS or corner_spread(obj) < MIN_SPREAD_SQUARES * spec.square_length:
        return None
    return CharucoView(obj, img, ids, source)


@dataclass(frozen=True)
class Coverage:
    """What the views cover: corners per cell of a 3 × 3 grid over the image, the largest radius reached (as a
    fraction of the half-diagonal), the views' tilts (degrees) and tilt-axis directions, and what is missing."""

    cells: np.ndarray
    radius: float
    tilts_deg: np.ndarray
    missing: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return not self.missing


@dataclass(frozen=True)
class IntrinsicsResult:
    """K, distortion (OpenCV order k1, k2, p1, p2, k3), each parameter's σ, residuals and the coverage."""

    K: np.ndarray
    dist: np.ndarray
    sigma: dict
    rms_px: float
    view_rms_px: np.ndarray
    width: int
    height: int
    model: str
    coverage: Coverage
    not_identified: tuple[str, ...] = ()
    sources: tuple[str, ...] = field(default=())
    #: how the distortion model was chosen (``model="auto"``), else ""
    note: str = ""

    @property
    def values(self) -> dict:
        k, d = self.K, self.dist
        return {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], **dict(zip(PARAMS[4:], d[:5]))}

    def lines(self) -> list[str]:
        """The result as printed: every parameter ± σ (or why not), the residuals, what is missing."""
        fixed = set(PARAMS[4:]) - set(DIST_MODELS[self.model][1])
        out = [f"{len(self.view_rms_px)} views, RMS reprojection error {self.rms_px:.3f} px (worst view "
               f"{self.view_rms_px.max():.3f} px), distortion model {self.model} ({', '.join(DIST_MODELS[self.model][1])})"
               + (f"; {self.note}" if self.note else "")]
        for p in PARAMS:
            v = self.values[p]
            if p in fixed:
                out.append(f"  {p:3s} {v:12.6g}   (held at 0)")
            else:
                note = "   NOT IDENTIFIED by these views" if p in self.not_identified else ""
                out.append(f"  {p:3s} {v:12.6g} ± {self.sigma[p]:.3g}{' px' if p in PARAMS[:4] else ''}{note}")
        c = self.coverage
        out.append(f"  coverage: corners reach {c.radius:.0%} of the half-diagonal; {int(np.sum(c.tilts_deg >= TILT_DEG))} "
                   f"of {len(c.tilts_deg)} views tilted ≥ {TILT_DEG:g}° (max {c.tilts_deg.max():.0f}°)")
        out += [f"  missing: {m}" for m in c.missing]
        return out


_CELLS = ("top-left", "top", "top-right", "left", "centre", "right", "bottom-left", "bottom", "bottom-right")


def coverage(views, width: int, height: int, rvecs, sigma: dict | None = None) -> Coverage:
    """What the views leave out (module docstring): cells of a 3 × 3 grid holding fewer than max(5, 1 %) of the
    corners, corners not reaching 80 % of the half-diagonal, fewer than 3 views tilted ≥ :data:`TILT_DEG` or
    their tilt axes within 30° of each other, a principal point σ above 0.3 px."""
    import cv2

    pts = np.concatenate([v.img for v in views])
    col = np.clip((pts[:, 0] / width * 3).astype(int), 0, 2)
    row = np.clip((pts[:, 1] / height * 3).astype(int), 0, 2)
    cells = np.bincount(row * 3 + col, minlength=9).reshape(3, 3)
    centre = np.array([(width - 1) / 2, (height - 1) / 2])
    radius = float(np.max(np.linalg.norm(pts - centre, axis=1)) / np.hypot(width / 2, height / 2))
    normals = np.array([cv2.Rodrigues(np.asarray(r, np.float64).reshape(3, 1))[0][:, 2] for r in rvecs])
    tilts = np.degrees(np.arccos(np.clip(np.abs(normals[:, 2]), 0, 1)))
    axes = np.degrees(np.arctan2(normals[:, 1], normals[:, 0])) % 180.0  # direction the board leans, mod 180°
    missing = []
    empty = [_CELLS[k] for k in range(9) if cells.ravel()[k] < max(5, 0.01 * len(pts))]
    if empty:
        missing.append(f"no corners in the image's {', '.join(empty)}: add views with the board there (the "
                       "distortion is extrapolated outside the corners)")
    if radius < 0.8:
        missing.append(f"corners reach only {radius:.0%} of the half-diagonal: the distortion toward the image "
                       "corners is extrapolated; add views with the board in the corners")
    tilted = tilts >= TILT_DEG
    if tilted.sum() < 3:
        missing.append(f"{int(tilted.sum())} views tilted ≥ {TILT_DEG:g}° (3 or more needed, in different "
                       "directions): focal length and principal point are not identified by fronto-parallel views")
    elif _spread_mod180(axes[tilted]) < 30.0:
        missing.append("every tilted view leans about one image axis: the focal length across it rests on the "
                       "board's square shape (fx/fy) and its σ says how well; views tilted about the other axis too "
                       "(e.g. hand-held images, --images) would determine it independently")
    if sigma is not None and max(sigma.get("cx", 0.0), sigma.get("cy", 0.0)) > 0.3:
        missing.append(f"principal point σ ({sigma['cx']:.2f}, {sigma['cy']:.2f}) px > 0.3 px: more tilted views "
                       "(30–50°), about both axes")
    return Coverage(cells, radius, tilts, tuple(missing))


def _spread_mod180(a: np.ndarray) -> float:
    """Largest angular separation (degrees) between directions ``a`` taken modulo 180°."""
    a = np.sort(np.asarray(a) % 180.0)
    gaps = np.diff(np.concatenate([a, a[:1] + 180.0]))
    return float(180.0 - gaps.max())


def calibrate_intrinsics(views, width: int, height: int, *, model: str = "auto") -> IntrinsicsResult:
    """K and distortion from ``views`` (:class:`CharucoView`, at least :data:`MIN_VIEWS`) of a ``width`` ×
    ``height`` camera (module docstring). ConfigError (one line) for too few views or a model name.

    ``model="auto"``: the ``4`` model first; if both tangential coefficients are within 2σ of 0 (not
    significant), the ``2`` model instead — the decentering terms p1, p2 are strongly correlated with the
    principal point (Brown 1971; a tangential term is to first order a shift of the image centre), so estimating
    terms the lens does not show costs the principal point much of its precision (σ(cx) ×2–3 on the simulated
    rig). The result says which model it kept and why (:attr:`IntrinsicsResult.note`)."""
    if model == "auto":
        first = _calibrate(views, width, height, "4")
        p1, p2 = first.dist[2], first.dist[3]
        if abs(p1) < 2 * first.sigma["p1"] and abs(p2) < 2 * first.sigma["p2"]:
            second = _calibrate(views, width, height, "2")
            return replace(second, note=f"tangential terms not significant (p1 = {p1:.2g} ± {first.sigma['p1']:.2g}, "
                                        f"p2 = {p2:.2g} ± {first.sigma['p2']:.2g}): held at 0 (--dist-model 4 "
                                        "estimates them)")
        return replace(first, note=f"tangential terms significant (p1 = {p1:.2g} ± {first.sigma['p1']:.2g}, "
                                   f"p2 = {p2:.2g} ± {first.sigma['p2']:.2g}): estimated")
    return _calibrate(views, width, height, model)


def _calibrate(views, width: int, height: int, model: str) -> IntrinsicsResult:
    import cv2

    if model not in DIST_MODELS:
        raise ConfigError.field("--dist-model", "dist_model", model, f"must be auto or one of {', '.join(DIST_MODELS)}")
    views = [v for v in views if v is not None]
    if len(views) < MIN_VIEWS:
        raise ConfigError.field(None, "views", len(views), f"{MIN_VIEWS} or more views with the ChArUco board found "
                                "are needed (tilted in several directions, reaching the image corners)")
    flags = 0
    for name in filter(None, DIST_MODELS[model][0].split("|")):
        flags |= getattr(cv2, name)
    obj = [v.obj.astype(np.float32).reshape(-1, 1, 3) for v in views]
    img = [v.img.astype(np.float32).reshape(-1, 1, 2) for v in views]
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    try:
        rms, K, dist, rvecs, _tvecs, sd, _sd_ext, per_view = cv2.calibrateCameraExtended(
            obj, img, (int(width), int(height)), None, None, flags=flags, criteria=criteria)
    except cv2.error as exc:
        raise ConfigError.field(None, "views", len(views), f"OpenCV could not calibrate: {str(exc).strip()[:120]}") from None
    d = np.zeros(5)
    raw = np.asarray(dist, dtype=np.float64).ravel()
    d[:min(5, raw.size)] = raw[:5]
    sd = np.asarray(sd, dtype=np.float64).ravel()
    sigma = {p: float(sd[k]) for k, p in enumerate(PARAMS)}
    estimated = set(PARAMS[:4]) | set(DIST_MODELS[model][1])
    bad = tuple(p for p in PARAMS if p in estimated and not (math.isfinite(sigma[p]) and sigma[p] <= IDENTIFIED[p]))
    cov = coverage(views, width, height, rvecs, sigma)
    return IntrinsicsResult(np.asarray(K, dtype=np.float64), d, sigma, float(rms),
                            np.asarray(per_view, dtype=np.float64).ravel(), int(width), int(height), model, cov, bad,
                            tuple(v.source for v in views))
