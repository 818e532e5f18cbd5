"""The GenICam pixel format of the simulated GigE camera is selectable (--sim-pixel-format), validated against
what the camera offers (one line naming them), recorded in the manifest, and by default 12-bit colour like the
default simulated camera (RGB12, which sim.gige_camera adds to Aravis's fake device's formats); a format of
another depth is said in one warning line. Against the rendering GigE camera on the loopback interface."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.rig.aravis import PIXEL_FORMATS
from tests.rig.test_aravis import _Clock, _Known, aravis, gige_lock  # noqa: F401 (fixtures)


def test_twelve_bit_formats_cross_the_link_at_their_depth(aravis):
    from gonio.rig.aravis import AravisCamera
    from sim.gige_camera import ADDED_FORMATS, GigECameraServer, served_formats

    offered = served_formats()
    assert set(ADDED_FORMATS) <= set(offered) and {"RGB8", "Mono8", "Mono16", "BayerRG8"} <= set(offered)
    with gige_lock(), GigECameraServer(_Known(), serial="GONIO-12") as server:
        for fmt in ("RGB12", "BayerGB12", "Mono12"):
            cam = AravisCamera(server.device, _Clock(), pixel_format=fmt, gain_unit="raw", width=64, height=48)
            try:
                frame = cam.capture(0.0025, 1.0, timeout=5)
                assert cam.identity()["pixel_format"] == fmt
            finally:
                cam.close()
            assert frame.bit_depth == 12 == PIXEL_FORMATS[fmt][0] and frame.pixels.dtype == np.uint16
            px = frame.pixels[4:-4, 4:-4].astype(float)
            full = np.array([25, 100, 200]) * 4095 / 255  # the 8-bit test frame on a 12-bit full scale
            got = px.reshape(-1, 3).mean(axis=0) if px.ndim == 3 else px.mean()
            np.testing.assert_allclose(got, full if px.ndim == 3 else full.mean(), atol=1.0)
        assert not server.errors


def _measure(out, *extra):
    return main(["measure", "--sim", "--sim-camera", "gige", "--plan", "in_plane", "--theta-i", "30",
                 "--theta-o-step", "40", "--out", str(out), "--quiet", *extra])


def test_a_chosen_format_is_validated_recorded_and_its_depth_said(aravis, tmp_path, capsys):
    assert _measure(tmp_path / "bad", "--sim-pixel-format", "Mono14") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--sim-pixel-format" in err[0] and "Mono14" in err[0]
    assert "offers Mono8, Mono16, RGB8" in err[0] and "RGB12" in err[0]
    assert not (tmp_path / "bad").exists()
    assert main(["measure", "--sim", "--sim-pixel-format", "RGB12", "--out", str(tmp_path / "d"), "--quiet"]) == 2
    assert "is the GenICam format of --sim-camera gige" in capsys.readouterr().err
    # a format of another depth: the sensor takes it, recorded, and said in one warning (the session itself, in
    # the default RGB12, is tests/rig/test_aravis.py::test_simulated_session_through_a_gige_camera)
    from gonio.session.rigs import _gige_link

    with pytest.warns(UserWarning) as said:
        link = _gige_link("RGB8", 12)
    assert link == {"camera_link": "gige", "pixel_format": "RGB8", "bit_depth": 8}
    assert [str(w.message) for w in said] == ["--sim-camera gige: RGB8 has 8 bits: the simulated camera is a 8-bit "
                                              "RGB8 sensor, not the default camera's 12 bits"]
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the default matches the default camera: nothing to say
        assert _gige_link("", 12) == {"camera_link": "gige", "pixel_format": "RGB12", "bit_depth": 12}


def test_the_manifests_pixel_format_is_checked(tmp_path):
    from gonio.errors import DataError
    from gonio.session.recording import checked_sim

    assert checked_sim({"camera_link": "gige", "pixel_format": "RGB12"}, "m.json")["pixel_format"] == "RGB12"
    with pytest.raises(DataError, match=r"m.json: sim.pixel_format = 'RGB99': expected a GenICam pixel format"):
        checked_sim({"camera_link": "gige", "pixel_format": "RGB99"}, "m.json")
