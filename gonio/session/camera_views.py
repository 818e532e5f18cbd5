"""The views ``gonio camera calibrate`` takes on the rig: the camera arm carries the camera around the ChArUco
board on the stage (as the geometric calibration's camera poses do, :func:`gonio.rig.geocal.calibration_plan`),
so the board is seen tilted about every axis, at several distances across the image; or the frames come from
image files (a board moved by hand in front of a fixed camera).

* :func:`view_plan`: the camera arm at signed elevations 10°–60° (10° steps) × 12 azimuths (the light parked on
  the far side), every pose inside the rig's joint limits and collision zones (144 on the shipped rig: the
  principal point's σ falls as 1/√views, ~0.1 px here with radial distortion only);
* :func:`capture_views`: move, check the E-stop and interlock before every move (as the session runner does),
  take a metered frame (:func:`gonio.session.geocal_observe.metered_board_frame`) and find the board's corners
  (:func:`gonio.pipeline.intrinsics.detect_view`);
* :func:`views_from_files`: the same detection on image files (8/16-bit PNG, TIFF, JPEG or ``.npy``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gonio.errors import ConfigError, DataError, EmergencyStop

__all__ = ["view_plan", "capture_views", "views_from_files"]

#: Camera-arm elevations (degrees, signed: past the pole is the other side) and azimuths of :func:`view_plan`.
ELEVATIONS_DEG = (-60.0, -50.0, -40.0, -30.0, -20.0, -10.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
AZIMUTHS_DEG = tuple(float(a) for a in range(-165, 180, 30))


def view_plan(rig) -> np.ndarray:
    """Joint angles (rad, ``rig.names`` order) of the calibration views (module docstring)."""
    if rig.layout != "arms":
        raise ConfigError.field(rig.source, "layout", rig.layout, "camera views on the rig need the 'arms' layout "
                                "(or give image files: --images)")
    rows = []
    for a in AZIMUTHS_DEG:
        for e in ELEVATIONS_DEG:
            pose = {"light_az": 0.0, "light_el": 70.0 if e < 0 else -70.0, "camera_az": a, "camera_el": e}
            rows.append([math.radians(pose[n]) for n in rig.names])
    j = np.array(rows)
    wi, wo = rig.directions(j)
    ok = np.all((j >= rig.lower) & (j <= rig.upper), axis=-1) & (rig.check_directions(wi, wo) == 0)
    return j[ok]


def _clear(controller) -> None:
    what = controller.status().stop_reason
    if what:
        raise EmergencyStop(f"rig controller: {what}: the camera views stopped (nothing more was sent to the servos)",
                            device="rig controller")


def capture_views(devices, spec, plan: np.ndarray, *, exposure: float = 0.005, gain: float = 1.0,
                  on_view=None, covers=None) -> tuple[list, list[tuple[int, str]]]:
    """Move to every pose of ``plan`` on ``devices`` (:class:`gonio.session.runner.Devices`), light on, and detect
    the board: ``(views, refused)`` — :class:`gonio.pipeline.intrinsics.CharucoView` per pose where the board
    was found, and ``(pose index, why)`` where not. ``on_view(k, n, view_or_None)`` reports progress. ``covers``:
    what lies on the board on the stage (:func:`gonio.pipeline.covers.cover_points` of the target), whose corners
    are left out."""
    from gonio.pipeline.intrinsics import detect_view
    from gonio.pipeline.markers import to_gray8
    from gonio.session.geocal_observe import metered_board_frame

    rig, ctl = devices.rig, devices.controller
    _clear(ctl)
    ctl.set_light(True, 1.0)
    views, refused = [], []
    board = spec.board()
    try:
        for k, j in enumerate(plan):
            _clear(ctl)
            devices.axes.move_to(rig.as_dict(j))
            devices.clock.sleep(0.3)  # settle
            f = metered_board_frame(devices.camera, exposure, gain)
            view = detect_view(to_gray8(f.pixels, f.bit_depth, f.black_level), spec, board=board, covers=covers,
                               source=f"pose {k} ({', '.join(f'{math.degrees(a):.0f}' for a in j)} deg)")
            if view is None:
                refused.append((k, "ChArUco board not found"))
            else:
                views.append(view)
            if on_view is not None:
                on_view(k, len(plan), view)
    finally:
        ctl.set_light(False)
    return views, refused


def _read_image(path: Path) -> np.ndarray:
    if not path.is_file():
        raise ConfigError.field("--images", "images", str(path), "no such file")
    if path.suffix.lower() == ".npy":
        try:
            img = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise DataError(f"{path}: not a .npy image ({exc})") from None
    else:
        import cv2

        from gonio.rig.camera import _quiet_opencv

        with _quiet_opencv(cv2):  # its own warning would repeat the line below
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise DataError(f"{path}: cannot be read as an image (PNG, TIFF, JPEG, BMP or .npy)")
        if img.ndim == 3:
            img = img[..., :3][..., ::-1]  # BGR(A) -> RGB
    if img.ndim not in (2, 3) or img.dtype.kind not in "ui" or min(img.shape[:2]) < 16:
        raise DataError(f"{path}: shape {img.shape} dtype {img.dtype}: expected an 8- or 16-bit grey or RGB image")
    return img


def views_from_files(paths, spec, covers=None) -> tuple[list, list[tuple[str, str]], tuple[int, int]]:
    """``(views, refused, (width, height))`` from image files (module docstring); every image the same size.
    ``covers``: as :func:`capture_views`'s."""
    from gonio.pipeline.intrinsics import detect_view
    from gonio.pipeline.markers import to_gray8

    views, refused, size = [], [], None
    board = spec.board()
    for p in map(Path, paths):
        img = _read_image(p)
        if size is None:
            size = (img.shape[1], img.shape[0])
        elif (img.shape[1], img.shape[0]) != size:
            raise DataError(f"{p}: {img.shape[1]}x{img.shape[0]} pixels, the first image {size[0]}x{size[1]}: one camera, "
                            "one size")
        bits = 8 if img.dtype == np.uint8 else 16
        view = detect_view(to_gray8(img, bits), spec, board=board, source=str(p), covers=covers)
        if view is None:
            refused.append((str(p), "ChArUco board not found"))
        else:
            views.append(view)
    if size is None:
        raise ConfigError.field("--images", "images", "", "no image files given")
    return views, refused, size
