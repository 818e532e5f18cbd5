"""The light's highlight in the calibration tile (issue 15): the simulated camera renders it from the
as-built geometry, gonio.pipeline.highlight finds it to a fraction of a pixel, refuses saturated, missing,
ambiguous and edge-cut spots, and its stated uncertainty covers the error."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.pipeline.highlight import MIN_SIGMA_PX, clear_of_edges, detect_highlight, find_highlight
from gonio.pipeline.target import CameraPose, Rect
from gonio.session.geocal_observe import calibration_layout, observe_pose
from sim.camera import SensorModel, SimCamera, SimScene
from sim.mirror_tile import CalibrationTile
from sim.rig import SimRigConfig


def _scene():
    from gonio.brdf import make

    layout = calibration_layout()
    cfg = SimRigConfig()
    cam = SimCamera(cfg.calibration(), SensorModel(), SimScene(layout, make("lambert", albedo=0.5),
                                                              tile=CalibrationTile(rect=layout.sample)))
    return cam, cfg.calibration(), layout


@pytest.fixture(scope="module")
def scene():
    return _scene()


def _place(cam, light_el_deg, cam_el_deg, az_deg=20.0, light_r=0.6, cam_r=0.4):
    a, el, ec = np.radians([az_deg, light_el_deg, cam_el_deg])
    light = light_r * np.array([np.sin(el) * np.cos(a), np.sin(el) * np.sin(a), np.cos(el)])
    eye = cam_r * np.array([-np.sin(ec) * np.cos(a), -np.sin(ec) * np.sin(a), np.cos(ec)])
    pose = CameraPose.look_at(eye)
    cam.set_pose(pose)
    cam.set_light(light, on=True, output=1.0)
    image = light * np.array([1.0, 1.0, -1.0])
    return pose, pose.project(image, cam.calibration)


@pytest.mark.parametrize("light_el, cam_el", [(30.0, 30.0), (50.0, 53.0), (10.0, 7.0)])
def test_the_highlight_is_found_at_the_light_s_mirror_image(scene, light_el, cam_el):
    cam, calib, layout = scene
    pose, uv = _place(cam, light_el, cam_el)
    cam.reseed(1)
    found = find_highlight(cam, calib)
    hl = found.highlight
    assert hl is not None, found.reason
    err = np.linalg.norm(hl.uv - uv)
    sigma = np.sqrt(np.trace(hl.cov_uv))
    assert err < 0.05 and MIN_SIGMA_PX <= sigma < 0.1 and err < 3 * sigma
    assert clear_of_edges(hl, pose, calib, layout.sample) == ""
    # normalized coordinates: the ray through the highlight points at the light's mirror image
    x = np.append(hl.xy, 1.0) @ pose.R
    image = cam._light_pos * np.array([1.0, 1.0, -1.0])
    d = (image - pose.centre) / np.linalg.norm(image - pose.centre)
    assert np.degrees(np.arccos(np.clip(x @ d / np.linalg.norm(x), -1, 1))) < 0.01


def test_a_saturated_highlight_is_refused_and_the_search_shortens_the_exposure(scene):
    cam, calib, _ = scene
    _place(cam, 30.0, 30.0)
    f = cam.capture(0.005)
    sat = calib.noise.linear_limit(4095, f.black_level)
    hl, why = detect_highlight(f.pixels, calib, black_level=f.black_level, saturation=sat)
    assert hl is None and why == "saturated"
    found = find_highlight(cam, calib, exposure=0.005)
    assert found.highlight is not None and found.exposures[0] > found.highlight.exposure
    assert found.highlight.peak_dn < sat - f.black_level


def test_no_highlight_on_the_tile_is_said_so():
    cam, calib, layout = _scene()  # its own camera: the noise drawn does not depend on the tests run before
    pose, uv = _place(cam, 30.0, 45.0)  # 15° off the mirror direction: the reflection is off the 80 mm tile
    found = find_highlight(cam, calib)
    assert found.highlight is None and "no highlight" in found.reason and "\n" not in found.reason


def test_a_highlight_cut_by_the_tile_s_edge_is_refused(scene):
    cam, calib, layout = scene
    pose, uv = _place(cam, 30.0, 30.0)
    hl = find_highlight(cam, calib).highlight
    small = Rect(-0.04, -0.04, 0.04, 0.0)  # a tile whose edge passes through the reflection point
    assert "edge" in clear_of_edges(hl, pose, calib, small)


def test_observe_pose_gives_a_board_pose_with_covariance_and_the_highlight(scene):
    cam, calib, layout = scene
    pose, _ = _place(cam, 40.0, 40.0)
    c, h, why = observe_pose(cam, calib, layout, np.zeros(4), highlight=True)
    assert why == "" and c is not None and h is not None
    assert np.linalg.norm(c.position - pose.centre) < 2e-3 and c.cov.shape == (6, 6)
    assert np.all(np.linalg.eigvalsh(c.cov) > 0) and np.all(np.linalg.eigvalsh(h.cov) > 0)
