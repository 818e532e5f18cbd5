"""A session's calibration error per pose (gonio.session.calibration_modes): built from the rig file the manifest
recorded and each pose's joints; none without a calibration covariance or when the samples' frame is not the plane
(a tilted mount); a pose record without usable joints is left out."""

from __future__ import annotations

import math

import numpy as np

from gonio.pipeline.target import SampleMount, TargetLayout
from gonio.rig.chain import ChainErrors
from gonio.rig.geocal import GeoCalResult, calibrated_rig_text
from gonio.rig.kinematics import load_rig, read_rig_text
from gonio.session.calibration_modes import session_modes

SIGMA_EL_DEG, SIGMA_ARC_MM = 0.1, 0.5


def _manifest(mount=None, calibrated=True):
    text = read_rig_text("default")[0]
    if calibrated:
        res = GeoCalResult(ChainErrors(), {"light.d_el_deg": SIGMA_EL_DEG, "light.arc_x_mm": SIGMA_ARC_MM}, {},
                           cov=np.diag([SIGMA_EL_DEG ** 2, SIGMA_ARC_MM ** 2]),
                           cov_names=("light.d_el_deg", "light.arc_x_mm"))
        text = calibrated_rig_text(text, res)
    layout = TargetLayout() if mount is None else TargetLayout(mount=mount)
    return {"rig": {"toml": text}, "target": layout.to_dict()}


def _poses():
    rig = load_rig("default")
    j = rig.solve_many(np.radians([20.0, 45.0]), np.radians([0.0, 90.0]), np.radians([20.0, 45.0]),
                       np.radians([180.0, 270.0]))[0]
    return rig, {3: {"joints_rad": rig.as_dict(j[0])}, 7: {"joints_rad": rig.as_dict(j[1])},
                 9: {"joints_rad": {"nonsense": 1.0}}}


def test_the_offsets_are_the_light_moved_one_sigma_along_each_axis():
    rig, meta = _poses()
    m = session_modes(_manifest(), meta)
    assert list(m.pose) == [3, 7]  # pose 9's joints are not the rig's: left out
    assert m.offsets.shape == (2, 2, 3)
    assert np.allclose(m.light[0], rig.light_position(rig.as_array(meta[3]["joints_rad"])))
    size = np.sort(np.linalg.norm(m.offsets, axis=2), axis=0)  # per pose: the arc offset's 0.5 mm, the elevation's
    assert np.allclose(size[0], SIGMA_ARC_MM * 1e-3, rtol=0.05)  # the arc offset moves the light by itself
    assert np.allclose(size[1], rig.light_radius * math.radians(SIGMA_EL_DEG), rtol=0.05)
    assert np.allclose(m.white, [-0.085, 0.0, 0.0])
    # and the board's frame turned one stated σ about each axis, the same at every pose
    from gonio.rig.geocal import BOARD_ROTATION_SIGMA_DEG

    assert np.allclose(m.frame_turns, math.radians(BOARD_ROTATION_SIGMA_DEG) * np.eye(3))
    assert m.n_modes == 2 + 3


def test_no_modes_without_a_covariance_or_on_a_tilted_mount():
    _, meta = _poses()
    assert session_modes(_manifest(calibrated=False), meta) is None
    assert session_modes(_manifest(mount=SampleMount(tilt_x_deg=10.0)), meta) is None
    assert session_modes({"rig": {"toml": "[calibration.covariance]\nnot toml ["}}, meta) is None  # unreadable: none
    assert session_modes(_manifest(), {}) is None
