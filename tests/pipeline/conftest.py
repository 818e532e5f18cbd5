"""A simulated camera + light on a sample, placed directly (the rig wiring comes later in sim/rig.py)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.geometry import from_spherical
from gonio.pipeline.acquire import Pipeline, PipelineSettings
from gonio.pipeline.target import CameraCalibration, CameraPose, TargetLayout
from sim.camera import SceneLight, SensorModel, SimCamera, SimScene
from sim.clock import SimClock

WIDTH, HEIGHT, FOCAL = 640, 480, 900.0


class Bench:
    """Camera, light and pipeline around one material."""

    def __init__(self, material, *, sensor=None, seed=0, drift=0.0, tau=300.0, intensity=1.0, transform=None,
                 settings=None, absolute_scale=None, layout=None):
        self.sensor = sensor or SensorModel()
        self.calib = CameraCalibration.pinhole(WIDTH, HEIGHT, FOCAL, noise=self.sensor.noise_model())
        self.layout = layout or TargetLayout()
        self.material = material
        self.clock = SimClock()
        self.light = SceneLight(self.clock, drift=drift, tau=tau)
        self.scene = SimScene(self.layout, material, light_intensity=intensity, sample_transform=transform)
        self.camera = SimCamera(self.calib, self.sensor, self.scene, seed=seed, clock=self.clock,
                                light_output=self.light.output)
        self.pipeline = Pipeline(self.camera, self.calib, self.layout, light=self.light, clock=self.clock,
                                 settings=settings, absolute_scale=absolute_scale)

    def place(self, theta_o, phi_o, theta_i, phi_i, r_cam=0.6, r_light=0.8):
        """Camera and light at spherical positions (degrees) around the sample centre."""
        eye = r_cam * from_spherical(np.radians(theta_o), np.radians(phi_o))
        pose = CameraPose.look_at(eye)
        light = r_light * from_spherical(np.radians(theta_i), np.radians(phi_i))
        self.camera.set_pose(pose)
        self.camera.set_light(light)
        return pose, light

    def measure(self, theta_o, phi_o, theta_i, phi_i, index=-1, **kw):
        pose, light = self.place(theta_o, phi_o, theta_i, phi_i)
        return self.pipeline.measure(light, pose_index=index, **kw)


@pytest.fixture
def lambert():
    return make("lambert", albedo=[0.6, 0.45, 0.3])


@pytest.fixture
def bench_factory():
    return Bench
