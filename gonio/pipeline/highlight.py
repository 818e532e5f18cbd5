"""The light's specular highlight in a flat mirror or glossy black tile on the stage: found in a frame,
located to a fraction of a pixel, with its uncertainty (the geometric calibration's light-arm
observation, :mod:`gonio.rig.geocal`).

Detection (:func:`detect_highlight`): the frame is averaged over its colour channels and the black
level removed; the brightest pixel of a 3 × 3 box-filtered copy is the candidate. In a window around
it, the background and its noise are the median and the MAD (×1.4826, Gaussian-consistent; Huber,
*Robust Statistics*, 1981, §5.1) of the window's border pixels. The highlight is the 8-connected
component of pixels more than ``max(6 σ_bg, 2 % of the peak)`` above the background that contains the
peak, dilated by one pixel (its skirt); its position is the background-subtracted intensity-weighted
centroid (first moment; for a symmetric spot it is unbiased to the spot's centre, and with n pixels of
independent noise its variance is ``Σ (u_k − ū)² σ_k² / (Σ w)²``, the linear propagation of the
pixels' variances; Alexander & Ng 1991, "Elimination of systematic error in subpixel accuracy
centroid estimation", Opt. Eng. 30(9)). The pixels' variances come from the camera's noise model
(EMVA 1288: :meth:`gonio.pipeline.target.NoiseModel.variance`).

A frame is refused (``None`` and the reason in :attr:`HighlightSearch.reason`) when the spot has a
saturated pixel (its centroid would be biased: :func:`find_highlight` shortens the exposure), when it
is too faint (peak below :data:`MIN_SNR` background σ), when it touches the frame's edge, or when a
second spot at least half as bright lies outside the window (a reflection that is not the light's).

:func:`find_highlight` captures at a short exposure (the board and the tile's diffuse part are then
black), shortens it while the spot saturates and lengthens it while its peak is below a quarter of
the linear range, then averages ``frames`` frames at the exposure found.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gonio.pipeline.target import CameraCalibration

__all__ = ["Highlight", "HighlightSearch", "detect_highlight", "find_highlight", "clear_of_edges", "MIN_SNR"]

#: Smallest peak-to-background-noise ratio of an accepted highlight.
MIN_SNR = 30.0
#: Floor (pixels) of the centroid's standard uncertainty: what photon noise alone does not show (the
#: lens's asymmetric blur, the emitter's non-uniform radiance, pixel response non-uniformity); a
#: centroid of a well-exposed spot is not better than ~0.02 px on real sensors (Alexander & Ng 1991).
MIN_SIGMA_PX = 0.02
#: Half-width (pixels) of the window the background and the spot are measured in.
WINDOW = 14


@dataclass(frozen=True)
class Highlight:
    """A detected highlight: pixel position ``uv`` (pixel centres at integers), normalized undistorted
    image coordinates ``xy`` (the ray ``(x, y, 1)`` in the camera frame) and their 2 × 2 covariances."""

    uv: np.ndarray
    cov_uv: np.ndarray
    xy: np.ndarray
    cov_xy: np.ndarray
    peak_dn: float
    n_pixels: int
    exposure: float = 0.0


@dataclass
class HighlightSearch:
    """What :func:`find_highlight` did: the highlight (or None), why not, the exposures tried."""

    highlight: Highlight | None
    reason: str = ""
    exposures: list = field(default_factory=list)


def _gray(pixels, black_level: float) -> np.ndarray:
    """The channels' mean less the black level. The mean is a left fold of the channel planes, divided by their
    count: what ``np.mean(axis=2)`` computes, in its order, without NumPy's slow reduction over a short last axis
    (~10x the time on a 640 × 480 × 3 frame)."""
    img = np.asarray(pixels, dtype=np.float64)
    if img.ndim == 3:
        total = img[..., 0].copy()
        for k in range(1, img.shape[2]):
            total += img[..., k]
        img = total / img.shape[2]
    return img - float(black_level)


def detect_highlight(pixels, calib: CameraCalibration, *, black_level: float = 0.0, saturation: float | None = None,
                     channels: int = 3, frames: int = 1, gain: float = 1.0):
    """``(Highlight | None, reason)`` in one frame (or the mean of ``frames`` frames); module docstring.

    ``saturation``: the raw value at which the sensor stops being linear (refused at or above it);
    ``channels``/``frames``: how many independent values each grey pixel averages (variance divided)."""
    import cv2

    img = _gray(pixels, black_level)
    h, w = img.shape
    smooth = cv2.blur(img.astype(np.float32), (3, 3))
    r, c = np.unravel_index(int(np.argmax(smooth)), smooth.shape)
    W = WINDOW
    r0, r1, c0, c1 = r - W, r + W + 1, c - W, c + W + 1
    if r0 < 0 or c0 < 0 or r1 > h or c1 > w:
        return None, f"brightest spot at pixel ({c}, {r}) is within {W} px of the frame's edge"
    win = img[r0:r1, c0:c1]
    border = np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])
    bg = float(np.median(border))
    sigma_bg = max(1.4826 * float(np.median(np.abs(border - bg))), 0.5)
    s = win - bg
    peak = float(s[W, W] if s[W, W] >= s.max() * 0.5 else s.max())
    if not peak >= MIN_SNR * sigma_bg:
        return None, f"no highlight: brightest spot {peak:.3g} DN above background, {MIN_SNR:g} x noise needed"
    thr = max(6.0 * sigma_bg, 0.02 * peak)
    n_lab, lab = cv2.connectedComponents((s > thr).astype(np.uint8), connectivity=8)
    mask = lab == lab[W, W] if lab[W, W] else lab == lab.ravel()[int(np.argmax(s))]
    mask = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    if mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any():
        return None, f"highlight at pixel ({c}, {r}) larger than the {2 * W + 1} px window (out of focus or not the light)"
    raw = np.asarray(pixels)[r0:r1, c0:c1]  # the window's raw values (the brightest channel): the spot's only
    raw = raw.max(axis=2) if raw.ndim == 3 else raw
    if saturation is not None and np.any(raw[mask] >= np.floor(saturation) - 0.5):
        return None, "saturated"
    outside = smooth.copy()
    outside[max(r0, 0):r1, max(c0, 0):c1] = -np.inf
    if float(outside.max()) - bg > 0.5 * float(smooth[r, c] - bg):
        rr, cc = np.unravel_index(int(np.argmax(outside)), outside.shape)
        return None, f"two bright spots (pixels ({c}, {r}) and ({cc}, {rr})): which one is the light's reflection?"
    wgt = np.where(mask, np.maximum(s, 0.0), 0.0)
    total = float(wgt.sum())
    vv, uu = np.mgrid[r0:r1, c0:c1].astype(np.float64)
    u = float((wgt * uu).sum() / total)
    v = float((wgt * vv).sum() / total)
    var = calib.noise.variance(np.maximum(win, 0.0), gain) / (channels * frames)
    var = np.where(mask, var + sigma_bg ** 2 / border.size, 0.0)  # + the background estimate's own error
    du, dv = (uu - u) * mask, (vv - v) * mask
    cov_uv = np.array([[np.sum(du * du * var), np.sum(du * dv * var)],
                       [np.sum(du * dv * var), np.sum(dv * dv * var)]]) / total ** 2
    cov_uv += np.eye(2) * MIN_SIGMA_PX ** 2
    xy, J = _normalized(np.array([u, v]), calib)
    return Highlight(uv=np.array([u, v]), cov_uv=cov_uv, xy=xy, cov_xy=J @ cov_uv @ J.T, peak_dn=peak,
                     n_pixels=int(mask.sum()), exposure=0.0), ""


def _normalized(uv, calib: CameraCalibration):
    """Undistorted normalized coordinates of pixel ``uv`` and their Jacobian d(xy)/d(uv) (finite differences)."""
    import cv2

    def f(p):
        return cv2.undistortPoints(np.asarray(p, np.float64).reshape(1, 1, 2), calib.K, calib.dist).reshape(2)

    xy = f(uv)
    J = np.stack([(f(uv + e) - f(uv - e)) / 2e-2 for e in (np.array([1e-2, 0.0]), np.array([0.0, 1e-2]))], axis=1)
    return xy, J


def find_highlight(camera, calib: CameraCalibration, *, exposure: float = 5e-5, min_exposure: float = 1e-5,
                   max_exposure: float = 0.05, frames: int = 2, gain: float = 1.0, max_tries: int = 8) -> HighlightSearch:
    """Capture the highlight at an exposure where it is bright but not saturated (module docstring)."""
    tried = []
    t = float(exposure)
    for _ in range(max_tries):
        f = camera.capture(t, gain)
        tried.append(t)
        sat = calib.noise.linear_limit((1 << f.bit_depth) - 1, f.black_level, gain)
        hl, why = detect_highlight(f.pixels, calib, black_level=f.black_level, saturation=sat, gain=gain)
        if why == "saturated":
            if t <= min_exposure:
                return HighlightSearch(None, f"highlight saturated at the shortest exposure {t:g} s: dim the light", tried)
            t = max(t / 4.0, min_exposure)
            continue
        if hl is None:
            return HighlightSearch(None, why, tried)
        target = 0.5 * (sat - f.black_level)
        if hl.peak_dn < 0.25 * (sat - f.black_level) and t < max_exposure:
            t = min(t * min(target / max(hl.peak_dn, 1e-9), 8.0), max_exposure)
            continue
        break
    else:
        return HighlightSearch(None, f"no usable exposure for the highlight after {max_tries} frames", tried)
    stack = [f.pixels.astype(np.float64)]
    for _ in range(frames - 1):
        stack.append(camera.capture(t, gain).pixels.astype(np.float64))
        tried.append(t)
    mean = np.mean(stack, axis=0)
    hl, why = detect_highlight(mean, calib, black_level=f.black_level, saturation=sat, frames=len(stack), gain=gain)
    if hl is None:
        return HighlightSearch(None, why, tried)
    from dataclasses import replace

    return HighlightSearch(replace(hl, exposure=t), "", tried)


def clear_of_edges(hl: Highlight, pose, calib: CameraCalibration, rect, *, margin_px: float = 2.0) -> str:
    """``""`` if the highlight lies inside the tile ``rect`` (a :class:`gonio.pipeline.target.Rect` in the
    sample plane, seen from camera ``pose``) by at least its own radius (``√(n/π)``) plus ``margin_px``;
    else why not: a spot cut by the tile's edge has a biased centroid."""
    corners = pose.project(rect.corners(), calib)  # (4, 2): the tile's outline (a convex quadrilateral)
    u = hl.uv
    need = np.sqrt(hl.n_pixels / np.pi) + margin_px
    d = []
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        e = b - a
        cross = e[0] * (u[1] - a[1]) - e[1] * (u[0] - a[0])
        d.append(cross / max(np.hypot(*e), 1e-12))
    d = np.array(d)
    d = d if np.sum(d > 0) >= np.sum(d < 0) else -d  # the corners' winding decides the inside's sign
    if np.min(d) < need:
        return (f"highlight at pixel ({u[0]:.1f}, {u[1]:.1f}) is {np.min(d):.1f} px from the tile's edge "
                f"({need:.1f} needed): its reflection may be cut")
    return ""
