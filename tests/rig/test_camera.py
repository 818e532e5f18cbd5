"""OpenCVCamera without a camera (none exists on CI machines): a stand-in for ``cv2.VideoCapture``
(OpenCV's object, not our code) that can block, count grabs and wait for a hardware trigger."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from gonio.errors import ConfigError, HardwareError, HardwareTimeout
from gonio.rig.calibration import LINEARIZED_BIT_DEPTH, CameraSettings, ResponseCurve
from gonio.rig.camera import OpenCVCamera, open_camera
from sim.clock import SimClock


class FakeCapture:
    """Behaves like a V4L2 ``VideoCapture``: settable properties, ``grab``/``read`` that may block."""

    def __init__(self, value=100, shape=(4, 6, 3), triggered: threading.Event | None = None):
        self.props: dict[int, float] = {}
        self.value, self.shape = value, shape
        self.grabs = self.reads = 0
        self.release_gate = threading.Event()
        self.block = False
        self.triggered = triggered
        self.released = False

    def set(self, prop, value):
        self.props[prop] = value
        return True

    def get(self, prop):
        return self.props.get(prop, 0.0)

    def grab(self):
        self.grabs += 1
        return True

    def read(self):
        self.reads += 1
        if self.block:
            self.release_gate.wait(5.0)
        if self.triggered is not None and not self.triggered.wait(5.0):
            return False, None
        img = np.zeros(self.shape, np.uint8)
        img[..., 0], img[..., 2] = self.value, 255 - self.value  # BGR
        return True, img

    def release(self):
        self.released = True

    def getBackendName(self):
        return "FAKE"


def test_frames_are_rgb_with_the_declared_encoding():
    cap = FakeCapture(value=10)
    cam = OpenCVCamera("fake", SimClock(), capture=cap, linear=True, bit_depth=8, black_level=4.0)
    f = cam.capture(0.01)
    assert f.pixels[0, 0].tolist() == [245, 0, 10] and f.linear and f.black_level == 4.0
    assert f.exposure == pytest.approx(0.01) and cap.grabs == 2 and cap.reads == 1


def test_capture_honours_its_timeout_and_the_camera_stays_usable():
    cap = FakeCapture()
    cam = OpenCVCamera("fake", SimClock(), capture=cap, linear=True)
    cap.block = True
    t0 = time.monotonic()
    with pytest.raises(HardwareTimeout, match="no frame within 0.2 s"):
        cam.capture(0.01, timeout=0.2)
    assert time.monotonic() - t0 < 2.0
    with pytest.raises(HardwareTimeout, match="still blocked"):  # the driver still holds the read
        cam.capture(0.01, timeout=0.1)
    cap.block = False
    cap.release_gate.set()
    f = cam.capture(0.01, timeout=2.0)
    assert f.pixels.shape == (4, 6, 3)
    cam.close()
    assert cap.released


def test_failed_read_and_rejected_exposure_are_hardware_errors():
    cap = FakeCapture()
    cap.read = lambda: (False, None)
    cam = OpenCVCamera("fake", SimClock(), capture=cap, linear=True)
    with pytest.raises(HardwareError, match="read failed"):
        cam.capture(0.01)
    cap2 = FakeCapture()
    cap2.get = lambda prop: 3.0  # the driver ignores the exposure request
    with pytest.raises(HardwareError, match="not accepted"):
        OpenCVCamera("fake", SimClock(), capture=cap2, linear=True).capture(0.05)
    with pytest.raises(ConfigError, match="camera.timeout"):
        OpenCVCamera("fake", SimClock(), capture=FakeCapture(), linear=True).capture(0.01, timeout=0)


def test_hardware_trigger_fires_each_exposure_without_flushing():
    fired = threading.Event()
    pulses = []
    cap = FakeCapture(triggered=fired)

    def trigger(exposure):
        pulses.append(exposure)
        fired.set()

    cam = OpenCVCamera("fake", SimClock(), capture=cap, linear=True, trigger=trigger)
    f = cam.capture(0.02, timeout=2.0)
    assert pulses == [pytest.approx(0.02)] and cap.grabs == 0 and f.meta["trigger"] == "hardware"
    fired.clear()
    cam.trigger = lambda exposure: None  # a trigger that never reaches the camera: a timeout, not a hang
    with pytest.raises(HardwareTimeout):
        cam.capture(0.02, timeout=0.2)


def test_response_curve_linearizes_frames():
    v = np.arange(256)
    curve = ResponseCurve(inverse=(v / 255.0) ** 2.2)
    settings = CameraSettings(linear=False, bit_depth=8, response=curve)
    cam = open_camera("fake", settings, SimClock(), capture=FakeCapture(value=128))
    f = cam.capture(0.01)
    assert f.linear and f.bit_depth == LINEARIZED_BIT_DEPTH and f.pixels.dtype == np.uint16
    assert f.pixels[0, 0, 2] == round(65535 * (128 / 255) ** 2.2)
    assert f.pixels[0, 0, 0] == round(65535 * (127 / 255) ** 2.2)
    with pytest.raises(ConfigError, match="non-linear 8-bit"):
        OpenCVCamera("fake", SimClock(), capture=FakeCapture(), linear=True, response=curve)


def test_missing_device_is_a_hardware_error():
    with pytest.raises(HardwareError, match="cannot open"):
        OpenCVCamera("/nonexistent/video9", SimClock())
