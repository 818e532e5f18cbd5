"""GenICam cameras through Aravis, against Aravis's fake GigE Vision camera on the loopback interface
(``arv-fake-gv-camera-0.8``, Debian aravis-tools) and gonio's rendering GigE camera (sim.gige_camera):
discovery, GenICam registers, software trigger and the GVSP stream are real.

Only one GigE Vision device can listen on 127.0.0.1's control port at a time: the fixtures take a
file lock, so parallel test workers wait for each other instead of colliding.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import shutil
import subprocess
from gonio import childproc  # children die with this process
import time

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.errors import ConfigError, HardwareError
from gonio.rig.aravis import PIXEL_FORMATS, demosaic
from gonio.rig.interfaces import Frame
from tests.debian import require


@pytest.fixture
def aravis():
    """Aravis through PyGObject: skipped naming what is missing (a failure under .ci/run)."""
    require("GenICam cameras through Aravis", "gir1.2-aravis-0.8", python=("gi", "gonio[genicam]"))


@contextlib.contextmanager
def gige_lock():
    with open("/tmp/gonio-test-gige.lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


@pytest.fixture
def fake_camera(aravis):
    """Aravis's fake GigE Vision camera on 127.0.0.1, started and stopped here."""
    require("Aravis's fake GigE Vision camera", "aravis-tools")
    with gige_lock():
        proc = childproc.popen([shutil.which("arv-fake-gv-camera-0.8"), "-i", "127.0.0.1", "-s", "GONIOTEST"], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        try:
            from gonio.rig.aravis import list_devices

            for _ in range(50):  # it answers discovery within a few hundred ms
                if any(d["id"] == "Aravis-Fake-GONIOTEST" for d in list_devices()):
                    break
                time.sleep(0.1)
            else:
                pytest.fail("the fake GigE Vision camera did not answer discovery within 5 s")
            yield "Aravis-Fake-GONIOTEST"
        finally:
            proc.terminate()
            proc.wait(timeout=10)


ARGS = ["--backend", "aravis", "--gain-unit", "raw"]


def test_list_info_and_capture_through_the_cli(fake_camera, tmp_path, capsys):
    assert main(["camera", "list"]) == 0
    assert "Aravis-Fake-GONIOTEST" in capsys.readouterr().out
    assert main(["camera", "info", "--camera", fake_camera, *ARGS]) == 0
    out = capsys.readouterr().out
    for expected in ("vendor           Aravis", "serial           GONIOTEST", "exposure_range_s 1e-05 .. 10",
                     "manual_exposure  yes (0.01 s read back for 0.01 s)", "Mono16"):
        assert expected in out
    import cv2

    for fmt, dtype in (("Mono16", np.uint16), ("Mono8", np.uint8), ("RGB8", np.uint8)):
        png = tmp_path / f"{fmt}.png"
        assert main(["camera", "capture", "--camera", "gige://127.0.0.1", *ARGS, "--pixel-format", fmt,
                     "--exposure", "0.004", "-o", str(png)]) == 0
        img = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        assert img.dtype == dtype and img.shape[:2] == (2048, 2048) and img.max() > img.min()


def test_bad_settings_are_one_line(fake_camera, tmp_path, capsys):
    cases = [(["--pixel-format", "Mono12Packed"], "camera.pixel_format = 'Mono12Packed': must be one of"),
             (["--pixel-format", "Mono12"], "not offered by this camera (it offers"),
             (["--exposure", "20"], "exposure 20 s outside the camera's range 1e-05 .. 10 s")]
    for extra, message in cases:
        args = ["camera", "capture", "--camera", fake_camera, *ARGS, "--exposure", "0.01", "-o",
                str(tmp_path / "x.npy"), *extra]
        assert main(args) != 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err


def test_no_camera_is_one_line(aravis, capsys):
    with gige_lock():  # nothing listens on 127.0.0.1 while we hold the lock
        assert main(["camera", "info", "--camera", "gige://127.0.0.1", *ARGS]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot open through Aravis" in err[0]


@pytest.mark.parametrize("pattern", ["RG", "GR", "GB", "BG"])
def test_demosaic_matches_the_pfnc_pattern(pattern):
    """A mosaic of a known image (each PFNC pattern) demosaics back to its colours: a wrong pattern
    mapping swaps red and blue or mixes in green."""
    from sim.gige_camera import mosaic

    yy, xx = np.mgrid[0:40, 0:60]
    rgb = np.stack([40 + xx, 100 + 0 * xx, 200 - yy], axis=-1).astype(np.uint8)  # smooth, distinct channels
    back = demosaic(mosaic(rgb, pattern), pattern).astype(int)
    inner = (slice(2, -2), slice(2, -2))
    assert np.abs(back[inner] - rgb[inner].astype(int)).max() <= 1


class _Known:
    """A camera whose frame encodes the exposure and gain it was asked for."""

    def __init__(self):
        self.asked = []

    def capture(self, exposure, gain=1.0, *, timeout=10.0):
        self.asked.append((exposure, gain))
        px = np.zeros((48, 64, 3), np.uint16)
        px[..., 0], px[..., 1], px[..., 2] = round(exposure * 1e4), 100, 200
        return Frame(px, exposure, gain, 8, 0.0, 0.0)


class _Clock:
    def now(self):
        return 0.0


def test_rendering_gige_camera_serves_what_the_host_asks(aravis):
    """The exposure and gain the host writes into the GigE camera's registers reach the renderer, and
    its frame comes back through GVSP in every format, Bayer included."""
    from gonio.rig.aravis import AravisCamera
    from sim.gige_camera import GigECameraServer

    known = _Known()
    with gige_lock(), GigECameraServer(known, serial="GONIO-T") as server:
        for fmt in ("RGB8", "BayerRG8", "BayerGB8", "Mono8", "Mono16"):
            cam = AravisCamera(server.device, _Clock(), pixel_format=fmt, gain_unit="raw", width=64, height=48)
            try:
                frame = cam.capture(0.0025, 3.0, timeout=5)
                assert cam.identity()["serial"] == "GONIO-T" and cam.identity()["pixel_format"] == fmt
            finally:
                cam.close()
            assert known.asked[-1] == (pytest.approx(0.0025), 3.0)
            px = frame.pixels.astype(float)
            assert frame.bit_depth == PIXEL_FORMATS[fmt][0]
            if px.ndim == 3:
                assert np.allclose(px[4:-4, 4:-4].reshape(-1, 3).mean(axis=0), [25, 100, 200], atol=1)
            else:
                top = 255 if fmt == "Mono8" else 65535
                assert np.allclose(px[4:-4, 4:-4], (25 + 100 + 200) / 3 * top / 255, rtol=0.01)
        assert not server.errors


class _Thermometer(_Known):
    """A camera whose frames report a sensor temperature that climbs by 0.5 °C a frame, then one
    impossible reading (a broken thermometer)."""

    def __init__(self, temps):
        super().__init__()
        self.temps = list(temps)

    def capture(self, exposure, gain=1.0, *, timeout=10.0):
        f = super().capture(exposure, gain)
        f.meta["sensor_temp_c"] = self.temps[len(self.asked) - 1]
        return f


def test_sensor_temperature_crosses_genicam_with_each_frame(aravis):
    """DeviceTemperature (SFNC) is read after every frame into meta["sensor_temp_c"], the dark model's
    input; a reading no sensor can have is left out and counted; a camera without the feature has none."""
    from gonio.rig.aravis import AravisCamera
    from sim.gige_camera import GigECameraServer

    temps = [25.0, 25.5, 26.0, 999.0, 26.5]
    with gige_lock():
        with GigECameraServer(_Thermometer(temps), serial="GONIO-TEMP", temperature=True) as server:
            cam = AravisCamera(server.device, _Clock(), pixel_format="RGB8", gain_unit="raw", width=64, height=48)
            try:
                got = [cam.capture(0.001 * (i + 1), 1.0, timeout=5).meta.get("sensor_temp_c") for i in range(5)]
            finally:
                cam.close()
            assert got == [25.0, 25.5, 26.0, None, 26.5] and cam.bad_temperatures == 1
            assert not server.errors
        with GigECameraServer(_Known(), serial="GONIO-NOTEMP") as server:  # _Known has no sensor model
            cam = AravisCamera(server.device, _Clock(), pixel_format="RGB8", gain_unit="raw", width=64, height=48)
            try:
                assert "sensor_temp_c" not in cam.capture(0.001, 1.0, timeout=5).meta
            finally:
                cam.close()
            assert cam.bad_temperatures == 0


def test_camera_toml_for_a_genicam_camera(tmp_path):
    from gonio.rig.calibration import load_camera_calibration

    base = "width = 320\nheight = 240\nfocal_px = 380.0\n[camera]\nlinear = true\nbackend = \"aravis\"\n"
    (tmp_path / "ok.toml").write_text(base + 'pixel_format = "Mono12"\ngain_unit = "raw"\n')
    d = load_camera_calibration(tmp_path / "ok.toml")
    assert d.camera.bit_depth == 12 and d.camera.to_dict()["pixel_format"] == "Mono12"
    for extra, message in (('pixel_format = "Mono12"\nbit_depth = 8\n', "Mono12 has 12 bits"),
                           ("", "a GenICam camera needs one of"),
                           ('pixel_format = "Mono8"\ngain_unit = "percent"\n', "camera.gain_unit")):
        (tmp_path / "bad.toml").write_text(base + extra)
        with pytest.raises(ConfigError, match=message):
            load_camera_calibration(tmp_path / "bad.toml")


def test_simulated_session_through_a_gige_camera(aravis, tmp_path, capsys):
    """`gonio measure --sim --sim-camera gige`: every frame of the session crosses GigE Vision (GVCP
    registers, software trigger, GVSP stream) into gonio's Aravis backend, and the fit recovers the
    material."""
    out = tmp_path / "s"
    with gige_lock():
        code = main(["measure", "--sim", "--sim-camera", "gige", "--plan", "in_plane", "--theta-i", "30",
                     "--theta-o-step", "20", "--out", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["sim"]["camera_link"] == "gige" and manifest["exit_status"] == "completed"
    # the default camera's depth crosses the link: 12-bit colour (RGB12, added to the fake device's formats)
    assert manifest["sim"]["pixel_format"] == "RGB12" and manifest["sim"]["bit_depth"] == 12
    assert "warning" not in capsys.readouterr().err
    records = [json.loads(line.split(b" ", 1)[1]) for line in (out / "samples.jsonl").read_bytes().splitlines()]
    temps = [r["meta"]["dark_model"]["sensor_temp_c"] for r in records if "dark_model" in r["meta"]]
    assert temps and all(isinstance(t, float) and 20 < t < 40 for t in temps)  # read over GenICam
    assert main(["fit", str(out), "--model", "microfacet", "--json", str(tmp_path / "fit.json")]) == 0
    params = json.loads((tmp_path / "fit.json").read_text())["params"]
    assert params["alpha"] == pytest.approx(0.25, rel=0.05)
    np.testing.assert_allclose(params["kd"], [0.3, 0.12, 0.06], rtol=0.05)
