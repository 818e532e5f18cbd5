"""A metal-like table gets a metal's Fresnel reflectance f0 (≥ 0.5), whichever candidate fits it (issue 29)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.brdf.fresnel import f0_from_eta
from gonio.fit.data import prepare
from gonio.fit.fit import fit
from gonio.fit.kernels_abc import abc_smooth_albedo
from gonio.fit.select import select
from gonio.io.merl import cell_directions


@pytest.fixture(scope="module")
def copper_like():
    """1,500 MERL cell centres of a copper-like conductor (f0 0.95/0.64/0.54, no diffuse), 1 % noise."""
    wi, wo, above = cell_directions()
    ok = above & (wi[..., 2] > 0.2) & (wo[..., 2] > 0.2)
    idx = np.random.default_rng(3).choice(np.flatnonzero(ok), 1500, replace=False)
    wi, wo = wi.reshape(-1, 3)[idx], wo.reshape(-1, 3)[idx]
    truth = make("microfacet", kd=0.0, ks=1.0, alpha=0.08, f0=[0.95, 0.64, 0.54])
    f = truth.eval(wi, wo)
    y = f * (1 + 0.01 * np.random.default_rng(4).standard_normal(f.shape))
    return prepare((wi, wo, y, 0.01 * f + 1e-9))


def _f0s(params):
    return [float(np.mean(v)) for k, v in params.items() if k.rsplit(".", 1)[-1] == "f0"] + \
           [float(f0_from_eta(v)) for k, v in params.items() if k == "eta"]


def test_the_selected_fit_of_a_metal_like_table_has_a_metal_f0(copper_like):
    # Schlick's coloured f0 is not a tied f0 times a colour: nothing fits to 1 %, so the set is not widened here
    sel = select(copper_like, ("microfacet", "lambert+2ggx"), widen=False, n_starts=1)
    assert _f0s(sel.params) and min(_f0s(sel.params)) >= 0.5, sel.params


def test_abc_smooth_on_a_metal_like_table_cannot_trade_fresnel_for_an_unbounded_lobe(copper_like):
    r = fit(copper_like, "abc-smooth", report=False, n_starts=1)
    assert f0_from_eta(r.params["eta"]) >= 0.5  # was eta 1.5 (f0 0.04) with a lobe reflecting 10x the light
    albedo = np.asarray(r.params["A"]) * abc_smooth_albedo(r.params["B"], r.params["C"])
    assert np.all(albedo <= 1 + 1e-9)


def test_abc_smooth_lobe_albedo_matches_numerical_integration():
    from scipy.integrate import quad

    for B, C in ((3.0, 0.5), (68.0, 1.9), (1e4, 1.0)):
        num = np.pi * quad(lambda u: (1 + B * u) ** -C, 0, 1, points=[1 / B])[0]
        assert abc_smooth_albedo(B, C) == pytest.approx(num, rel=1e-8)


def test_the_one_se_rule_prefers_a_physical_row_only_among_those_the_data_cannot_tell_apart():
    from gonio.fit.select import one_se_choice

    rows = [{"model": "simple", "n_params": 3, "score": 1.00, "cv_se": 0.1, "unphysical": "f0 0.09"},
            {"model": "physical", "n_params": 9, "score": 1.05, "cv_se": 0.1},
            {"model": "simplest", "n_params": 2, "score": 1.50, "cv_se": 0.1}]  # beyond one SE: never chosen
    assert one_se_choice(rows)[0]["model"] == "physical"
    del rows[0]["unphysical"]
    assert one_se_choice(rows)[0]["model"] == "simple"  # physical too now: the fewer parameters win
    rows[1]["score"] = 1.2  # the physical one beyond one SE: the unphysical best is kept
    rows[0]["unphysical"] = "f0 0.09"
    assert one_se_choice(rows)[0]["model"] == "simple"


def test_a_sample_declared_a_metal_with_no_metal_candidate_keeps_the_data_s_choice_and_says_so():
    from gonio.fit.select import lobe_f0s

    from .conftest import synth

    plastic = synth("microfacet", {"kd": [0.3, 0.2, 0.1], "ks": 0.6, "alpha": 0.3, "f0": 0.04}, n=800)
    kw = dict(criterion="cv", widen=False, n_starts=1)
    sel = select(plastic, ("lambert", "microfacet"), metal=True, **kw)
    row = {r["model"]: r for r in sel.candidates}
    assert sel.model_name == "microfacet" and lobe_f0s(sel.params)[0] < 0.1  # no candidate is a metal's
    assert "not a metal's Fresnel" in row["microfacet"]["reason"] and "no specular term" in row["lambert"]["unphysical"]
    assert any("no candidate has a metal's Fresnel" in n for n in sel.notes)
    plain = select(plastic, ("lambert", "microfacet"), **kw)
    assert plain.model_name == "microfacet" and "not a metal" not in " ".join(r["reason"] for r in plain.candidates)
    assert lobe_f0s({"eta": [0.2, 0.2, 0.5], "k": [3.0, 2.5, 2.0]})[0] > 0.8  # a complex index: a metal's f0


def test_gulbrandsen_index_has_the_normal_reflectance_it_is_given():
    from gonio.brdf.fresnel import conductor, gulbrandsen_index

    r, g = np.meshgrid(np.linspace(0.5, 0.99, 7), np.linspace(0.0, 1.0, 5))
    eta, k = gulbrandsen_index(r, g)
    np.testing.assert_allclose(conductor(np.ones(1), eta.ravel(), k.ravel())[0], r.ravel(), rtol=1e-9)
    assert np.all(k[0] < 1e-5) and np.all(k[1:] > 0.1)  # edge tint 0: the dielectric of that F(0)


def test_abc_smooth_conductor_kernel_matches_the_model():
    from gonio.fit.kernels import kernel_for
    from gonio.fit.layout import Basis, Layout

    from .conftest import synth

    s = prepare(synth("abc-smooth-conductor", {"kd": 0.01, "A": 50.0, "B": 3e3, "C": 1.7, "f0": 0.8, "edge": 0.4},
                      n=300))
    L = Layout("abc-smooth-conductor", {})
    fast = Basis(L, s, kernel_for(L))(np.array([3e3, 1.7, 0.8, 0.4]))
    slow = Basis(L, s, None)(np.array([3e3, 1.7, 0.8, 0.4]))
    for a, b in zip(fast[1], slow[1]):
        np.testing.assert_allclose(np.broadcast_to(a[:, None], b.shape), b, rtol=1e-12, atol=1e-300)


@pytest.fixture(scope="module")
def dim_metal():
    """A metal as MERL tables show one (issue 29): its lobe reflects 0.08 of the light at normal incidence and rises
    towards grazing as a dielectric's does (Schlick f0 0.08), which a free Fresnel factor fits exactly."""
    from .conftest import synth

    return synth("microfacet", {"kd": 0.002, "ks": 1.0, "alpha": 0.15, "f0": 0.08}, n=400)


