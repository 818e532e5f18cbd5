"""Hand-held ChArUco views for camera calibration: the simulated camera (with the intrinsics and distortion it is
given, which the host does not know) looking at the board from many directions — tilted about both axes, the
board placed all over the image, near the corners too — as a person waving a board in front of a fixed camera
would give. The frames go to image files for ``gonio camera calibrate --images`` (tests, benchmarks).

Poses: a board point within ±``spread`` of its centre is looked at from ``distance`` metres, from a direction
``tilt`` off the board's normal (uniform in [10°, ``max_tilt``], any azimuth); the camera is then turned
(pan and tilt within ±``offset`` of the half field of view) so the board lands off-centre, and rolled about its
axis at random.
"""

from __future__ import annotations

import math

import numpy as np

from gonio.brdf import make
from gonio.pipeline.target import CameraCalibration, CameraPose, TargetLayout
from sim.camera import SensorModel, SimCamera, SimScene
from sim.clock import SimClock

__all__ = ["handheld_poses", "render_handheld_views"]


def _rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def handheld_poses(calibration: CameraCalibration, n: int, *, seed: int = 0, distance=(0.35, 0.5),
                   max_tilt_deg: float = 45.0, spread: float = 0.05, offset: float = 0.55) -> list[CameraPose]:
    """``n`` camera poses (world = the board's sample frame) as the module docstring describes."""
    rng = np.random.default_rng(seed)
    half_fov_x = math.atan(calibration.width / 2 / calibration.K[0, 0])
    half_fov_y = math.atan(calibration.height / 2 / calibration.K[1, 1])
    poses = []
    for _ in range(n):
        target = np.array([*rng.uniform(-spread, spread, 2), 0.0])
        tilt = math.radians(rng.uniform(10.0, max_tilt_deg))
        az = rng.uniform(0, 2 * math.pi)
        eye = target + rng.uniform(*distance) * np.array([math.sin(tilt) * math.cos(az),
                                                          math.sin(tilt) * math.sin(az), math.cos(tilt)])
        base = CameraPose.look_at(eye, target, up=(math.cos(az + 1.3), math.sin(az + 1.3), 0.0))
        turn = (_rot("y", rng.uniform(-offset, offset) * half_fov_x) @ _rot("x", rng.uniform(-offset, offset) * half_fov_y)
                @ _rot("z", rng.uniform(-math.pi, math.pi)))
        R = turn.T @ base.R  # the camera turned: the board seen off-centre and rolled
        poses.append(CameraPose(R, -R @ eye))
    return poses


def render_handheld_views(calibration: CameraCalibration, n: int, *, seed: int = 0, bit_depth: int = 12,
                          **pose_kw) -> list[np.ndarray]:
    """Rendered frames (uint16 or uint8 arrays) of :func:`handheld_poses`, each exposed so the board's white
    squares reach ~60 % of the range; lit from above the camera."""
    sensor = SensorModel(bit_depth=bit_depth)
    scene = SimScene(layout=TargetLayout(), material=make("lambert", albedo=(0.5, 0.5, 0.5)))
    cam = SimCamera(calibration, sensor, scene, seed=seed, clock=SimClock())
    frames = []
    for pose in handheld_poses(calibration, n, seed=seed, **pose_kw):
        cam.set_pose(pose)
        cam.set_light(pose.centre + np.array([0.0, 0.0, 0.3]))
        f = cam.capture(0.005)
        p99 = float(np.percentile(f.pixels[::2, ::2], 99.0)) - f.black_level
        full = sensor.saturation - f.black_level
        t = float(np.clip(0.005 * 0.6 * full / max(p99, 1.0), sensor.min_exposure, sensor.max_exposure))
        frames.append(cam.capture(t).pixels)
    return frames
