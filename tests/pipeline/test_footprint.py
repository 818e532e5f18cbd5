"""A tile's mean over its directions is not the BRDF at its mean direction where the BRDF curves: the second-order
bias ½ tr(H Σ_h) is estimated from the neighbouring tiles and removed, with its own variance (gonio.pipeline.footprint)."""

from __future__ import annotations

import numpy as np

from gonio.pipeline.footprint import footprint_correction, tile_half_moments


def _grid(n=7, step=0.01):
    x, y = np.meshgrid(np.arange(n) * step, np.arange(n) * step)
    return np.stack([x.ravel(), y.ravel()], -1)


def test_the_moments_of_each_tile_s_half_vectors():
    h = np.array([[0.0, 0.0, 1], [0.2, 0.0, 1], [0.1, 0.1, 1], [0.1, -0.1, 1]])
    m, c = tile_half_moments(h, np.array([0, 0, 1, 1]), 2)
    assert np.allclose(m, [[0.1, 0.0], [0.1, 0.0]])
    assert np.allclose(c[0], [[0.01, 0], [0, 0]]) and np.allclose(c[1], [[0, 0], [0, 0.01]])


def test_a_quadratic_brdf_s_tile_bias_is_removed_exactly():
    """For f quadratic in h the tile means are f(mean) + ½ tr(H Σ) exactly; the correction recovers it wherever the
    tile has its 8 neighbours (and at edges with at least 7 valid tiles)."""
    n = 7
    hm = _grid(n)
    H = np.array([[-800.0, 150.0], [150.0, -500.0]])
    g = np.array([3.0, -2.0])

    def f(h):
        return 2.0 + h @ g + 0.5 * np.einsum("ti,ij,tj->t", h, H, h)

    S = np.array([[2e-5, 5e-6], [5e-6, 1e-5]])
    Sig = np.broadcast_to(S, (n * n, 2, 2)).copy()
    bias = 0.5 * np.trace(H @ S)
    means = (f(hm) + bias)[:, None] * np.ones((1, 3))
    delta, dvar = footprint_correction(means, np.full_like(means, 1e-6), hm, Sig, n)
    interior = np.zeros((n, n), bool)
    interior[1:-1, 1:-1] = True
    assert np.allclose(delta[interior.ravel()], bias, rtol=1e-6)
    assert np.allclose((means - delta)[interior.ravel()], f(hm)[interior.ravel(), None], rtol=1e-9)
    corners = [0, n - 1, n * (n - 1), n * n - 1]  # 4 valid tiles: too few, left as they are
    assert np.all(delta[corners] == 0) and np.all(dvar[corners] == 0)


def test_the_correction_s_variance_is_what_noise_gives_it():
    """Noise on the tile values: the corrected value's variance is var + dvar (Monte-Carlo), never negative."""
    n = 5
    hm = _grid(n)
    Sig = np.broadcast_to(np.diag([3e-5, 3e-5]), (n * n, 2, 2)).copy()
    rng = np.random.default_rng(0)
    sd = 0.01
    base = np.ones((n * n, 3))
    out = []
    for _ in range(3000):
        y = base + rng.normal(0, sd, base.shape)
        d, dvar = footprint_correction(y, np.full_like(y, sd ** 2), hm, Sig, n)
        out.append(y - d)
    emp = np.var(np.stack(out), axis=0)
    pred = sd ** 2 + dvar
    assert np.all(pred > 0)
    assert np.allclose(emp, pred, rtol=0.12)
    assert pred[12, 0] > sd ** 2  # the centre tile: the correction adds noise of its own


def test_tiles_without_values_are_left_alone():
    n = 5
    hm = _grid(n)
    y = np.ones((n * n, 3))
    y[12] = np.nan
    d, dv = footprint_correction(y, np.full_like(y, 1e-4), hm, np.zeros((n * n, 2, 2)), n)
    assert np.all(np.isfinite(d)) and d[12].tolist() == [0, 0, 0] and np.allclose(d, 0)
