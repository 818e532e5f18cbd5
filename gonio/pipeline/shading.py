"""The board's illumination in a frame, and the ChArUco corners found again with it divided out (flat-fielded).

A point light a few decimetres from the board lights it unevenly: the irradiance ``I cos θ / r²`` changes by 10–30 %
across the board, about 10⁻³ of its value per pixel. A sub-pixel corner finder is not blind to that. OpenCV's
(``cv2.cornerSubPix``, Förstner & Gülch 1987) solves ``Σ_p ∇I(p) ∇I(p)ᵀ (q − p) = 0`` over a window: in the flat
parts of a checker the shading's own gradient ``T ∇s`` is not zero, and on the edges it weights the bright side
more (``∇I = s ∇T + T ∇s``). The corner moves towards the light by about ``|∇ ln s| w²`` (``w`` the window's
half-size): 0.01 px on the simulated rig's calibration frames, always the same way in the image because the
calibration's highlight frames see the light from the same side, and so a bias of the camera arm's ``arc_x`` by
+1.5σ in every calibration (issue 28; measured in ``/work/notes/bench-logs/uncert5``).

A lab flat-fields the board image (divides it by the illumination) before it locates the corners; so does
:func:`flat_fielded`: the illumination ``s`` is fitted to the board's white margins (the white ring of each
marker's square, where the board is known to be uniformly white), ``ln s`` a quadratic in the image coordinates,
and :func:`gonio.pipeline.markers.detect_board_pose` (``flat_field=True``) finds the board again in ``I / s``.
Measured on the calibration plan's highlight frames (noiseless, 282 poses, the board origin's image position): the
point light moves it by +0.0080 ± 0.0017 px in y against a uniform light; detected again in the flat-fielded frame,
by +0.0002 ± 0.0017 px. Refining only the corners on ``I / s`` removed half of it: the markers, from which the
detector interpolates the corners before refining them to 0.1 px, are shifted by the shading too.
"""

from __future__ import annotations

import numpy as np

__all__ = ["white_margin_points", "fit_illumination", "flat_fielded", "MIN_SHADING_SAMPLES"]

#: Fewest usable white-margin samples for an illumination fit (six coefficients, a robust second pass).
MIN_SHADING_SAMPLES = 24

def white_margin_points(spec) -> np.ndarray:
    """Points (board frame, (n, 3) m) on the white margin around every marker: the middle of the ring between the
    marker's edge and its square's, three points on each of the four sides (at the side's middle and ±M/4 along
    it, M the marker's side): each half a margin, ``(L − M)/4``, from both edges, well away from the chessboard
    corners. The squares are found from the board's marker object points (each marker at the centre of a white
    square), so the layout follows OpenCV's board whatever its pattern convention."""
    board = spec.board()
    centres = np.array([np.asarray(c, dtype=np.float64).reshape(-1, 3).mean(axis=0) for c in board.getObjPoints()])
    L, M = spec.square_length, spec.marker_length
    m = (L + M) / 4.0  # from the square's centre to the margin's middle
    along = np.array([-M / 4.0, 0.0, M / 4.0])
    offs = np.concatenate([np.stack([np.full(3, s * m), along, np.zeros(3)], axis=1) for s in (-1, 1)]
                          + [np.stack([along, np.full(3, s * m), np.zeros(3)], axis=1) for s in (-1, 1)])
    return (centres[:, None, :] + offs[None, :, :]).reshape(-1, 3)


def _design(xy: np.ndarray, shape) -> np.ndarray:
    """The quadratic's terms ``1, u, v, u², uv, v²`` at image points ``xy`` (n, 2), ``u, v`` the coordinates
    scaled to [−1, 1] over the image (conditioning)."""
    h, w = shape[:2]
    u = (xy[:, 0] - 0.5 * (w - 1)) / (0.5 * w)
    v = (xy[:, 1] - 0.5 * (h - 1)) / (0.5 * h)
    return np.stack([np.ones_like(u), u, v, u * u, u * v, v * v], axis=1)


def fit_illumination(gray: np.ndarray, xy: np.ndarray, *, saturation: float = 255.0):
    """The coefficients of ``ln s`` (:func:`_design`'s quadratic) fitted to the image values at the white-margin
    points ``xy`` (n, 2, px) by least squares, then again without the samples more than 4 robust standard
    deviations (1.4826 × the median absolute deviation: Hampel 1974) from the first fit (a highlight, a speck,
    a part the covers missed); ``None`` with fewer than :data:`MIN_SHADING_SAMPLES` usable samples (inside the
    image, above 0 and below ``saturation``). Values by bilinear interpolation (``cv2.remap``)."""
    import cv2

    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    h, w = gray.shape[:2]
    inside = (xy[:, 0] >= 0) & (xy[:, 0] <= w - 1) & (xy[:, 1] >= 0) & (xy[:, 1] <= h - 1)
    xy = xy[inside]
    if len(xy) < MIN_SHADING_SAMPLES:
        return None
    img = np.asarray(gray, dtype=np.float32)
    val = cv2.remap(img, xy[:, 0].astype(np.float32).reshape(-1, 1), xy[:, 1].astype(np.float32).reshape(-1, 1),
                    cv2.INTER_LINEAR).reshape(-1).astype(np.float64)
    ok = (val > 0) & (val < saturation)
    if ok.sum() < MIN_SHADING_SAMPLES:
        return None
    A, y = _design(xy[ok], gray.shape), np.log(val[ok])
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    r = y - A @ coef
    s = 1.4826 * np.median(np.abs(r - np.median(r)))
    keep = np.abs(r) <= 4.0 * max(s, 1e-6)
    if keep.sum() < MIN_SHADING_SAMPLES:
        return None
    return np.linalg.lstsq(A[keep], y[keep], rcond=None)[0]


def flat_fielded(gray: np.ndarray, rvec, tvec, calib, spec, *, exclude=None) -> np.ndarray | None:
    """``gray`` (an 8-bit frame of the board) divided by the board's illumination, as 8 bits again: the
    illumination fitted (:func:`fit_illumination`) to the white margins (:func:`white_margin_points`) seen with the
    board pose ``(rvec, tvec)``, leaving out the margin points ``exclude`` says (a function of their image points
    (m, 2) giving a mask: those under a cover); the quotient scaled so the illumination's mean over the image is
    kept. ``None`` when the illumination cannot be fitted."""
    import cv2

    pts = white_margin_points(spec)
    proj, _ = cv2.projectPoints(pts, np.asarray(rvec, dtype=np.float64).reshape(3, 1),
                                np.asarray(tvec, dtype=np.float64).reshape(3, 1), calib.K, calib.dist)
    xy = proj.reshape(-1, 2)
    if exclude is not None:
        xy = xy[~np.asarray(exclude(xy), dtype=bool)]
    coef = fit_illumination(gray, xy)
    if coef is None:
        return None
    h, w = gray.shape[:2]
    u = ((np.arange(w) - 0.5 * (w - 1)) / (0.5 * w))[None, :]
    v = ((np.arange(h) - 0.5 * (h - 1)) / (0.5 * h))[:, None]
    c = coef
    lns = (c[1] * u + c[3] * u * u) + (c[2] * v + c[5] * v * v) + c[4] * (u * v)  # _design's terms without the constant
    lns -= lns.mean()
    flat = np.asarray(gray, dtype=np.float32) * np.exp(-lns).astype(np.float32)
    np.rint(flat, out=flat)
    return np.clip(flat, 0, 255).astype(np.uint8)
