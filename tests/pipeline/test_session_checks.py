"""Checks the session runner makes through the pipeline at session start, on the simulated rig."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.errors import ConfigError
from gonio.pipeline.target import CameraCalibration
from gonio.plan.plan import CaptureSettings, Plan
from gonio.session.runner import SessionRunner
from gonio.session.store import SessionStore
from sim.rig import SimRig, SimRigConfig


def test_frame_size_other_than_the_calibration_is_a_one_line_config_error(tmp_path):
    # the camera delivers 160x120 frames, the pipeline is calibrated for 320x240
    plan = Plan(poses=np.radians([[30.0, 0, 30, 180]]), capture=CaptureSettings(), generator="custom")
    with SimRig(config=SimRigConfig(width=160, height=120, focal_px=190.0)) as sim:
        devices = sim.open_devices()
        try:
            calib = CameraCalibration.pinhole(320, 240, 380.0, noise=sim.calibration.noise)
            store = SessionStore.create(tmp_path / "s", {"plan": plan, "mode": "test"})
            runner = SessionRunner(plan, store, devices, calib, sim.layout, stream=None)
            with pytest.raises(ConfigError) as err:
                runner.run()
        finally:
            devices.close()
    msg = str(err.value)
    assert "\n" not in msg and "160x120" in msg and "320x240" in msg, msg
    manifest = json.loads((tmp_path / "s" / "manifest.json").read_text())
    assert manifest["exit_status"].startswith("error") and manifest["sample_count"] == 0
