"""Every frame from a GenICam camera is validated before use (gonio.rig.aravis): a zero-size frame (Width set
to 0 mid-session) or one of another size is a one-line HardwareError naming the camera and the field after
the retries — it used to come back as a (48, 0, 3) array, a ValueError further on — and a bad frame that the
camera corrects is retried. Against Aravis's fake GigE Vision camera (the arv-fake-gv-camera-0.8 device and
sim.gige_camera's rendering one): registers, trigger and GVSP are real."""

from __future__ import annotations

import pytest

from gonio.cli.main import main
from gonio.errors import HardwareError
from tests.rig.test_aravis import ARGS, _Clock, _Known, aravis, fake_camera, gige_lock  # noqa: F401 (fixtures)

def _open(device, **kw):
    from gonio.rig.aravis import AravisCamera

    return AravisCamera(device, _Clock(), pixel_format="RGB8", gain_unit="raw", width=64, height=48, **kw)


@pytest.mark.parametrize("width", [0, 32])
def test_a_frame_of_another_size_is_one_hardware_error_naming_the_field(aravis, width):
    from sim.gige_camera import GigECameraServer

    with gige_lock(), GigECameraServer(_Known(), serial="GONIO-W") as server:
        cam = _open(server.device)
        try:
            assert cam.capture(0.001, 1.0, timeout=5).pixels.shape == (48, 64, 3)
            cam._cam.get_device().set_integer_feature_value("Width", width)  # the camera changes under us
            with pytest.raises(HardwareError) as err:
                cam.capture(0.001, 1.0, timeout=5)
        finally:
            cam.close()
    msg = str(err.value)
    assert "\n" not in msg and "gige://127.0.0.1" in msg and f"frame width = {width}: expected 64" in msg
    assert "3 times" in msg and cam.incomplete == 3  # retried before it was reported


def test_a_bad_frame_the_camera_corrects_is_retried(aravis):
    """The camera's region is wrong for a while (another thread puts it back once the first bad frame was seen):
    the capture retries and returns the frame of the configured size."""
    import threading
    import time

    from sim.gige_camera import GigECameraServer

    with gige_lock(), GigECameraServer(_Known(), serial="GONIO-R") as server:
        cam = _open(server.device, retries=200)
        dev = cam._cam.get_device()

        def put_back():
            t0 = time.monotonic()
            while cam.incomplete == 0 and time.monotonic() - t0 < 20:
                time.sleep(0.001)
            dev.set_integer_feature_value("Width", 64)

        try:
            assert cam.capture(0.001, 1.0, timeout=5).pixels.shape == (48, 64, 3)
            dev.set_integer_feature_value("Width", 32)
            fixer = threading.Thread(target=put_back)
            fixer.start()
            frame = cam.capture(0.001, 1.0, timeout=20)
            fixer.join()
        finally:
            cam.close()
    assert frame.pixels.shape == (48, 64, 3) and 1 <= cam.incomplete < 200


def test_the_fake_camera_at_zero_width_through_the_cli_is_one_line(fake_camera, tmp_path, capsys):
    """Aravis's own fake camera (arv-fake-gv-camera-0.8): its Width at 0 before a capture (what another program
    or a camera reset can do) is one line and exit code 3, no traceback, no file."""
    from gonio.rig.aravis import AravisCamera

    cam = AravisCamera(fake_camera, _Clock(), pixel_format="Mono8", gain_unit="raw", width=64, height=48)
    try:
        cam._cam.get_device().set_integer_feature_value("Width", 0)
        with pytest.raises(HardwareError, match=r"frame width = 0: expected 64"):
            cam.capture(0.001, 1.0, timeout=5)
    finally:
        cam.close()
    # the CLI opens the camera afresh (its region is set again): a frame of the size asked comes back
    assert main(["camera", "capture", "--camera", fake_camera, *ARGS, "--pixel-format", "Mono8", "--exposure", "0.001",
                 "-o", str(tmp_path / "f.npy")]) == 0


class _SlowFirst(_Known):
    """A renderer whose first frame takes 3 s (the simulated camera's first frame compiles its kernels)."""

    def capture(self, exposure, gain=1.0, *, timeout=10.0):
        if not self.asked:
            import time

            time.sleep(3.0)
        return super().capture(exposure, gain)


def test_a_slow_frame_does_not_lose_the_simulated_camera(aravis):
    """The rendering GigE camera renders inside the fake device's fill callback, which holds its registers: a
    first frame of 3 s left the host's heartbeats unanswered past the device's 3 s heartbeat timeout, the device
    dropped its controller and never sent another frame ('no frame within 10 s' in 2 of 3 `gonio measure --sim
    --sim-camera gige` runs on a loaded machine). The server gives the device a longer heartbeat timeout."""
    from sim.gige_camera import GigECameraServer

    with gige_lock(), GigECameraServer(_SlowFirst(), serial="GONIO-SLOW") as server:
        cam = _open(server.device)
        try:
            shapes = [cam.capture(0.001, 1.0, timeout=8).pixels.shape for _ in range(3)]
        finally:
            cam.close()
    assert shapes == [(48, 64, 3)] * 3
