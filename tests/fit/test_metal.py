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


def test_a_sample_declared_a_metal_flags_a_dielectric_fresnel_and_says_the_data_reject_a_metal():
    from gonio.fit.select import lobe_f0s

    from .conftest import synth

    plastic = synth("microfacet", {"kd": [0.3, 0.2, 0.1], "ks": 0.6, "alpha": 0.3, "f0": 0.04}, n=800)
    kw = dict(criterion="cv", widen=False, n_starts=1)
    sel = select(plastic, ("lambert", "microfacet"), metal=True, **kw)
    row = {r["model"]: r for r in sel.candidates}
    assert sel.model_name == "microfacet" and lobe_f0s(sel.params)[0] < 0.1  # the data decide, not the prior
    assert "not a metal's Fresnel" in row["microfacet"]["reason"] and "unphysical" not in row["lambert"]
    assert any("declared a metal" in n and "lambert" in n for n in sel.notes)
    plain = select(plastic, ("lambert", "microfacet"), **kw)
    assert plain.model_name == "microfacet" and "not a metal" not in " ".join(r["reason"] for r in plain.candidates)
    assert lobe_f0s({"eta": [0.2, 0.2, 0.5], "k": [3.0, 2.5, 2.0]})[0] > 0.8  # a complex index: a metal's f0
