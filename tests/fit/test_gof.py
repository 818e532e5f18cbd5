"""Selection notices a model that does not fit the data, widens its candidates, and says when none fits
(issue 29)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.fit.data import prepare
from gonio.fit.fit import fit
from gonio.fit.gof import MAX_RATIO, goodness_of_fit
from gonio.fit.losses import LOSSES
from gonio.fit.select import DEFAULT_CANDIDATES, LARGE_TABLE_CANDIDATES, METAL_CANDIDATES, WIDEN_CANDIDATES, select
from gonio.samples import SampleSet

from .conftest import synth


def test_a_rough_diffuse_material_gets_oren_nayar_from_the_default_candidates():
    s = synth("oren-nayar", {"albedo": [0.5, 0.35, 0.25], "sigma": 0.5}, n=700)
    sel = select(s)
    assert sel.model_name == "oren-nayar" and sel.status == "ok" and not sel.misfit
    assert sel.winner.goodness["fits"] and sel.winner.goodness["chi2_red"] < 1.2
    np.testing.assert_allclose(sel.params["albedo"], [0.5, 0.35, 0.25], rtol=0.01)
    assert any("no candidate fits" in n and "added oren-nayar" in n for n in sel.notes)
    rows = {r["model"]: r for r in sel.candidates}
    assert not rows["lambert"]["fits"] and rows["lambert"]["fit_ratio"] > 50


def _retroreflector(n=700) -> SampleSet:
    """A Lambertian floor and a lobe around the *incident* direction (f depends on wi·wo): no candidate has one."""
    s = synth("lambert", {"albedo": 0.2}, n=n)
    mirror = s.wo * np.array([-1.0, -1.0, 1.0])
    y = make("phong", kd=0.2, ks=0.5, exponent=30.0).eval(s.wi, mirror)
    y = y * (1 + 0.01 * np.random.default_rng(2).standard_normal(y.shape))
    return SampleSet(s.wi, s.wo, y, 0.01 * np.abs(y) + 1e-9)


def test_a_material_no_candidate_fits_is_reported_as_such(capsys):
    sel = select(_retroreflector(), ("lambert", "microfacet"))
    assert sel.status == "misfit" and "no candidate fits the data" in sel.misfit
    tried = {r["model"] for r in sel.candidates}
    assert set(WIDEN_CANDIDATES) <= tried  # widened before giving up
    assert not any(r.get("fits") for r in sel.candidates if "fits" in r)
    assert "NO CANDIDATE FITS" in "\n".join(sel.table_lines())
    assert "DOES NOT FIT" in "\n".join(sel.winner.summary_lines())
    assert sel.to_dict()["status"] == "misfit"


def test_residual_structure_is_found_without_uncertainties():
    s = _retroreflector(n=900)
    d = prepare((s.wi, s.wo, s.f))
    bad = fit(d, "lambert", report=False).build().eval(d.wi, d.wo)
    g = goodness_of_fit(bad, d, LOSSES["robust"], 3)
    assert g["test"] == "residual structure" and not g["fits"] and g["ratio"] > MAX_RATIO
    truth = make("phong", kd=0.2, ks=0.5, exponent=30.0).eval(d.wi, d.wo * np.array([-1.0, -1.0, 1.0]))
    good = goodness_of_fit(truth, d, LOSSES["robust"], 3)  # the model that made the data: only noise is left
    assert good["fits"] and abs(good["rho"]) < 0.15


def test_help_lists_the_candidates_select_uses(capsys):
    with pytest.raises(SystemExit):
        main(["fit", "--help"])
    text = " ".join(capsys.readouterr().out.split()).replace("- ", "-")
    for name in DEFAULT_CANDIDATES + LARGE_TABLE_CANDIDATES + WIDEN_CANDIDATES + METAL_CANDIDATES:
        assert name in text, name
    assert ",".join(DEFAULT_CANDIDATES) in text


def test_the_neighbour_pairs_are_found_once_and_give_the_uncached_answer():
    s = _retroreflector(n=600)
    d = prepare((s.wi, s.wo, s.f))
    m = fit(d, "lambert", report=False).build().eval(d.wi, d.wo)
    first = goodness_of_fit(m, d, LOSSES["robust"], 3)
    assert ("gof_pairs", 0) in d._kernel_cache  # found once, reused by the next candidate on the same data
    again = goodness_of_fit(m * 1.1, d, LOSSES["robust"], 3)
    fresh = prepare((s.wi, s.wo, s.f))  # no cache: the pairs found anew
    assert goodness_of_fit(m * 1.1, fresh, LOSSES["robust"], 3)["rho"] == again["rho"]
    assert first["rho"] != again["rho"]
