"""CAMERA.toml parsing (gonio.rig.calibration): every bad value is a one-line ConfigError naming the
file, field and value; response curves round-trip through .npz without pickle; `gonio measure` on
hardware refuses a bad or unusable camera description before a session directory exists."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.errors import ConfigError
from gonio.rig.calibration import CameraDescription, ResponseCurve, load_camera_calibration

BASE = "width = 320\nheight = 240\nfocal_px = 380.0\n"
LINEAR = BASE + "[camera]\nlinear = true\nbit_depth = 12\nblack_level = 64\n"


def _write(tmp_path, text, name="camera.toml"):
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def _curve(tmp_path, name="resp.npz"):
    v = np.arange(256)
    ResponseCurve(inverse=np.stack([(v / 255.0) ** 2.2] * 3, axis=-1), exposures=(0.001, 0.002, 0.004)).save(
        tmp_path / name)
    return tmp_path / name


def test_linear_camera_description_round_trips_through_the_manifest(tmp_path):
    d = load_camera_calibration(_write(tmp_path, LINEAR + 'trigger = "controller"\n[noise]\nread_noise_e = 2.5\n'))
    assert d.camera.linear and d.camera.bit_depth == 12 and d.camera.black_level == 64.0
    assert d.camera.trigger == "controller" and d.calibration.noise.read_noise_e == 2.5
    assert d.calibration.K[0, 0] == 380.0 and d.calibration.width == 320
    back = CameraDescription.from_dict(d.to_dict(), source="manifest")
    assert back.camera == d.camera and np.array_equal(back.calibration.K, d.calibration.K)


def test_non_linear_camera_with_its_response_curve(tmp_path):
    _curve(tmp_path)
    d = load_camera_calibration(_write(tmp_path, BASE + '[camera]\nlinear = false\nbit_depth = 8\nresponse = "resp.npz"\n'))
    r = d.camera.response
    assert r is not None and r.inverse.shape == (256, 3) and r.exposures == (0.001, 0.002, 0.004)
    assert r.inverse[128, 1] == pytest.approx((128 / 255) ** 2.2)
    back = CameraDescription.from_dict(d.to_dict(), source="manifest")  # curve stored inline in the manifest
    assert np.array_equal(back.camera.response.inverse, r.inverse)


@pytest.mark.parametrize("text, field", [
    (BASE + "[noise]\nfoo = 1\n", "noise.foo = 1: unknown key"),
    ("width = 320\nheight = 240\nfocal_px = \"x\"\n", "focal_px = 'x'"),
    ("width = 0\nheight = 240\nfocal_px = 380.0\n", "width = 0"),
    ("width = 320\nfocal_px = 380.0\n", "height = None: missing"),
    (BASE + "[noise]\ndn_per_electron = -1\n", "noise.dn_per_electron = -1"),
    (BASE + "dist = [1, 2]\n", "dist = [1, 2]"),
    (BASE + "colour = 1\n", "colour = 1: unknown key"),
    (LINEAR + "bit_depth = 9\n", None),  # duplicate key: invalid TOML, still one line
    (BASE + "[camera]\nlinear = true\nbit_depth = 9\n", "camera.bit_depth = 9"),
    (BASE + "[camera]\nlinear = \"yes\"\n", "camera.linear = 'yes'"),
    (BASE + "[camera]\nlinear = true\nshutter = 1\n", "camera.shutter = 1: unknown key"),
    (BASE + "[camera]\nlinear = true\ntrigger = \"gpio\"\n", "camera.trigger = 'gpio'"),
    (BASE + "[camera]\nlinear = false\nresponse = \"nope.npz\"\n", "camera.response = 'nope.npz': no such file"),
    (BASE + "[camera]\nlinear = false\n", "camera.linear = False: a non-linear camera needs its response curve"),
    (BASE, "gonio camera response"),  # no [camera]: an 8-bit webcam without a curve, with how to fix it
])
def test_bad_values_are_one_line_config_errors(tmp_path, text, field):
    p = _write(tmp_path, text)
    with pytest.raises(ConfigError) as exc:
        load_camera_calibration(p)
    msg = str(exc.value)
    assert "\n" not in msg and str(p) in msg
    if field is not None:
        assert field in msg


def test_response_with_a_linear_camera_and_bad_curve_files(tmp_path):
    _curve(tmp_path)
    with pytest.raises(ConfigError, match="non-linear 8-bit"):
        load_camera_calibration(_write(tmp_path, LINEAR + 'response = "resp.npz"\n'))
    np.savez(tmp_path / "obj.npz", inverse_response=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ConfigError, match="camera.response"):  # object arrays need pickle: refused
        load_camera_calibration(_write(tmp_path, BASE + '[camera]\nresponse = "obj.npz"\n'))
    np.savez(tmp_path / "short.npz", inverse_response=np.ones(10))
    with pytest.raises(ConfigError, match="shape"):
        load_camera_calibration(_write(tmp_path, BASE + '[camera]\nresponse = "short.npz"\n'))
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ConfigError, match="junk.npz"):
        load_camera_calibration(_write(tmp_path, BASE + '[camera]\nresponse = "junk.npz"\n'))


@pytest.mark.parametrize("text, expect", [
    (BASE + "[noise]\nfoo = 1\n", "noise.foo"),
    (BASE, "camera.linear = False"),
])
@pytest.mark.parametrize("command", [["measure"], ["calibrate", "rig"], ["calibrate", "check"]])
def test_measure_refuses_the_camera_before_creating_a_session(tmp_path, capsys, text, expect, command):
    cal = _write(tmp_path, text)
    out = tmp_path / {"measure": "session", "rig": "calibrated.toml", "check": "check.session"}[command[-1]]
    rc = main([*command, "--rig", "default", "--servo-port", "/dev/null", "--controller-port", "/dev/null",
               "--camera", "0", "--calibration", str(cal), "--session" if command[-1] == "check" else "--out", str(out),
               "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and expect in err and "\n" not in err and "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob("*.session"))


def test_lens_aperture_reaches_the_manifest_and_the_detector_solid_angle(tmp_path):
    from gonio.session.detector import aperture_from_calibration, aperture_solid_angle

    d = load_camera_calibration(_write(tmp_path, "f_number = 4.0\nfocal_length_m = 0.016\n" + LINEAR))
    manifest_calibration = CameraDescription.from_dict(d.to_dict(), source="manifest").to_dict()
    diameter, how = aperture_from_calibration(manifest_calibration, "manifest")
    assert diameter == pytest.approx(0.004) and how == "focal_length_m / f_number"
    # a 4 mm pupil at 0.4 m: 2π(1 − R/√(R² + D²/4)) ≈ π D²/(4 R²)
    assert aperture_solid_angle(diameter, 0.4) == pytest.approx(np.pi * 0.004 ** 2 / 4 / 0.4 ** 2, rel=1e-4)
    for text, field in (("f_number = 4.0\n", "focal_length_m"), ("aperture_diameter_m = -1\n", "aperture_diameter_m")):
        with pytest.raises(ConfigError) as err:
            load_camera_calibration(_write(tmp_path, text + LINEAR, name="bad.toml"))
        assert field in str(err.value) and "bad.toml" in str(err.value) and "\n" not in str(err.value)


def test_black_level_above_full_scale_and_non_npz_response_are_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"camera.black_level = 5000.0: must be below the 12-bit full scale 4095"):
        load_camera_calibration(_write(tmp_path, BASE + "[camera]\nlinear = true\nbit_depth = 12\nblack_level = 5000\n"))
    np.save(tmp_path / "obj.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    (tmp_path / "obj.npz").write_bytes((tmp_path / "obj.npy").read_bytes())
    with pytest.raises(ConfigError) as err:
        load_camera_calibration(_write(tmp_path, BASE + '[camera]\nlinear = false\nbit_depth = 8\nresponse = "obj.npz"\n'))
    msg = str(err.value)
    assert "camera.response" in msg and "allow_pickle" not in msg and "\n" not in msg


def test_a_resumed_hardware_session_gets_the_whole_recorded_calibration(tmp_path):
    from gonio.session.recording import calibration_from_record as _calibration_from_dict

    text = LINEAR.replace("[camera]", "radiometric_scale = [1.5, 1.25, 1.0]\ndist = [0.1, -0.02, 0.0, 0.0]\n[camera]")
    d = load_camera_calibration(_write(tmp_path, text))
    back = _calibration_from_dict(d.to_dict(), "manifest")
    assert back.radiometric_scale is not None and list(back.radiometric_scale) == [1.5, 1.25, 1.0]
    assert np.array_equal(back.dist, d.calibration.dist) and np.array_equal(back.K, d.calibration.K)


@pytest.mark.parametrize("noise, missing", [("", ("dn_per_electron", "read_noise_e")),
                                            ("[noise]\nread_noise_e = 2.5\n", ("dn_per_electron",)),
                                            ("[noise]\nread_noise_e = 2.5\ndn_per_electron = 0.4\n", ())])
def test_noise_fields_left_to_defaults_are_known_and_said_when_a_session_starts(tmp_path, capsys, noise, missing):
    """A CAMERA.toml without [noise] gave every sample's σ from gonio's default sensor, silently (found by QA,
    qa-lab); the session now says so in one line and records which fields were defaults."""
    from gonio.cli.measure import _say_noise_defaults

    d = load_camera_calibration(_write(tmp_path, LINEAR + noise))
    assert d.noise_defaults == missing
    _say_noise_defaults({"hardware": {"noise_defaults": list(missing)}}, "camera.toml")
    err = capsys.readouterr().err
    if missing:
        assert err.count("\n") == 1 and err.startswith("gonio: warning: camera.toml: [noise] does not give")
        assert all(k in err for k in missing) and "not this camera's" in err
    else:
        assert err == ""
