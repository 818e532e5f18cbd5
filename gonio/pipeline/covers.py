"""What hides the ChArUco board's corners: the target's own parts lying on it, and which detected corners they spoil.

The layout (:class:`gonio.pipeline.target.TargetLayout`) puts a white reference patch and the sample (a flat patch,
the calibration tile, a sphere or a cylinder) on the board. A chessboard corner is located by a sub-pixel corner
finder in a window around it (OpenCV's ChArUco detector: ``cv2.cornerSubPix`` — Förstner & Gülch 1987 — in a
window of half-size ``clip(d − 2, 1, 10)`` px, ``d`` the distance to the nearest marker corner); the finder assumes
the four squares of a checker meet there. Where a patch covers part of that window, the "corner" it returns is not
the board's: the default layout's white patch has its edge through two corners, which came out 0.1–0.25 mm off, all
away from the board's centre — a systematic error of every board pose (a scale of +2·10⁻⁴ and a 0.01–0.02 mm shift
of the board frame in x on the simulated rig; the closing note of the third session, docs/uncertainty.md). Those
corners are left out (:func:`covered_corners`), as a lab would mask them.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cover_points", "covered_corners", "covered_in_plane", "covered_by", "corner_windows", "cover_hulls",
           "near_hulls", "pose_projector", "plane_projector", "COVER_MARGIN_PX", "MAX_WINDOW_PX"]

#: Pixels added to a corner finder's window: the lens's (or the renderer's) blur reaches that far beyond it.
COVER_MARGIN_PX = 2.0
#: Largest half-size (px) of OpenCV's ChArUco corner window (its ``getMaximumSubPixWindowSizes``: at most 10).
MAX_WINDOW_PX = 10.0


def _sphere_points(centre, radius, n: int = 400) -> np.ndarray:
    """``n`` points spread evenly over a sphere (the Fibonacci lattice: González, "Measurement of areas on a
    sphere using Fibonacci and latitude–longitude lattices", Math. Geosci. 42, 2010): their image's convex hull is
    the sphere's outline to within ``r (1 − cos(π/√n))`` (0.6 % of r at n = 400)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * k
    s = np.sqrt(1.0 - z * z)
    return np.asarray(centre, dtype=np.float64) + radius * np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def _cylinder_points(cyl, n: int = 64) -> np.ndarray:
    """Points on the rims of a cylinder's two end discs: the convex hull of their image is the cylinder's outline."""
    from gonio.geometry import frame_from_normal

    a = cyl.a
    f = frame_from_normal(a)
    t = 2.0 * np.pi * np.arange(n) / n
    ring = cyl.radius * (np.cos(t)[:, None] * f[0] + np.sin(t)[:, None] * f[1])
    return np.concatenate([cyl.P + 0.5 * cyl.length * a + ring, cyl.P - 0.5 * cyl.length * a + ring])


def cover_points(layout) -> list[np.ndarray]:
    """The parts of ``layout`` that lie on the board, each as points (sample frame, m) whose image's convex hull is
    what it hides: the white reference patch's corners, and the curved sample (sphere, cylinder) or else the flat
    sample patch's corners through its mount (the calibration tile is the calibration layout's sample patch)."""
    out = [layout.white.corners()]
    if layout.sphere is not None:
        out.append(_sphere_points(layout.sphere.centre, layout.sphere.radius))
    elif layout.cylinder is not None:
        out.append(_cylinder_points(layout.cylinder))
    else:
        out.append(layout.sample_corners())
    return out


def _hull_distance(points: np.ndarray, hull: np.ndarray) -> np.ndarray:
    """Distance (px) of ``points`` (n, 2) from the convex polygon ``hull`` (k, 2, counter-clockwise or clockwise):
    0 inside, else the distance to the nearest edge (point–segment distance, vectorized over points × edges)."""
    a = hull
    b = np.roll(hull, -1, axis=0)
    e = b - a  # (k, 2)
    d = points[:, None, :] - a[None, :, :]  # (n, k, 2)
    cross = e[None, :, 0] * d[..., 1] - e[None, :, 1] * d[..., 0]
    inside = np.all(cross >= 0, axis=1) | np.all(cross <= 0, axis=1)
    t = np.clip(np.einsum("nkj,kj->nk", d, e) / np.maximum(np.einsum("kj,kj->k", e, e), 1e-300), 0.0, 1.0)
    dist = np.linalg.norm(d - t[..., None] * e[None], axis=2).min(axis=1)
    return np.where(inside, 0.0, dist)


def pose_projector(rvec, tvec, calib):
    """Board-frame points (k, 3) → pixels (k, 2) through the board pose ``(rvec, tvec)`` and ``calib``
    (``cv2.projectPoints``); None for points partly behind the camera (no image outline: not a view the rig takes)."""
    import cv2

    rvec = np.asarray(rvec, dtype=np.float64).reshape(3, 1)
    tvec = np.asarray(tvec, dtype=np.float64).reshape(3, 1)
    R_cb, _ = cv2.Rodrigues(rvec)

    def project(p):
        p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        if not np.all(p @ R_cb[2] + float(tvec[2, 0]) > 0):
            return None
        return cv2.projectPoints(p, rvec, tvec, calib.K, calib.dist)[0].reshape(-1, 2)

    return project


def plane_projector(obj, img):
    """Board-frame points (k, 3) → pixels (k, 2) by the homography of the board plane onto the image that the
    corners ``obj`` (board frame) ↔ ``img`` (pixels) define (least squares, Hartley & Zisserman §4.1; z dropped, the
    lens's distortion left out — it moves an outline by a fraction of a corner window), for views without a camera
    model (intrinsic calibration); None when the corners define no homography (fewer than 4, degenerate)."""
    import cv2

    obj = np.asarray(obj, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(img, dtype=np.float64).reshape(-1, 2)
    if len(obj) < 4:
        return None
    H, _ = cv2.findHomography(obj[:, :2], img, 0)
    if H is None or not np.all(np.isfinite(H)):
        return None

    def project(p):
        p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
        return cv2.perspectiveTransform(np.ascontiguousarray(p[:, :2]).reshape(-1, 1, 2), H).reshape(-1, 2)

    return project


def corner_windows(obj, project, spec) -> np.ndarray | None:
    """OpenCV's ChArUco corner-finder window half-sizes (px, (n,)) of the board corners ``obj`` (board frame,
    (n, 3) m) seen through ``project`` (:func:`pose_projector`, :func:`plane_projector`) (its
    ``getMaximumSubPixWindowSizes``): ``d − 2`` clipped to [1, :data:`MAX_WINDOW_PX`] (OpenCV truncates it to an
    integer: the floor of this), ``d`` the distance to the nearest corner of the neighbouring markers, here the
    nearest of the four points ``(±δ, ±δ)`` from the corner, ``δ = (square − marker)/2``, all projected; None when
    ``project`` gives none."""
    obj = np.asarray(obj, dtype=np.float64).reshape(-1, 3)
    n = len(obj)
    delta = 0.5 * (spec.square_length - spec.marker_length)
    offs = np.array([[delta, delta, 0.0], [-delta, delta, 0.0], [delta, -delta, 0.0], [-delta, -delta, 0.0]])
    p = project(np.concatenate([obj] + [obj + o for o in offs]))
    if p is None:
        return None
    p = p.reshape(5, n, 2)
    d = np.linalg.norm(p[1:] - p[0][None], axis=2).min(axis=0)
    return np.clip(d - 2.0, 1.0, MAX_WINDOW_PX)


def cover_hulls(project, spec, covers) -> list[np.ndarray]:
    """The image outlines (convex hulls, (k, 2) px) of ``covers`` (point sets in the sample frame,
    :func:`cover_points`) seen through ``project``; a cover it cannot project has none."""
    import cv2

    hulls = []
    for cover in covers or ():
        q = project(spec.sample_to_board(np.asarray(cover, dtype=np.float64).reshape(-1, 3)))
        if q is None:
            continue
        hull = cv2.convexHull(np.asarray(q, dtype=np.float32).reshape(-1, 2)).reshape(-1, 2).astype(np.float64)
        if len(hull) >= 3:
            hulls.append(hull)
    return hulls


def near_hulls(points, hulls, reach) -> np.ndarray:
    """Which image points (n, 2) lie within ``reach`` px (scalar or (n,)) of one of ``hulls``: a mask (n,)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    near = np.zeros(len(points), dtype=bool)
    for hull in hulls:
        near |= _hull_distance(points, hull) < reach
    return near


def covered_by(obj, project, spec, covers, img=None) -> np.ndarray:
    """Which board corners ``obj`` (board frame, (n, 3) m) a cover reaches, seen through ``project``: a boolean
    mask (n,). ``covers``: point sets in the sample frame (:func:`cover_points`).

    A corner is covered when its corner finder's window (:func:`corner_windows`; a square window of half-size
    ``w`` reaches ``√2 w``), plus :data:`COVER_MARGIN_PX` of blur, touches the image of a cover (the convex hull
    of its projected points, :func:`cover_hulls`). ``img``: the corners' image points (n, 2); default their
    projection."""
    obj = np.asarray(obj, dtype=np.float64).reshape(-1, 3)
    n = len(obj)
    if n == 0 or not covers or project is None:
        return np.zeros(n, dtype=bool)
    win = corner_windows(obj, project, spec)
    if win is None:
        return np.zeros(n, dtype=bool)
    centre = project(obj) if img is None else np.asarray(img, dtype=np.float64).reshape(n, 2)
    return near_hulls(centre, cover_hulls(project, spec, covers), np.sqrt(2.0) * win + COVER_MARGIN_PX)


def covered_corners(obj, rvec, tvec, calib, spec, covers, img=None) -> np.ndarray:
    """:func:`covered_by` with the board pose ``(rvec, tvec)`` and ``calib`` (:func:`pose_projector`)."""
    return covered_by(obj, pose_projector(rvec, tvec, calib), spec, covers, img)


def covered_in_plane(obj, img, spec, covers) -> np.ndarray:
    """:func:`covered_by` without a camera model (intrinsic calibration): through the board plane's homography onto
    the image that the corners ``obj`` ↔ ``img`` define (:func:`plane_projector`), the covers by their footprint
    on the board (a sphere's or a raised sample's outline seen obliquely reaches further)."""
    return covered_by(obj, plane_projector(obj, img), spec, covers, img)
