"""Opening a camera that does not exist: one typed error, no OpenCV log lines on the process's stderr."""

from __future__ import annotations

import cv2
import pytest

from gonio.errors import HardwareError
from gonio.rig.camera import OpenCVCamera
from sim.clock import SimClock


def test_an_index_that_cannot_exist_raises_without_opencv_noise_and_restores_the_log_level(capfd):
    before = cv2.utils.logging.getLogLevel()
    with pytest.raises(HardwareError, match="camera 97: cannot open"):
        OpenCVCamera(97, SimClock())  # V4L2 index 97: no such /dev/video97 here
    out, err = capfd.readouterr()
    assert "WARN" not in err and "VIDEOIO" not in err, err
    assert cv2.utils.logging.getLogLevel() == before  # scoped to the opening, not the process
