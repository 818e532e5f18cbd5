"""The geometric calibration's noise model (gonio.rig.geocal_noise): on observations whose noise is known —
board poses and highlights with the detectors' noise, the arms standing 0.02° off the joints they report, the
board pose and the highlight of one frame sharing those joints — the variance components come back (the joints'
scatter; the factor by which the stated board covariances were too small), the whitened residuals' χ² of each
group is ~1, and the truth lies within the stated uncertainties."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.rig.chain import _rx, _ry, _rz, chain_forward
from gonio.rig.geocal import CameraObservation, HighlightObservation, calibrate_geometry, calibration_plan
from gonio.rig.geocal_noise import pair_frames
from gonio.rig.kinematics import load_rig
from sim.as_built import AsBuilt, observe

BOARD_MM, BOARD_DEG, HIGH_MRAD, JOINT_DEG = 0.1, 0.02, 0.3, 0.02
#: the board poses' covariances are stated this many times too small in standard deviation
UNDERSTATED = 2.0


def frames(rig, ab, plan, seed):
    """Board poses at every pose and highlights at the highlight poses, drawn with the noise above; the
    covariances state the board's noise UNDERSTATED times too small, the highlight's right, the joints' not."""
    rng = np.random.default_rng(seed)
    cams, highs = [], []
    cov_b = np.diag([BOARD_MM ** 2] * 3 + [BOARD_DEG ** 2] * 3) / UNDERSTATED ** 2
    cov_h = np.eye(2) * (HIGH_MRAD * 1e-3) ** 2
    for kind in ("camera", "highlight"):
        for j in plan[kind]:
            actual = j + np.radians(rng.normal(0.0, JOINT_DEG, 4))
            pl, pc, R = chain_forward(rig, ab.errors, actual)
            a = np.radians(rng.normal(0.0, BOARD_DEG, 3))
            R_obs = _rx(np.asarray(a[0])) @ _ry(np.asarray(a[1])) @ _rz(np.asarray(a[2])) @ R
            p_obs = pc + rng.normal(0.0, BOARD_MM * 1e-3, 3)
            cams.append(CameraObservation(np.array(j), p_obs, R_obs, cov_b))
            if kind == "highlight":
                v = R @ (pl * np.array([1.0, 1.0, -1.0]) - pc)
                xy = v[:2] / v[2] + rng.normal(0.0, HIGH_MRAD * 1e-3, 2)
                highs.append(HighlightObservation(np.array(j), xy, p_obs, R_obs, cov_h))
    return cams, highs


@pytest.fixture(scope="module")
def fit():
    rig = load_rig("default")
    ab = AsBuilt.from_seed(rig, 5)
    cams, highs = frames(rig, ab, calibration_plan(rig), 5)
    return rig, ab, cams, highs, calibrate_geometry(rig, cams, highs)


def test_the_frames_board_pose_and_highlight_are_paired(fit):
    rig, ab, cams, highs, _ = fit
    pair = pair_frames(cams, highs)
    n_cam = len(cams) - len(highs)
    assert np.array_equal(pair, np.arange(n_cam, len(cams)))  # each highlight with its own frame's board pose
    g_cams, g_highs = observe(ab, calibration_plan(rig, quick=True), 5)  # separate poses: nothing shared
    assert np.all(pair_frames(g_cams, g_highs) == -1)


def test_the_variance_components_and_chi2_come_back(fit):
    *_, res = fit
    n = res.noise
    assert abs(n["joint_sigma_deg"] / JOINT_DEG - 1.0) < 0.15
    assert abs(n["scale_board_frontal"] / UNDERSTATED - 1.0) < 0.15
    assert abs(n["scale_board_oblique"] / UNDERSTATED - 1.0) < 0.15
    assert 0.7 < n["scale_highlight"] < 1.3
    for group in ("board_frontal", "board_oblique", "highlight"):
        assert abs(n[f"chi2_{group}"] - 1.0) < 0.15, group


def test_the_truth_is_within_the_stated_uncertainty(fit):
    _, ab, _, _, res = fit
    z = np.array([abs(v - t) / s for (_, v, s, unit), t in zip(res.table(), ab.errors.folded().vector())
                  if not unit.startswith("not")])
    assert len(z) == 25 and np.max(z) < 4.0 and np.sqrt(np.mean(z ** 2)) < 1.5


def test_the_estimated_noise_is_printed(fit, capsys):
    from gonio.cli.calibrate import print_result

    *_, res = fit
    print_result(res)
    line = [x for x in capsys.readouterr().out.splitlines() if "noise (estimated from the residuals)" in x]
    assert len(line) == 1 and f"joints {res.noise['joint_sigma_deg']:.3g}° rms" in line[0] and "χ²/n board frontal " in line[0]
