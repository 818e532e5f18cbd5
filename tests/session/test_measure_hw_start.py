"""A hardware `gonio measure` whose devices do not open: one error line, an exit code, and no session directory."""

from __future__ import annotations

import pytest

from gonio.cli.main import main

CAMERA_TOML = "width = 640\nheight = 480\nfocal_px = 700.0\n[camera]\nlinear = true\nbit_depth = 12\n"


def _measure(tmp_path, servo, controller, camera="97"):
    calib = tmp_path / "C.toml"
    calib.write_text(CAMERA_TOML)
    return main(["measure", "--rig", "default", "--servo-port", servo, "--controller-port", controller,
                 "--camera", camera, "--calibration", str(calib), "--quiet", "--out", str(tmp_path / "hw7")])


@pytest.mark.parametrize("which", ["servo", "controller"])
def test_missing_serial_port_fails_before_the_session_directory_exists(tmp_path, capfd, which):
    present = tmp_path / "ttyPRESENT"
    present.write_text("")
    missing = str(tmp_path / "ttyMISSING")
    servo, controller = (missing, str(present)) if which == "servo" else (str(present), missing)
    assert _measure(tmp_path, servo, controller) == 3
    err = capfd.readouterr().err.strip()
    assert err.count("\n") == 0 and f"--{which}-port {missing}: no such device" in err, err
    assert not (tmp_path / "hw7").exists()
    assert _measure(tmp_path, servo, controller) == 3  # and a re-run says the same, not "holds another session"
    assert "another session" not in capfd.readouterr().err


def test_camera_that_cannot_open_fails_in_one_line_and_leaves_nothing(tmp_path, capfd):
    port = tmp_path / "ttyPRESENT"
    port.write_text("")
    assert _measure(tmp_path, str(port), str(port), camera="97") == 3  # V4L2 index 97: no such camera here
    err = capfd.readouterr().err.strip()
    assert err.count("\n") == 0 and "camera 97: cannot open" in err, err
    assert "WARN" not in err
    assert not (tmp_path / "hw7").exists()
