"""The calibration's residuals for a batch of chains (gonio.rig.geocal_residuals) or of joint shifts: every row is,
bit for bit, the residual vector of its chain (its shift) alone — for both layouts, the whitened and raw blocks, the board's camera and the
extended source — so the all-columns-at-once Jacobian is scipy's own '2-point' Jacobian exactly, and the
calibration's solution and uncertainties are those of the one-column-at-a-time finite differences."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize._numdiff import approx_derivative

from gonio.errors import ConfigError
from gonio.rig.chain import ChainErrors, chain_forward
from gonio.rig.geocal import _whiteners, calibration_plan
from gonio.rig.geocal_noise import FrameNoise
from gonio.rig.geocal_residuals import Observed, errors_at, forward_jacobian, residual_blocks
from gonio.rig.kinematics import load_rig
from sim.as_built import AsBuilt, observe

N_PARAMS = len(ChainErrors().names())


def _batch(rng, k=7):
    """Parameter vectors: the declared chain, one without a mounting rotation, one with a single mounting angle,
    two that keep one arm of the first (the light's, the camera's: chain_forward computes such an arm once) and
    random ones (a batch mixing rows with and without the mounting rotation)."""
    V = rng.normal(0.0, 0.5, (k, N_PARAMS))
    V[0] = 0.0
    V[1, 22:25] = 0.0
    V[2, 23:25] = 0.0
    V[3], V[4] = 0.0, 0.0
    V[3, 12] = 0.3                # camera.d_el_deg: the light arm as row 0's
    V[4, [1, 6, 23]] = 0.2        # light.d_el_deg, light.axis_y_mm, camera.mount_y_deg: the camera arm as row 0's
    return V


@pytest.mark.parametrize("layout", ["default", "turntable"])
def test_chain_forward_of_a_batch_is_each_chain_alone(layout):
    rig = load_rig(layout)
    rng = np.random.default_rng(1)
    V = _batch(rng)
    j = rng.uniform(-1.2, 1.2, (30, 4))
    batch = chain_forward(rig, ChainErrors.from_vectors(V), j)
    for k, v in enumerate(V):
        for one, many in zip(chain_forward(rig, ChainErrors.from_vector(v), j), batch):
            assert one.shape == many[k].shape
            np.testing.assert_array_equal(many[k], one)


@pytest.fixture(scope="module")
def observations():
    rig = load_rig("default")
    cams, highs = observe(AsBuilt.from_seed(rig, 4), calibration_plan(rig, quick=True), 4)
    cov_c, cov_h = np.diag([0.01] * 3 + [4e-4] * 3), np.eye(2) * 1e-7  # (mm, deg)², normalized image units²
    return rig, [replace(c, cov=cov_c) for c in cams], [replace(h, cov=cov_h) for h in highs]


@pytest.mark.parametrize("case", ["raw", "whitened", "board camera", "extended source"])
def test_residual_blocks_of_a_batch_are_each_chain_alone(observations, case):
    rig, cams, highs = observations
    kw = {}
    if case == "whitened":
        kw["white"] = {"camera": _whiteners(cams, 1.0), "highlight": _whiteners(highs, 1e3)}
        assert kw["white"]["camera"] is not None and kw["white"]["highlight"] is not None
    if case == "board camera":
        kw["highlight_camera"] = "board"
    if case == "extended source":
        highs = [replace(h, f0=0.04, source_radius_m=0.01) for h in highs]
    obs = Observed.of(cams, highs)
    V = _batch(np.random.default_rng(2)) * 0.2
    batch = residual_blocks(rig, ChainErrors.from_vectors(V), obs, **kw)
    for k, v in enumerate(V):
        one = residual_blocks(rig, ChainErrors.from_vector(v), obs, **kw)
        assert sorted(one) == sorted(batch)
        for name in one:
            np.testing.assert_array_equal(batch[name][k], one[name])


def test_the_batched_jacobian_is_scipys_two_point_jacobian(observations):
    """forward_jacobian against scipy.optimize's own finite differences (approx_derivative, '2-point', what
    least_squares takes without a jac) on the frame-whitened residuals of the noise model: identical arrays."""
    rig, cams, highs = observations
    noise = FrameNoise(rig, cams, highs)
    x = np.random.default_rng(3).normal(0.0, 0.3, N_PARAMS)
    W = noise.whiteners(ChainErrors.from_vector(x))
    idx = [i for i in range(N_PARAMS) if i not in (25, 26, 27, 28)]  # the arms' fields (no turntable, no height)
    x[[25, 26, 27, 28]] = 0.0

    def fun(p, idx):
        return noise.whitened(errors_at(x, idx, p), W)

    p = x[idx]
    p[3] = 0.0  # a parameter at zero: scipy's step is then +√ε
    J = forward_jacobian(fun, p, idx)
    ref = approx_derivative(fun, p, method="2-point", args=(idx,), f0=fun(p, idx))
    assert J.shape == ref.shape == (len(fun(p, idx)), len(idx))
    np.testing.assert_array_equal(J, ref)
    assert J.flags["F_CONTIGUOUS"] == ref.flags["F_CONTIGUOUS"]  # the same memory order: same BLAS results after


def test_the_joint_jacobians_of_a_batch_of_shifts_are_each_shift_alone(observations):
    """FrameNoise.jacobians evaluates its eight joint shifts in one batch: the same central differences, bit for
    bit, as the residuals at each shift alone."""
    rig, cams, highs = observations
    noise = FrameNoise(rig, cams, highs)
    errors = ChainErrors.from_vector(np.random.default_rng(4).normal(0.0, 0.3, N_PARAMS))
    Jc, Jh = noise.jacobians(errors)
    h = 1e-6
    for k in range(4):
        e = np.zeros(4)
        e[k] = h
        (cp, hp), (cm, hm) = noise.raw(errors, e), noise.raw(errors, -e)
        np.testing.assert_array_equal(Jc[..., k], (cp - cm) / (2 * h) * (np.pi / 180.0))
        np.testing.assert_array_equal(Jh[..., k], (hp - hm) / (2 * h) * (np.pi / 180.0))
    assert Jc.shape == (len(cams), 6, 4) and Jh.shape == (len(highs), 2, 4) and np.all(np.abs(Jh).sum(-1) > 0)


def test_a_calibration_with_the_batched_jacobian_is_the_one_with_scipys(observations):
    """End to end: calibrate_geometry with the batched Jacobian (the default) and with scipy's own per-column
    '2-point' finite differences give the same errors, σ, covariance, residuals and evaluation count, bit for bit."""
    from gonio.rig.geocal import calibrate_geometry

    rig, cams, highs = observations
    cams = [replace(c, cov=None) for c in cams]  # geometric observations: each kind rescaled by its scatter
    highs = [replace(h, cov=None) for h in highs]
    a = calibrate_geometry(rig, cams, highs, jacobian="2-point")
    b = calibrate_geometry(rig, cams, highs)
    np.testing.assert_array_equal(a.errors.vector(), b.errors.vector())
    assert a.sigma.keys() == b.sigma.keys() and all(np.array_equal(a.sigma[k], b.sigma[k], equal_nan=True) for k in a.sigma)
    np.testing.assert_array_equal(a.cov, b.cov)
    np.testing.assert_array_equal(a.residuals, b.residuals)
    assert (a.nfev, a.not_identified, a.start) == (b.nfev, b.not_identified, b.start) and a.nfev > 0
    with pytest.raises(ConfigError, match="jacobian = 'cs'"):
        calibrate_geometry(rig, cams, highs, jacobian="cs")
