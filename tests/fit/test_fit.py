"""Fitting single models: known parameters recovered, uncertainties honest, solvers agree."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.errors import ConfigError, DataError
from gonio.fit import fit, prepare
from gonio.fit.kernels import kernel_for
from gonio.fit.layout import Basis, Layout, make_basis

from .conftest import synth


def test_lambert_albedo_within_1_percent():
    s = synth("lambert", {"albedo": [0.2, 0.5, 0.8]})
    r = fit(s, "lambert")
    assert r.loss == "chi2" and r.identifiable
    np.testing.assert_allclose(r.params["albedo"], [0.2, 0.5, 0.8], rtol=0.01)
    # reduced chi2 near 1 when the noise model is right; the uncertainty matches the scatter
    assert 0.8 < r.chi2_red < 1.2
    err = np.abs(np.array(r.params["albedo"]) - [0.2, 0.5, 0.8]) / np.array(r.uncertainty["albedo"])
    assert np.all(err < 5)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_microfacet_alpha_within_2_percent(dist):
    truth = {"kd": [0.3, 0.2, 0.1], "ks": [0.4, 0.5, 0.6], "alpha": 0.15, "distribution": dist}
    r = fit(synth("microfacet", truth), "microfacet", fixed={"distribution": dist})
    assert r.method == "varpro"
    assert abs(r.params["alpha"] - 0.15) / 0.15 < 0.02
    np.testing.assert_allclose(r.params["kd"], truth["kd"], rtol=0.01)
    np.testing.assert_allclose(r.params["ks"], truth["ks"], rtol=0.02)
    assert r.rms_rel < 0.03 and r.n_params == 7


def test_f0_is_fitted_shared_across_channels():
    truth = {"kd": [0.3, 0.12, 0.06], "ks": [0.8, 0.7, 0.6], "alpha": 0.2, "f0": 0.04}
    r = fit(synth("microfacet", truth, n=1500), "microfacet")
    assert r.n_params == 8 and isinstance(r.params["f0"], float)
    assert r.params["f0"] == pytest.approx(0.04, rel=0.1) and r.uncertainty["f0"] < 0.01
    np.testing.assert_allclose(r.params["ks"], truth["ks"], rtol=0.02)
    per_channel = fit(synth("microfacet", truth, n=1500), "microfacet", free=("f0",))
    assert per_channel.n_params == 10 and len(per_channel.params["f0"]) == 3


def test_varpro_and_plain_reach_the_same_optimum():
    s = synth("lambert+ggx", {"diffuse.albedo": 0.3, "lobe1.ks": [0.5, 0.4, 0.3], "lobe1.alpha": 0.2}, n=600)
    a = fit(s, "lambert+ggx", loss="cosine", method="varpro")
    b = fit(s, "lambert+ggx", loss="cosine", method="plain")
    assert a.cost == pytest.approx(b.cost, rel=1e-6)
    assert a.params["lobe1.alpha"] == pytest.approx(b.params["lobe1.alpha"], rel=1e-4)


@pytest.mark.parametrize("loss", ["cosine", "log", "cbrt"])
def test_losses_recover_noise_free_parameters(loss):
    truth = {"kd": [0.3, 0.2, 0.1], "ks": [0.4, 0.5, 0.6], "alpha": 0.25}
    r = fit(synth("microfacet", truth, n=500, noise=0.0), "microfacet", loss=loss)
    assert r.loss == loss
    assert r.params["alpha"] == pytest.approx(0.25, rel=1e-3)
    np.testing.assert_allclose(r.params["ks"], truth["ks"], rtol=1e-3)


def test_two_lobes_are_reported_sharpest_first():
    truth = {"diffuse.albedo": [0.2, 0.3, 0.1], "lobe1.ks": [0.3, 0.2, 0.1], "lobe1.alpha": 0.4,
             "lobe2.ks": [0.3, 0.3, 0.4], "lobe2.alpha": 0.08}
    r = fit(synth("lambert+2ggx", truth, n=1200), "lambert+2ggx", n_starts=2)
    assert r.params["lobe1.alpha"] == pytest.approx(0.08, rel=0.02)
    assert r.params["lobe2.alpha"] == pytest.approx(0.4, rel=0.02)
    np.testing.assert_allclose(r.params["lobe1.ks"], truth["lobe2.ks"], rtol=0.03)


def test_reproducible():
    s = synth("blinn-phong", {"kd": 0.2, "ks": 0.5, "exponent": 80.0}, n=400)
    a, b = fit(s, "blinn-phong", seed=3), fit(s, "blinn-phong", seed=3)
    assert a.params == b.params and a.uncertainty == b.uncertainty


def test_kernels_match_model_eval():
    s = prepare(synth("microfacet", {"kd": 0.2, "ks": 0.5, "alpha": 0.3}, n=300))
    for fixed in ({"f0": 1.0}, {"f0": [0.9, 0.5, 0.2], "distribution": "beckmann"}, {"f0": 1.0, "kd": 0.1}):
        L = Layout("microfacet", fixed)
        assert kernel_for(L) is not None
        fast = Basis(L, s, kernel_for(L))(np.array([0.23]))
        slow = Basis(L, s, None)(np.array([0.23]))
        np.testing.assert_allclose(fast[0], slow[0], rtol=1e-12, atol=1e-300)
        for a, b in zip(fast[1], slow[1]):
            a = a if a.ndim == 2 else np.repeat(a[:, None], 3, 1)
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-300)  # the model's own lobe formula
    L = Layout("lambert+2ggx", {"lobe1.f0": 1.0, "lobe2.f0": 1.0})
    fast, slow = make_basis(L, s, True), make_basis(L, s, False)
    for a, b in zip(fast(np.array([0.1, 0.5]))[1], slow(np.array([0.1, 0.5]))[1]):
        np.testing.assert_allclose(np.broadcast_to(a if a.ndim == 2 else a[:, None], b.shape), b, rtol=1e-12)


def test_the_ward_kernel_is_the_model_and_stays_out_where_a_held_colour_adds_an_offset():
    """gonio.fit.kernels._ward: the model's own expression on cached geometry, so its basis is the model's (the
    widths at their floor and ceiling included); a kd held at a non-zero value (an offset) keeps the model path."""
    s = prepare(synth("ward", {"kd": 0.2, "ks": 0.5, "alpha_x": 0.1, "alpha_y": 0.3}, n=300))
    for fixed in ({}, {"kd": 0.0}):
        L = Layout("ward", fixed)
        assert kernel_for(L) is not None
        for shape in ([0.1, 0.3], [1e-4, 1.0], [0.05, 0.05]):
            fast = Basis(L, s, kernel_for(L))(np.array(shape))
            slow = Basis(L, s, None)(np.array(shape))
            assert not np.any(slow[0])
            for a, b in zip(fast[1], slow[1]):
                np.testing.assert_allclose(np.repeat(a[:, None], 3, 1), b, rtol=1e-15, atol=0)
    assert kernel_for(Layout("ward", {"kd": 0.1})) is None


# -- degenerate inputs ------------------------------------------------------------------------------
def test_too_few_samples_is_a_data_error():
    s = synth("microfacet", {"kd": 0.2, "ks": 0.5, "alpha": 0.3}, n=6).subset(slice(0, 2))
    with pytest.raises(DataError, match="cannot determine 8 parameters"):
        fit(s, "microfacet")


def test_nan_samples_are_dropped_and_all_nan_is_an_error():
    s = synth("lambert", {"albedo": 0.5}, n=200)
    f = s.f.copy()
    f[:50] = np.nan
    r = fit((s.wi, s.wo, f, s.sigma), "lambert")
    assert r.dropped["non-finite"] == 50 and r.n_used == len(s) - 50
    with pytest.raises(DataError, match="no usable sample"):
        fit((s.wi, s.wo, np.full_like(f, np.nan)), "lambert")


def test_all_zeros_gives_not_identifiable_shape():
    s = synth("lambert", {"albedo": 0.5}, n=200)
    r = fit((s.wi, s.wo, np.zeros_like(s.f)), "microfacet")
    assert r.params["kd"] == [0.0, 0.0, 0.0] and r.params["ks"] == [0.0, 0.0, 0.0]
    assert not r.identifiable and any("alpha" in n for n in r.notes)
    assert any("all values are zero" in n for n in r.notes)


def test_single_incidence_angle_lambert_still_fits():
    s = synth("lambert", {"albedo": [0.3, 0.4, 0.5]}, n=300, theta_i=0.5)
    r = fit(s, "lambert")
    np.testing.assert_allclose(r.params["albedo"], [0.3, 0.4, 0.5], rtol=0.01)


def test_bad_names_are_config_errors():
    s = synth("lambert", {"albedo": 0.5}, n=50)
    with pytest.raises(ConfigError, match="unknown loss"):
        fit(s, "lambert", loss="huber")
    with pytest.raises(ConfigError, match="unknown model"):
        fit(s, "glossy")
    with pytest.raises(ConfigError, match="chi2"):
        fit((s.wi, s.wo, s.f), "lambert", loss="chi2")
