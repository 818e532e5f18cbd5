"""`gonio calibrate check`'s measure (gonio.rig.geocheck): wi and wo as the camera sees them are exact on
noise-free observations of the true rig, poses too imprecise to judge are left out of the verdict, and the
verdict is one line. (The check session itself, through the runner on the simulated as-built rig, is in
tests/rig/test_geocal.py.)"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from gonio.rig.geocal import calibration_plan
from gonio.rig.geocheck import GeoCheck, check_geometry, wi_sigma, wo_sigma
from gonio.rig.kinematics import load_rig
from sim.as_built import AsBuilt, observe


def test_the_camera_s_wi_and_wo_are_the_true_ones_and_the_declared_rig_is_off():
    rig = load_rig("default")
    ab = AsBuilt.from_seed(rig, 9)
    plan = calibration_plan(rig, quick=True)
    cams, highs = observe(ab, plan, 9, pose_mm=0.0, pose_deg=0.0, highlight_px=0.0, joint_deg=0.0)
    true_rig = replace(rig, geometry_errors=ab.errors)
    exact = check_geometry(true_rig, cams, highs)
    assert exact.wi_deg.max() < 1e-6 and exact.wo_deg.max() < 1e-6 and exact.ok
    declared = check_geometry(rig, cams, highs)
    j = np.stack([h.joints for h in highs])
    from gonio.rig.chain import angle_between_deg

    truth = angle_between_deg(rig.directions(j)[0], ab.directions(j)[0])
    # the declared file's light distance is used for the ray: off by its few-mm error, a few hundredths of a degree
    assert np.max(np.abs(declared.wi_deg - truth)) < 0.1 and np.median(declared.wi_deg) > 0.5 and not declared.ok


def test_a_pose_s_own_uncertainty_comes_from_its_covariances():
    rig = load_rig("default")
    ab = AsBuilt.from_seed(rig, 9)
    cams, highs = observe(ab, calibration_plan(rig, quick=True), 9)
    cam, high = cams[0], highs[0]
    c1 = np.diag([0.2 ** 2] * 3 + [0.02 ** 2] * 3)
    assert np.isnan(wo_sigma(cam)) and np.isnan(wi_sigma(high, c1, 0.5))  # no covariance: unknown, not zero
    s1 = wo_sigma(replace(cam, cov=c1))
    assert 0.2e-3 / np.linalg.norm(cam.position) * 0.5 < np.radians(s1) < 0.2e-3 / np.linalg.norm(cam.position) * 1.5
    hc = np.eye(2) * (0.2 / 380) ** 2
    a, b = wi_sigma(replace(high, cov=hc), c1, 0.5), wi_sigma(replace(high, cov=hc * 4), c1 * 4, 0.5)
    c = wi_sigma(replace(high, cov=hc), c1 * 4, 0.5)
    assert 0.005 < a < 0.2 and 1.95 * a < b < 2.05 * a  # twice all the noise: twice the direction's (first order)
    assert a < c < b  # the board's pose is part of it, the highlight's centroid too


def test_imprecise_poses_are_left_out_and_the_verdict_is_one_line():
    chk = GeoCheck(np.array([0.05, 0.08, 0.9]), np.array([0.04, 0.06]), 0.25,
                   np.array([0.02, 0.03, 0.5]), np.array([0.02, np.nan]))
    assert chk.ok and chk.p95("wi") < 0.1  # the 0.9° pose had a 0.5° σ of its own
    lines = chk.lines("cal.toml")
    assert "1 more too uncertain to judge" in lines[0] and "0.90°" in lines[0]
    assert lines[-1].startswith("verdict: OK: cal.toml's wi and wo are within 0.25°") and "\n" not in lines[-1]
    bad = replace(chk, wo_deg=np.array([0.04, 0.6]))
    assert not bad.ok and bad.lines("cal.toml")[-1].startswith("verdict: RECALIBRATE: cal.toml's wo is off by")
    none = replace(chk, wi_sigma=np.array([0.5, 0.5, 0.5]))
    assert not none.ok and none.lines("x")[-1].startswith("verdict: NOT CHECKED: no pose measured wi precisely")
