"""The geometric calibration's covariance (gonio.rig.geocov): written with the calibrated rig file and read back,
refused in one line when it is not a covariance, propagated to the light's position and to wi, and the wi error
it allows over the reachable poses compared with the goal; `calibrate check`'s verdict follows every number it
prints (the re-measured poses, the calibration's own bound, the simulated truth)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gonio.errors import ConfigError
from gonio.rig import geocov
from gonio.rig.chain import angle_between_deg, chain_forward
from gonio.rig.geocal import calibrate_geometry, calibrated_rig_text, calibration_plan
from gonio.rig.geocheck import GeoCheck
from gonio.rig.kinematics import load_rig, read_rig_text
from sim.as_built import AsBuilt, observe


@pytest.fixture(scope="module")
def calibrated():
    rig = load_rig("default")
    ab = AsBuilt.from_seed(rig, 4)
    res = calibrate_geometry(rig, *observe(ab, calibration_plan(rig, quick=True), 4))
    text, _ = read_rig_text("default")
    return rig, ab, res, load_rig(text=calibrated_rig_text(text, res), source="cal.toml")


def test_the_covariance_is_written_with_the_rig_file_and_read_back(calibrated):
    rig, ab, res, cal = calibrated
    assert np.allclose(np.sqrt(np.diag(res.cov)), [res.sigma[n] for n in res.cov_names])
    assert set(res.cov_names) == {n for n, s in res.sigma.items() if np.isfinite(s)}
    c = cal.geometry_covariance
    assert c.names == res.cov_names
    assert np.allclose(c.matrix, res.cov, rtol=1e-5, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(c.matrix) > -1e-9 * np.abs(c.matrix).max())


@pytest.mark.parametrize("table, what", [
    ({"names": ["light.d_el_deg"]}, "names and matrix"),
    ({"names": ["light.nope"], "matrix": [[1.0]]}, "distinct chain fields"),
    ({"names": ["light.d_el_deg", "light.d_el_deg"], "matrix": [[1.0, 0], [0, 1.0]]}, "distinct chain fields"),
    ({"names": ["light.d_el_deg"], "matrix": [[1.0, 2.0]]}, "1 x 1 finite numbers"),
    ({"names": ["light.d_el_deg", "light.d_az_deg"], "matrix": [[1.0, 0.5], [0.0, 1.0]]}, "not a covariance"),
    ({"names": ["light.d_el_deg"], "matrix": [[-1.0]]}, "not a covariance"),
    ({"names": ["light.d_el_deg"], "matrix": [["x"]]}, "not a matrix of numbers"),
])
def test_a_bad_covariance_table_is_one_line(table, what):
    with pytest.raises(ConfigError) as info:
        geocov.GeometryCovariance.from_table(table, source="cal.toml: calibration.covariance")
    assert what in str(info.value) and "cal.toml" in str(info.value) and "\n" not in str(info.value)


def test_the_light_position_covariance_is_the_chain_s_first_order_propagation(calibrated):
    """Monte-Carlo of the chain with parameters drawn from the covariance agrees with J C Jᵀ."""
    rig, ab, res, cal = calibrated
    j = geocov.workspace_joints(cal, 5, seed=2)
    C = geocov.light_position_covariance(cal, j)
    assert C.shape == (len(j), 3, 3)
    names = res.errors.names()
    x0 = res.errors.vector()
    z = np.random.default_rng(0).standard_normal((4000, len(res.cov_names))) @ cal.geometry_covariance.factor().T
    where = [names.index(n) for n in res.cov_names]
    pts = []
    for dz in z[:400]:
        x = x0.copy()
        x[where] += dz
        pts.append(chain_forward(cal, type(res.errors).from_vector(x), j)[0])
    emp = np.einsum("dni,dnj->nij", *(np.stack(pts) - chain_forward(cal, res.errors, j)[0],) * 2) / 400
    assert np.allclose(np.sqrt(np.trace(emp, axis1=1, axis2=2)), np.sqrt(np.trace(C, axis1=1, axis2=2)), rtol=0.15)
    s = geocov.wi_covariance_sigma_deg(cal, j)
    assert np.all((s > 0.005) & (s < 0.3))
    assert geocov.light_position_covariance(rig, j) is None and geocov.wi_error_p95(rig) is None


def test_the_wi_bound_covers_the_true_error_and_the_goal_line_says_what_would_help(calibrated):
    rig, ab, res, cal = calibrated
    jw = geocov.workspace_joints(cal, 1000, seed=5)
    true = np.percentile(angle_between_deg(cal.directions(jw)[0], ab.directions(jw)[0]), 95)
    bound = geocov.wi_error_p95(cal)
    assert 0.3 * bound < true < 3 * bound  # the truth is one draw of what the covariance allows
    ok, line = geocov.goal_line(cal, goal_deg=10.0)
    assert ok and f"p95 {bound:.3f}°" in line
    ok, line = geocov.goal_line(cal, goal_deg=bound / 2)
    assert not ok and line.startswith("CANNOT REACH THE GOAL") and "more poses" in line and "larger ChArUco board" in line
    assert "most from light." in line or "most from camera." in line


def test_the_check_verdict_follows_the_calibration_bound_and_the_truth():
    """The re-measured poses are within the threshold, but the calibration's own uncertainty (or, on the
    simulator, the truth over the reachable poses) is not: the verdict is RECALIBRATE and says why."""
    chk = GeoCheck(np.array([0.05, 0.08, 0.1]), np.array([0.04, 0.06]), 0.25, None, None)
    assert chk.ok and chk.lines("cal.toml")[-1].startswith("verdict: OK")
    loose = replace(chk, bound_wi_p95=0.4)
    assert not loose.ok
    last = loose.lines("cal.toml")[-1]
    assert last.startswith("verdict: RECALIBRATE: cal.toml's calibration's own uncertainty allows wi errors of 0.400°")
    assert "more poses" in last
    wrong = replace(chk, bound_wi_p95=0.1, truth_p95={"wi": 0.569, "wo": 0.05})
    lines = wrong.lines("cal.toml")
    assert not wrong.ok and "wi vs the simulated truth over the reachable poses: p95 0.569°" in "\n".join(lines)
    assert lines[-1].startswith("verdict: RECALIBRATE: cal.toml's wi is off by 0.569° from the simulated truth")
