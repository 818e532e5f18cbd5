"""gonio.prior: the prior's file format, reconstruction inside its span, σ calibration, out-of-span verdicts."""

import numpy as np
import pytest

from gonio.errors import DataError
from gonio.prior import Posterior, PriorGrid, build_prior, load_prior, save_prior
from gonio.prior.mapping import from_mapped, sigma_from_mapped, sigma_to_mapped, to_mapped
from tests.prior.conftest import GRID, node_values_of, synthetic_materials


def _directions(n, seed):
    """Random direction pairs above the horizon (θ ≤ 75°)."""
    rng = np.random.default_rng(seed)
    ti, to = np.arccos(rng.uniform(np.cos(np.radians(75)), 1, (2, n)))
    po = rng.uniform(0, 2 * np.pi, n)
    wi = np.column_stack([np.sin(ti), np.zeros(n), np.cos(ti)])
    wo = np.column_stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)])
    return wi, wo


def _in_span(prior, coef, wi, wo):
    """BRDF values of the in-span material μ + B·coef (3 channels) at the directions, exactly as the model
    interpolates it."""
    h = prior.grid.weights(wi, wo)
    u = h @ prior.node_mapped(coef).T
    return from_mapped(u, h @ prior.f_ref, prior.eps)


def test_mapping_round_trips_and_delta_method():
    f = np.array([[0.0, 0.01, 5.0]])
    u = to_mapped(f, np.array([0.1]))
    assert np.allclose(from_mapped(u, np.array([0.1])), f, rtol=1e-12, atol=1e-15)
    s = sigma_to_mapped(f, 0.01 * f + 1e-4)
    assert np.allclose(sigma_from_mapped(f, s), 0.01 * f + 1e-4)


def test_material_inside_the_span_is_reconstructed_to_rounding(synthetic_prior):
    pr = synthetic_prior
    rng = np.random.default_rng(3)
    coef = rng.normal(size=(3, pr.n_components)) * np.sqrt(pr.variance)
    wi, wo = _directions(60, 1)
    f = _in_span(pr, coef, wi, wo)
    post = Posterior.start(pr).update(wi, wo, f, 1e-9 * (f + 1e-3))
    mean, _ = post.node_mapped()
    assert np.max(np.abs(mean - pr.node_mapped(coef))) < 1e-6
    wt, wt_o = _directions(200, 2)
    fp, _ = post.predict(wt, wt_o)
    assert np.allclose(fp, _in_span(pr, coef, wt, wt_o), rtol=1e-6, atol=1e-9)
    assert not post.quality().out_of_span


def test_posterior_sigma_is_calibrated_on_noisy_synthetic_data(synthetic_prior):
    """Coefficients drawn from the prior, 5 % noise: the truth falls within 2σ at ~95 % of held-out directions."""
    pr = synthetic_prior
    rng = np.random.default_rng(5)
    hits = []
    for trial in range(10):
        coef = rng.normal(size=(3, pr.n_components)) * np.sqrt(pr.variance)
        wi, wo = _directions(12, 10 + trial)
        f = _in_span(pr, coef, wi, wo)
        sigma = 0.05 * (f + 1e-3)
        noisy = f + rng.normal(size=f.shape) * sigma
        post = Posterior.start(pr).update(wi, wo, noisy, sigma)
        wt, wt_o = _directions(300, 100 + trial)
        fp, sp = post.predict(wt, wt_o)
        truth = _in_span(pr, coef, wt, wt_o)
        hits.append(np.abs(fp - truth) <= 2 * sp)
    cover = float(np.mean(hits))
    assert 0.9 <= cover <= 1.0, cover


def test_a_material_unlike_the_prior_is_said_to_be_outside_its_span(synthetic_prior):
    from gonio.brdf import make

    mirror = make("microfacet", kd=[0.0, 0.0, 0.0], ks=[1, 1, 1], alpha=0.03, f0=[0.9] * 3)
    wi, wo = _directions(80, 7)
    f = mirror.eval(wi, wo)
    q = Posterior.start(synthetic_prior).update(wi, wo, f, 0.01 * f + 1e-5).quality()
    assert q.out_of_span and "OUTSIDE" in q.line()


@pytest.mark.parametrize("bad, what", [("nan_f", "not finite"), ("zero_sigma", "sigma"), ("neg_sigma", "sigma"),
                                       ("nan_sigma", "sigma")])
def test_bad_samples_are_refused_naming_the_sample(synthetic_prior, bad, what):
    wi, wo = _directions(5, 1)
    f = np.full((5, 3), 0.1)
    s = np.full((5, 3), 0.01)
    {"nan_f": f, "zero_sigma": s, "neg_sigma": s, "nan_sigma": s}[bad][3, 1] = {
        "nan_f": np.nan, "zero_sigma": 0.0, "neg_sigma": -1.0, "nan_sigma": np.nan}[bad]
    with pytest.raises(DataError, match=f"sample 3: .*{what}"):
        Posterior.start(synthetic_prior).update(wi, wo, f, s)