def test_a_declared_metal_gets_a_metal_fresnel_even_where_a_dielectric_shape_fits_better(dim_metal):
    from gonio.fit.select import lobe_f0s

    kw = dict(criterion="cv", widen=False, n_starts=1, folds=2)
    pair = ("dupuy2015", "dupuy2015-conductor")  # the same tabulated D, with a free Fresnel table or a conductor's
    sel = select(dim_metal, pair, metal=True, **kw)
    row = {r["model"]: r for r in sel.candidates}
    assert sel.model_name == "dupuy2015-conductor" and min(lobe_f0s(sel.params)) >= 0.5, sel.params
    free, cond = row["dupuy2015"], row["dupuy2015-conductor"]
    assert free["score"] + free["cv_se"] < cond["score"]  # the free table fits better, beyond one SE (undeclared: it)...
    assert "excluded" in row["dupuy2015"]["reason"]  # ...and is excluded: the declaration is a constraint
    assert any("declared a metal" in n and "dupuy2015 " in n and "standard errors" in n for n in sel.notes)


def test_the_conductor_data_driven_model_searches_metals_only(dim_metal):
    from gonio.brdf.fresnel import conductor

    r = fit(dim_metal, "dupuy2015-conductor", report=False)
    f0 = conductor(np.ones(1), np.asarray(r.params["eta"]), np.asarray(r.params["k"]))[0]
    assert np.all(f0 >= 0.5 - 1e-9), f0  # was a dielectric's 0.07 (eta 1.7, k 0) on a MERL metal
    assert "f0" in r.at_bound  # the data would go lower: said, not hidden


def test_abc_smooth_conductor_recovers_a_conductor_and_says_what_its_scale_means():
    from .conftest import synth

    truth = {"kd": 0.003, "A": [300.0, 250.0, 200.0], "B": 3e3, "C": 1.5, "f0": 0.6, "edge": 0.3}
    r = fit(synth("abc-smooth-conductor", truth, n=600, noise=0.0), "abc-smooth-conductor", report=False, n_starts=1)
    assert r.params["f0"] == pytest.approx(0.6, rel=1e-3) and r.params["edge"] == pytest.approx(0.3, rel=1e-2)
    assert r.params["B"] == pytest.approx(3e3, rel=1e-3)
    scale = np.asarray(r.params["A"]) * abc_smooth_albedo(r.params["B"], r.params["C"])
    assert any("a conductor's Fresnel: index" in n and f"{scale[0]:.3g}" in n for n in r.notes), r.notes
