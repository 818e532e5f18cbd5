"""``gonio camera info|capture|response --sim``: the lab-bench camera commands on the rendering camera.

Response recovery tolerance (stated): the recovered inverse response of the simulated 8-bit camera
(y = 255 x^(1/2.2)) matches (v/255)^2.2 within 8 % (max over channels) for 8-bit values 20..255
(measured ~5 %; below ~20 the bracket holds few, noisy samples), and frames linearized through it
are proportional to exposure within 3 % (median ratio of doubled exposures).
"""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.errors import ConfigError
from gonio.pipeline.acquire import Pipeline
from gonio.pipeline.hdr import BadFrame
from gonio.pipeline.target import CameraCalibration, TargetLayout
from gonio.rig.calibration import LinearizedCamera, ResponseCurve
from sim.camera import SensorModel, SimCamera, SimScene

BRACKET = "0.00025,0.0005,0.001,0.002,0.004,0.008,0.016,0.032"


@pytest.fixture(scope="module")
def recovered(tmp_path_factory):
    out = tmp_path_factory.mktemp("resp") / "response.npz"
    assert main(["camera", "response", "--sim", "--exposures", BRACKET, "-o", str(out)]) == 0
    return ResponseCurve.load(out)


def _sim_camera(seed=3):
    calib = CameraCalibration.pinhole(320, 240, 380.0)
    sensor = SensorModel(bit_depth=8, linear=False)
    scene = SimScene(layout=TargetLayout(), material=make("lambert", albedo=(0.5, 0.5, 0.5)))
    return SimCamera(calib, sensor, scene, seed=seed), calib


def test_response_recovers_the_simulated_gamma(recovered):
    v = np.arange(256)
    truth = (v / 255.0) ** 2.2
    m = v >= 20
    rel = np.abs(recovered.inverse[m] / truth[m, None] - 1.0)
    assert recovered.inverse.shape == (256, 3) and rel.max() < 0.08
    assert len(recovered.exposures) == 8 and recovered.exposures[0] == pytest.approx(0.00025)
    assert np.all(np.diff(recovered.inverse, axis=0) >= 0)


def test_frames_through_the_recovered_curve_are_linear_and_accepted(recovered):
    raw_cam, calib = _sim_camera()
    cam = LinearizedCamera(raw_cam, recovered)
    t = 0.002
    raw = [raw_cam.capture(t * k).pixels for k in (1, 2, 4)]
    lin = [cam.capture(t * k) for k in (1, 2, 4)]
    assert all(f.linear and f.bit_depth == 16 and f.pixels.dtype == np.uint16 for f in lin)
    for a in range(2):  # exposure doubled: the linear value doubles where neither frame is clipped/dark
        ok = (raw[a] >= 20) & (raw[a + 1] <= 245)
        ratio = (lin[a + 1].pixels[ok] - lin[a + 1].black_level) / (lin[a].pixels[ok] - lin[a].black_level)
        assert ok.sum() > 10000 and abs(np.median(ratio) - 2.0) < 0.06
    # the session's pipeline takes the linearized frames and still refuses the raw ones
    pipe = Pipeline(cam, calib, TargetLayout())
    frame, px, _, _ = pipe._grab(0.004, 1.0)
    assert frame.linear and px.shape == (240, 320, 3)
    with pytest.raises(BadFrame, match="linear = False"):
        Pipeline(raw_cam, calib, TargetLayout())._grab(0.004, 1.0)


def test_capture_writes_raw_png_and_npy(tmp_path, capsys):
    import cv2

    png, npy = tmp_path / "f.png", tmp_path / "f.npy"
    assert main(["camera", "capture", "--sim", "--sim-bit-depth", "12", "--exposure", "0.004", "-o", str(png)]) == 0
    assert main(["camera", "capture", "--sim", "--sim-bit-depth", "12", "--exposure", "0.004", "-o", str(npy)]) == 0
    out = capsys.readouterr().out
    assert "320x240 uint16 (12-bit, linear), exposure 0.004 s" in out
    a = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)[..., ::-1]
    b = np.load(npy, allow_pickle=False)
    assert a.dtype == np.uint16 and np.array_equal(a, b) and 0 < b.max() <= 4095  # same seed: same frame


def test_info_and_command_errors(tmp_path, capsys):
    assert main(["camera", "info", "--sim"]) == 0
    out = capsys.readouterr().out
    assert "width            320" in out and "no (8-bit, gamma 2.2)" in out
    for argv, expect in [
        (["camera", "capture", "--sim", "--exposure", "0.004", "-o", str(tmp_path / "f.jpg")], "must end in .png or .npy"),
        (["camera", "response", "--sim", "--exposures", "0.001,0.002", "-o", str(tmp_path / "r.npz")], "at least 3"),
        (["camera", "response", "--sim", "--exposures", "0.001,x,0.004", "-o", str(tmp_path / "r.npz")], "'x'"),
        (["camera", "response", "--sim", "--exposures", "0.00001,0.00002,0.00003", "-o", str(tmp_path / "r.npz")],
         "widen the bracket"),
        (["camera", "response", "--sim", "--sim-bit-depth", "12", "--exposures", BRACKET, "-o", str(tmp_path / "r.npz")],
         "linear = true"),
    ]:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert expect in err and "\n" not in err, (argv, err)
    with pytest.raises(ConfigError):
        ResponseCurve.load(tmp_path / "r.npz")  # nothing was written by the failed runs
