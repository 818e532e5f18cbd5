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


def test_data_sets_with_the_same_directions_share_their_tree_and_neighbours_not_their_pairs(monkeypatch):
    """gonio.fit.metrics.geometry_cache: the k-d tree and the 4 nearest neighbours of the samples tested depend on the
    directions alone, so a second data set with the very same directions (another table of the same MERL cells) takes
    them from the first; the pairs, which skip neighbours with equal values, are its own and those found unshared."""
    from gonio.fit import gof, metrics

    rng = np.random.default_rng(3)
    n = metrics.SHARED_GEOMETRY_MIN
    wi, wo = (np.abs(rng.normal(size=(n, 3))) + [0, 0, 0.5] for _ in range(2))
    y1 = rng.uniform(0.1, 1.0, (n, 3))
    y2 = np.ones((n, 3))  # every neighbour with the same values: no pair
    a, b, c = prepare((wi, wo, y1)), prepare((wi, wo, y2)), prepare((wo, wi, y1))
    assert metrics.data_tree(a) is metrics.data_tree(b) and metrics.data_tree(c) is not metrics.data_tree(a)
    shared = [gof._neighbour_pairs(d, 0) for d in (a, b)]
    monkeypatch.setattr(metrics, "SHARED_GEOMETRY_MIN", n + 1)
    for d, got in zip((prepare((wi, wo, y1)), prepare((wi, wo, y2))), shared):
        want = gof._neighbour_pairs(d, 0)
        assert metrics.data_tree(d) is not metrics.data_tree(a)
        assert all(np.array_equal(x, w) for x, w in zip(got, want))
    assert len(shared[0][0]) == gof.GOF_N and len(shared[1][0]) == 0