def test_prior_file_round_trip_and_refusals(tmp_path, synthetic_prior):
    p = save_prior(synthetic_prior, tmp_path / "p.npz")
    back = load_prior(p)
    assert back.grid == GRID and back.materials == synthetic_prior.materials
    assert np.allclose(back.basis, synthetic_prior.basis, atol=2e-3 * np.abs(synthetic_prior.basis).max())
    assert np.allclose(back.variance, synthetic_prior.variance)
    with np.load(p) as z:
        arrays = dict(z)
    for key, value, msg in (("version", np.array(2), "format version 2"),
                            ("grid_id", np.array("healpix-64"), "unknown prior grid"),
                            ("format", np.array("other"), "not a gonio prior")):
        bad = tmp_path / f"bad-{key}.npz"
        np.savez(bad, **{**arrays, key: value})
        with pytest.raises(DataError, match=msg) as e:
            load_prior(bad)
        assert "\n" not in str(e.value) and str(bad) in str(e.value)
    wrong = tmp_path / "wrong-shape.npz"
    np.savez(wrong, **{**arrays, "grid_id": np.array(PriorGrid(15, 10, 8).grid_id)})
    with pytest.raises(DataError, match="shape"):
        load_prior(wrong)


def test_leave_one_out_calibration_widens_the_variances():
    mats = synthetic_materials(10, seed=4)
    v = node_values_of(mats)
    w = np.full(GRID.size, 1.0 / GRID.size)
    cal = build_prior(v, [n for n, _ in mats], GRID, weight=w, n_components=5)
    raw = build_prior(v, [n for n, _ in mats], GRID, weight=w, n_components=5, calibrate=False)
    assert np.all(cal.variance >= raw.variance) and np.sum(cal.residual) > np.sum(raw.residual)


def test_error_reduction_is_the_exact_drop_of_the_weighted_error(synthetic_prior):
    # adaptive measuring ranks candidates by error_reduction: it must equal what adding the sample really does to
    # Σ w·Var(u) (the posterior after the update, computed the long way), with the cube-root weights
    pr = synthetic_prior
    wi, wo = _directions(6, 11)
    f = _in_span(pr, np.full((3, pr.n_components), 0.3), wi, wo)
    post = Posterior.start(pr).update(wi, wo, f, 0.01 * f + 1e-4)
    w = post.cbrt_weight()
    assert w.shape == (3, pr.grid.size) and np.all(w >= 0)
    cwi, cwo = _directions(5, 12)
    fc = _in_span(pr, np.full((3, pr.n_components), 0.3), cwi, cwo)
    su = 0.02
    red = post.error_reduction(cwi, cwo, su, node_weight=w)
    var0 = post.node_mapped()[1] ** 2
    for j in range(len(cwi)):
        after = post.update(cwi[j:j + 1], cwo[j:j + 1], fc[j:j + 1], su * (fc[j:j + 1] + pr.eps))
        brute = float(np.sum(w * (var0 - after.node_mapped()[1] ** 2)))
        assert red[j] == pytest.approx(brute, rel=1e-6, abs=1e-12)
    # the default weights give expected_error_after
    e = post.expected_error_after(cwi, cwo, su)
    for j in range(2):
        after = post.update(cwi[j:j + 1], cwo[j:j + 1], fc[j:j + 1], su * (fc[j:j + 1] + pr.eps))
        assert e[j] == pytest.approx(after.expected_error(), rel=1e-9)


def test_the_cube_root_weights_follow_what_was_measured(synthetic_prior):
    # the same poses, two materials: the weights (and so the next pose) depend on the values measured, which a
    # criterion of the posterior covariance alone cannot (it does not depend on them)
    pr = synthetic_prior
    wi, wo = _directions(8, 13)
    k = pr.n_components
    bright, dark = (_in_span(pr, np.full((3, k), c), wi, wo) for c in (1.0, -1.0))
    wb = Posterior.start(pr).update(wi, wo, bright, 0.01 * bright + 1e-4).cbrt_weight()
    wd = Posterior.start(pr).update(wi, wo, dark, 0.01 * dark + 1e-4).cbrt_weight()
    assert not np.allclose(wb / wb.sum(), wd / wd.sum(), rtol=0.05)


@pytest.mark.parametrize("grid, rows", [(GRID, slice(None)), (PriorGrid(56, 24, 20), slice(30, 45)),
                                        (PriorGrid(2, 3, 512), slice(0, 15))])
def test_the_merl_cells_weights_built_per_axis_are_the_angles_weights_bit_for_bit(grid, rows):
    """PriorGrid.weights_merl (per-axis coordinates, each corner's weight a broadcast product; what Posterior.table
    and build.cell_weight use) is weights_angles at merl_cell_angles' cells above the horizon: the same CSR matrix,
    bit for bit; merl_above is merl_cell_angles' horizon mask."""
    from gonio.io.merl import cell_directions
    from gonio.prior.grid import merl_above, merl_cell_angles

    th, td, pd, above = merl_cell_angles(rows)
    wi, wo, _ = cell_directions()
    # the horizon test agrees with the cell directions' (both cos θ > 0) wherever it is not at rounding level
    clear = (np.minimum(wi[rows][..., 2], wo[rows][..., 2]) ** 2) > 1e-20
    assert np.array_equal(above[clear], (wi[rows][..., 2] > 0)[clear] & (wo[rows][..., 2] > 0)[clear])
    assert np.array_equal(merl_above(rows), above)
    a, b = grid.weights_angles(th[above], td[above], pd[above]), grid.weights_merl(rows)
    assert a.shape == b.shape == (int(above.sum()), grid.size)
    for x, y in ((a.indptr, b.indptr), (a.indices, b.indices), (a.data, b.data)):
        assert x.dtype == y.dtype and np.array_equal(x, y)
