"""Model selection chooses what the data require, and not more."""

from __future__ import annotations

import pytest

from gonio.errors import ConfigError
from gonio.fit.select import select

from .conftest import synth

CANDS = ("lambert", "microfacet", "lambert+2ggx")


def _chosen(sel):
    assert sum(r["status"] == "chosen" for r in sel.candidates) == 1
    assert all("reason" in r for r in sel.candidates)
    return sel.winner.model_name


def test_bic_chooses_lambert_for_lambertian_data():
    sel = select(synth("lambert", {"albedo": [0.3, 0.5, 0.7]}, n=800), CANDS)
    assert sel.criterion == "bic" and _chosen(sel) == "lambert"


def test_bic_chooses_one_lobe_for_a_one_lobe_material():
    s = synth("microfacet", {"kd": [0.3, 0.2, 0.1], "ks": 0.5, "alpha": 0.2}, n=800)
    assert _chosen(select(s, CANDS)) == "microfacet"


def test_bic_chooses_two_lobes_for_a_two_lobe_material():
    truth = {"diffuse.albedo": [0.2, 0.3, 0.1], "lobe1.ks": [0.3, 0.3, 0.4], "lobe1.alpha": 0.06,
             "lobe2.ks": [0.3, 0.2, 0.1], "lobe2.alpha": 0.45}
    sel = select(synth("lambert+2ggx", truth, n=1000), CANDS, n_starts=2)
    assert _chosen(sel) == "lambert+2ggx"
    assert sel.winner.params["lobe1.alpha"] == pytest.approx(0.06, rel=0.03)


def test_too_small_sigmas_do_not_buy_extra_lobes():
    s = synth("microfacet", {"kd": [0.3, 0.2, 0.1], "ks": 0.5, "alpha": 0.2, "f0": 0.05}, n=800)
    s.sigma[...] = s.sigma / 5.0  # stated uncertainties 5x too small: chi2_red ~ 25 for every candidate
    sel = select(s, CANDS)
    assert _chosen(sel) == "microfacet"
    rows = {r["model"]: r for r in sel.candidates}
    assert rows["lambert+2ggx"]["chi2_red"] > 10 and rows["microfacet"]["chi2_scale"] > 10
    assert "chi2 divided by" in rows["microfacet"]["reason"]
    assert sel.adjustment and sel.to_dict()["adjustment"] == sel.adjustment


def test_cv_without_uncertainties_uses_the_one_se_rule():
    s = synth("lambert", {"albedo": 0.4}, n=300)
    sel = select((s.wi, s.wo, s.f), ("lambert", "microfacet"), folds=3)
    assert sel.criterion == "cv" and _chosen(sel) == "lambert"
    assert all("cv" in r and "cv_se" in r for r in sel.candidates)


def test_failed_candidates_are_listed_and_bad_criterion_rejected():
    s = synth("lambert", {"albedo": 0.4}, n=3).subset(slice(0, 3))
    sel = select(s, ("lambert", "lambert+2ggx"))
    assert _chosen(sel) == "lambert"
    assert [r["status"] for r in sel.candidates] == ["chosen", "failed"]
    with pytest.raises(ConfigError, match="criterion"):
        select(s, ("lambert",), criterion="vibes")
