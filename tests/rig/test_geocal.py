"""Geometric calibration (gonio.rig.geocal, issue 15): the estimated assembly errors of as-built simulated
rigs are within their stated uncertainties, unidentifiable parameters are said so, a degenerate pose set
is refused in one line, and the calibrated rig file gives the host the true directions."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.errors import ConfigError
from gonio.rig.chain import angle_between_deg
from gonio.rig.geocal import DegeneratePoses, calibrate_geometry, calibrated_rig_text, calibration_plan
from gonio.rig.kinematics import load_rig, read_rig_text
from sim.as_built import AsBuilt, observe


@pytest.fixture(scope="module")
def rig():
    return load_rig("default")


@pytest.fixture(scope="module")
def plan(rig):
    return calibration_plan(rig)


@pytest.fixture(scope="module")
def fits(rig, plan):
    out = []
    for seed in (11, 12, 13):
        ab = AsBuilt.from_seed(rig, seed)
        out.append((ab, calibrate_geometry(rig, *observe(ab, plan, seed))))
    return out


def test_parameters_are_recovered_within_their_stated_uncertainty(fits):
    z = []
    for ab, res in fits:
        for (name, value, sigma, unit), truth in zip(res.table(), ab.errors.folded().vector()):
            if unit.startswith("not identified"):
                assert np.isnan(sigma)
                continue
            assert 0 < sigma < 5.0, name
            z.append(abs(value - truth) / sigma)
    z = np.array(z)
    assert len(z) == 3 * 25  # 11 light + 14 camera (with its mounting rotation) parameters
    assert np.mean(z < 3.0) >= 0.99  # the stated uncertainty is honest ...
    assert np.mean(z < 0.2) < 0.5    # ... and not inflated to make the first assert trivial


def test_unidentifiable_parameters_are_reported_not_guessed(fits):
    _, res = fits[0]
    assert "sample_height_mm" in res.not_identified and "turntable.tilt_x_deg" in res.not_identified
    assert res.errors.sample_height_mm == 0.0 and np.isnan(res.sigma["sample_height_mm"])


def test_calibrated_rig_file_gives_the_true_directions(rig, fits, tmp_path):
    ab, res = fits[0]
    text, _ = read_rig_text("default")
    path = tmp_path / "calibrated.toml"
    path.write_text(calibrated_rig_text(text, res))
    cal = load_rig(path)
    j = np.random.default_rng(0).uniform([-2.5, -1.3, -2.5, -1.3], [2.5, 1.3, 2.5, 1.3], (500, 4))
    twi, two = ab.directions(j)
    before = angle_between_deg(rig.directions(j)[0], twi)
    after_i = angle_between_deg(cal.directions(j)[0], twi)
    after_o = angle_between_deg(cal.directions(j)[1], two)
    assert np.median(before) > 0.5
    assert np.median(after_i) < 0.1 and np.median(after_o) < 0.1
    ti, pi_, to, po = cal.forward(j)
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], -1)
    assert np.allclose(wi, cal.directions(j)[0], atol=1e-12)
    with pytest.raises(ConfigError, match="already has a \\[calibration\\]"):
        calibrated_rig_text(path.read_text(), res)


def test_a_bad_calibration_table_is_one_line(tmp_path):
    text, _ = read_rig_text("default")
    p = tmp_path / "bad.toml"
    p.write_text(text + "\n[calibration.light]\nd_az_deg = 'three'\n")
    with pytest.raises(ConfigError, match="d_az_deg"):
        load_rig(p)


@pytest.mark.parametrize("cut, reason", [
    (lambda plan: {"camera": plan["camera"][:4], "highlight": plan["highlight"]}, "4 camera poses"),
    (lambda plan: {"camera": np.repeat(plan["camera"][np.isclose(plan["camera"][:, 2], plan["camera"][0, 2])], 3, 0),
                   "highlight": plan["highlight"]}, "camera observations at 1 azimuth"),
    (lambda plan: {"camera": plan["camera"],
                   "highlight": plan["highlight"][np.isclose(plan["highlight"][:, 1], plan["highlight"][0, 1])]},
     "light observations at 1 elevation"),
])
def test_a_degenerate_pose_set_is_refused_in_one_line(rig, plan, cut, reason):
    ab = AsBuilt.from_seed(rig, 1)
    bad = cut(plan)
    with pytest.raises(DegeneratePoses, match=reason) as info:
        calibrate_geometry(rig, *observe(ab, bad, 1))
    assert "\n" not in str(info.value)


@pytest.fixture(scope="module")
def calibrated_7(rig, tmp_path_factory):
    """A calibrated rig file for as-built rig 7 (from geometric observations: the rendered session is
    tests/session/test_geocal_session.py's and the benchmark's), and what print_result printed."""
    import contextlib
    import io

    from gonio.cli.calibrate import print_result

    ab = AsBuilt.from_seed(rig, 7)
    res = calibrate_geometry(rig, *observe(ab, calibration_plan(rig, quick=True), 7))
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        print_result(res)
    out = tmp_path_factory.mktemp("cal7") / "cal.toml"
    out.write_text(calibrated_rig_text(read_rig_text("default")[0], res))
    return out, buf.getvalue()


def test_calibrate_check_re_measures_the_rig_and_gives_a_verdict(calibrated_7, tmp_path, capsys):
    """`gonio calibrate check`: a short session on the simulated as-built rig (rendered frames: the board pose
    and the highlight, as on a rig); the calibrated file passes, the declared one is told to recalibrate."""
    from gonio.cli.main import main

    out, printed = calibrated_7
    assert "not identified" in printed and "±" in printed and "started from the hand-eye geometry" in printed
    assert load_rig(out).geometry_errors is not None
    assert main(["calibrate", "check", "--sim", "--sim-as-built", "7", "--rig", str(out), "--quiet",
                 "--session", str(tmp_path / "c1")]) == 0
    after = capsys.readouterr().out
    assert main(["calibrate", "check", "--sim", "--sim-as-built", "7", "--quiet", "--session", str(tmp_path / "c0")]) == 1
    before = capsys.readouterr().out

    def seen(text, name):  # p95 of the error against what the camera saw
        return float(text.split(f"  {name} vs the ")[1].split("p95 ")[1].split("°")[0])

    def truth(text):
        return float(text.split("vs the simulated truth at the board poses: wi median ")[1].split("°")[0])

    assert truth(after) < 0.1 < 0.5 < truth(before)
    assert seen(after, "wi") < 0.25 < 1.0 < seen(before, "wi") and seen(after, "wo") < 0.25 < 1.0 < seen(before, "wo")
    assert after.strip().splitlines()[-1].startswith("verdict: OK: ")
    assert main(["resume", str(tmp_path / "c1")]) == 0  # a finished check session: its report again
    assert capsys.readouterr().out.strip().splitlines()[-1] == after.strip().splitlines()[-1]
    verdict = before.strip().splitlines()[-1]
    assert verdict.startswith("verdict: RECALIBRATE: ") and "> 0.25°" in verdict
    assert main(["calibrate", "check", "--sim", "--threshold", "-1", "--session", str(tmp_path / "c2")]) != 0
    assert "--threshold = '-1': expected degrees in (0, 90]" in capsys.readouterr().err
    assert not (tmp_path / "c2").exists()


def test_a_session_on_the_calibrated_rig_records_its_uncertainties(calibrated_7, tmp_path, capsys):
    from gonio.cli.main import main

    out, _ = calibrated_7
    d = tmp_path / "s"
    assert main(["measure", "--sim", "--quiet", "--plan", "in_plane", "--theta-i-step", "40", "--theta-o-step", "40",
                 "--sim-resolution", "320x240", "--sim-as-built", "7", "--rig", str(out), "--out", str(d)]) == 0
    import json

    rec = json.loads((d / "manifest.json").read_text())["rig"]
    assert len(rec["sha256"]) == 64 and "light" in rec["calibration"]["uncertainty"]
    assert "names" in rec["calibration"]["covariance"]
    # the calibration's covariance reaches every pose's light position and every sample's shared σ
    from gonio.rig.geocov import light_position_covariance
    from gonio.session.store import load_session, scan_samples

    metas = {k: m for k, (_s, m) in scan_samples(d / "samples.jsonl").records.items()}
    cal = load_rig(out)
    for m in metas.values():
        j = cal.as_array(m["joints_rad"])
        assert np.allclose(m["light_cov_m2"], light_position_covariance(cal, j), rtol=1e-9, atol=0)
    _, samples = load_session(d)
    ok = np.isfinite(samples.sigma).all(axis=1)
    assert np.all(samples.sigma_pose[ok] > 0) and np.all(samples.sigma_pose[ok] <= samples.sigma[ok])
    # ... and, shared by every pose, the fit's σ (gonio.fit.geometry): gonio fit prints it and its JSON says so
    capsys.readouterr()
    assert main(["fit", str(d), "--model", "lambert", "--json", str(tmp_path / "fit.json")]) == 0
    said = capsys.readouterr().out
    assert "geometric calibration's error shared by all" in said and "JCGM 100" in said
    notes = json.loads((tmp_path / "fit.json").read_text())["notes"]
    assert any("geometric calibration's error shared by all" in n for n in notes)
    from gonio.api import calibration_modes
    from gonio.report import load_entries

    fitted = load_entries([str(d)], fit_models=("lambert",))[0].fits["lambert"][1]  # gonio report's fits too
    assert any("geometric calibration's error shared by all" in n for n in fitted["notes"])
    modes = calibration_modes(d)
    assert modes.offsets.shape == (len(cal.geometry_covariance.names), len(metas), 3)
    # the offsets along the principal axes hold the light position's covariance at every pose
    for k, m in metas.items():
        i = list(modes.pose).index(k)
        C = np.einsum("ki,kj->ij", modes.offsets[:, i], modes.offsets[:, i])
        assert np.allclose(C, m["light_cov_m2"], rtol=1e-6, atol=1e-14)
    assert main(["calibrate", "rig", "--rig", str(out), "--sim", "--estimate"]) != 0
    assert "already calibrated" in capsys.readouterr().err


def test_a_bad_declared_geometry_the_hand_eye_start_and_the_joint_fit(rig, plan):
    """Servo horns 15° off on both arms (and the camera 5° askew on its bracket): the closed-form
    robot-world/hand-eye solution (gonio.rig.handeye, Shah 2013; OpenCV's calibrateRobotWorldHandEye where the
    installed OpenCV exposes it) already puts the camera arm near the truth; the joint least squares started
    there and started from the declared geometry reach the same estimate, the truth within 3σ."""
    from gonio.rig.handeye import camera_arm_start, robot_world_hand_eye

    ab = AsBuilt.from_seed(rig, 21)
    for arm in (ab.errors.light, ab.errors.camera):
        arm["d_az_deg"], arm["d_el_deg"] = 15.0, -15.0
    ab.errors.camera["mount_z_deg"] = 5.0
    cams, highs = observe(ab, plan, 21)
    truth = ab.errors.folded()
    start = camera_arm_start(rig, cams)
    for k in ("d_az_deg", "d_el_deg", "tilt_x_deg", "tilt_y_deg", "mount_z_deg"):
        assert abs(start[k] - truth.camera[k]) < 0.5, k  # vs 15° from the declared geometry
    he = calibrate_geometry(rig, cams, highs)
    de = calibrate_geometry(rig, cams, highs, start="declared")
    assert he.start == "hand-eye" and de.start == "declared"
    sig = np.array([he.sigma[n] for n in he.errors.names()])
    ok = np.isfinite(sig)
    assert np.all(np.abs(he.errors.vector() - de.errors.vector())[ok] < 0.02 * sig[ok])  # the same optimum
    assert np.all(np.abs(he.errors.vector() - truth.vector())[ok] < 3 * sig[ok])
    # the NumPy solver is the closed form itself: exact on noise-free poses
    rng = np.random.default_rng(0)
    from gonio.rig.chain import _rx, _ry, _rz

    RY, RZ = _rx(np.asarray(0.1)) @ _rz(np.asarray(-0.3)), _ry(np.asarray(0.2)) @ _rx(np.asarray(0.05))
    tY, tZ = np.array([0.01, -0.02, 0.003]), np.array([0.0, 0.1, 0.4])
    RB = _rz(rng.uniform(-3, 3, 10)) @ _ry(rng.uniform(-1, 1, 10))
    tB = rng.normal(0, 0.1, (10, 3))
    RA = RZ @ RB @ RY.T
    tA = (RZ @ tB[..., None])[..., 0] + tZ - (RA @ tY[:, None])[..., 0]
    got = robot_world_hand_eye(RA, tA, RB, tB, use_opencv=False)
    for a, b in zip(got, (RY, tY, RZ, tZ)):
        np.testing.assert_allclose(a, b, atol=1e-9)


def test_the_camera_mounting_rotation_is_estimated_or_said_not_identified(rig, plan, fits):
    """The mounting rotation (camera.mount_*_deg) turns the image, not the camera's position: the board's
    orientation and the highlights determine it (recovered in the seeded fits above). Board poses whose
    orientation is unknown (±60°) and no highlight cannot: it is reported not identified and kept at 0 in the
    calibrated rig file, while the arm's parameters that positions determine are still estimated."""
    from dataclasses import replace

    for ab, res in fits:
        for k in ("mount_x_deg", "mount_y_deg", "mount_z_deg"):
            assert abs(res.errors.camera[k] - ab.errors.camera[k]) < 3 * res.sigma[f"camera.{k}"] < 0.1
    ab = AsBuilt.from_seed(rig, 4)
    cams, _ = observe(ab, plan, 4)
    cams = [replace(c, cov=np.diag([0.2 ** 2] * 3 + [60.0 ** 2] * 3)) for c in cams]
    res = calibrate_geometry(rig, cams, [], check=False)
    for k in ("mount_x_deg", "mount_y_deg", "mount_z_deg"):
        assert "too large" in res.not_identified[f"camera.{k}"] and res.errors.camera[k] == 0.0
    assert "camera.d_az_deg" not in res.not_identified
    assert abs(res.errors.camera["d_az_deg"] - ab.errors.camera["d_az_deg"]) < 3 * res.sigma["camera.d_az_deg"]
    text = calibrated_rig_text(read_rig_text("default")[0], res)
    assert '"camera.mount_z_deg" = "uncertainty' in text and "\nmount_z_deg = 0\n" in text
