"""Fitting and selection that hold on measured-like data (issue 14), on synthetic tables only."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.errors import ConfigError
from gonio.fit import fit
from gonio.fit.energy import albedo_check
from gonio.fit.metrics import cbrt_error, image_error
from gonio.fit.data import prepare
from gonio.fit.select import select
from gonio.geometry import dirs_from_half_diff
from gonio.io.merl import cell_directions
from gonio.samples import SampleSet

from tests.fit.conftest import synth


@pytest.fixture(scope="module")
def merl_cells():
    """25,000 random MERL cell centres with both directions within 80° of the normal (seeded): the
    table's own sampling, dense near the specular peak."""
    wi, wo, above = cell_directions()
    ok = above & (wi[..., 2] > np.cos(np.radians(80))) & (wo[..., 2] > np.cos(np.radians(80)))
    idx = np.random.default_rng(5).choice(np.flatnonzero(ok), 25_000, replace=False)
    return wi.reshape(-1, 3)[idx], wo.reshape(-1, 3)[idx]


@pytest.fixture(scope="module")
def chrome_like(merl_cells):
    """A chrome-like table: a razor-thin Beckmann peak (α = 0.005) over a diffuse floor kd = 0.003. The
    fitted lambert+ggx cannot match the peak's shape exactly, as on real chrome."""
    wi, wo = merl_cells
    truth = make("lambert+beckmann", **{"diffuse.albedo": 0.003, "lobe1.alpha": 0.005, "lobe1.ks": 0.8})
    return prepare((wi, wo, truth.eval(wi, wo)), source="chrome-like")


def test_chrome_like_table_gets_its_small_diffuse_albedo(chrome_like):
    r = fit(chrome_like, "lambert+ggx", report=False)
    assert r.loss == "robust"  # the default without uncertainties
    np.testing.assert_allclose(r.params["diffuse.albedo"], 0.003, atol=0.01)
    assert r.params["lobe1.alpha"] < 0.01  # a razor-thin lobe (GGX's α for a Beckmann peak is not the same α)


def test_metrics_zero_for_the_truth_and_larger_for_a_wrong_model(merl_cells):
    wi, wo = merl_cells
    truth = make("lambert+ggx", **{"diffuse.albedo": [0.3, 0.2, 0.1], "lobe1.alpha": 0.2, "lobe1.ks": 0.5})
    d = prepare((wi, wo, truth.eval(wi, wo)))
    assert cbrt_error(truth.eval(d.wi, d.wo), d.y, d.cos_i) < 1e-12
    good = image_error(truth, d)
    wrong = make("lambert+ggx", **{"diffuse.albedo": [0.3, 0.2, 0.1], "lobe1.alpha": 0.1, "lobe1.ks": 0.5})
    assert good is not None and good < 0.1  # nearest-sample lookup of sparse samples: a floor
    assert image_error(wrong, d) > 2 * good
    assert cbrt_error(wrong.eval(d.wi, d.wo), d.y, d.cos_i) > 0.01


def test_two_lobes_are_split_by_shape_not_by_colour():
    truth = {"diffuse.albedo": [0.02, 0.02, 0.02], "lobe1.ks": [0.3, 0.3, 0.3], "lobe1.alpha": 0.04,
             "lobe1.f0": 1.0, "lobe2.ks": [0.4, 0.12, 0.03], "lobe2.alpha": 0.3, "lobe2.f0": 1.0}
    s = synth("lambert+2ggx", truth, n=3000, seed=4)
    r = fit(s, "lambert+2ggx", fixed={"lobe1.f0": 1.0, "lobe2.f0": 1.0}, report=False)
    p = r.params
    assert p["lobe1.alpha"] == pytest.approx(0.04, rel=0.15) and p["lobe2.alpha"] == pytest.approx(0.3, rel=0.15)
    ks1, ks2 = np.array(p["lobe1.ks"]), np.array(p["lobe2.ks"])
    assert ks1.max() / ks1.min() < 1.3  # the narrow lobe stays grey: no lobe takes one channel
    np.testing.assert_allclose(ks2, truth["lobe2.ks"], rtol=0.15, atol=0.01)


def test_two_lobe_search_keeps_lobes_apart_in_width():
    # a single coloured lobe: a second lobe may only be at least twice as broad, never a colour twin
    s = synth("lambert+ggx", {"diffuse.albedo": 0.05, "lobe1.ks": [0.5, 0.2, 0.05], "lobe1.alpha": 0.2,
                              "lobe1.f0": 1.0}, n=2000, seed=2)
    p = fit(s, "lambert+2ggx", report=False).params
    assert p["lobe2.alpha"] >= 1.99 * p["lobe1.alpha"]


def _anisotropic_samples():
    """Ward (αx 0.08, αy 0.3) at 600 (θh, θd, φd) points, each seen at 8 azimuths φh of the half vector
    (a turntable): what gonio.tabulate's isotropy check needs to see the φh dependence."""
    rng = np.random.default_rng(9)
    n = 600
    th, td, pd = rng.uniform(0.02, 0.5, n), rng.uniform(0.05, 0.7, n), rng.uniform(0, np.pi, n)
    ph = (np.arange(8) * np.pi / 4)[:, None] + rng.uniform(0, 0.1, (8, n))
    wi, wo = dirs_from_half_diff(np.broadcast_to(th, ph.shape), ph, np.broadcast_to(td, ph.shape),
                                 np.broadcast_to(pd, ph.shape))
    wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
    ok = (wi[:, 2] > 0.2) & (wo[:, 2] > 0.2)
    wi, wo = wi[ok], wo[ok]
    f = make("ward", kd=0.1, ks=0.4, alpha_x=0.08, alpha_y=0.3).eval(wi, wo)
    y = f * (1 + 0.01 * rng.standard_normal(f.shape))
    return SampleSet(wi, wo, y, 0.01 * f)


def test_select_adds_an_anisotropic_candidate_for_anisotropic_data():
    sel = select(_anisotropic_samples(), ["lambert", "blinn-phong", "microfacet"])
    assert sel.model_name == "ward"
    assert any("anisotropic" in n for n in sel.notes)
    assert sel.params["alpha_x"] == pytest.approx(0.08, rel=0.1)


def test_unknown_candidate_is_refused_in_one_line(tmp_path, capsys):
    s = synth("lambert", {"albedo": 0.5}, n=200)
    with pytest.raises(ConfigError, match="foo") as exc:
        select(s, ["foo", "lambert"])
    assert "\n" not in str(exc.value) and "unknown model" in str(exc.value)


def test_energy_check_flags_albedo_above_one():
    bad = make("lambert+ggx", **{"diffuse.albedo": 0.9, "lobe1.ks": 0.9, "lobe1.alpha": 0.3})
    good = make("lambert+ggx", **{"diffuse.albedo": 0.4, "lobe1.ks": 0.5, "lobe1.alpha": 0.3})
    assert not albedo_check(bad)["ok"] and albedo_check(bad)["albedo_max"] > 1.2
    assert albedo_check(good)["ok"]
    # an unnormalized lobe is integrated: ABC with a huge scale is caught
    assert not albedo_check(make("abc", kd=0.5, A=50.0, B=10.0, C=1.0))["ok"]


def test_parameters_at_a_bound_are_reported_in_table_and_json(tmp_path, capsys):
    s = synth("microfacet", {"kd": [0.0, 0.2, 0.3], "ks": 0.5, "alpha": 0.15, "f0": 1.0}, n=1500, seed=3)
    r = fit(s, "microfacet")
    assert r.at_bound["kd"] == {"r": "lower 0"}
    assert "AT BOUND: r lower 0" in "\n".join(r.summary_lines())
    report = json.loads(r.to_json())
    assert report["at_bound"]["kd"] == {"r": "lower 0"}
    assert set(report["metrics"]) == {"cbrt_rel", "image_rel", "delta_e"} and report["energy"]["ok"]


def test_gtr_kernel_matches_the_model():
    from gonio.fit.kernels import kernel_for
    from gonio.fit.layout import Basis, Layout

    s = prepare(synth("gtr", {"kd": 0.2, "ks": 0.5, "alpha": 0.3, "gamma": 1.3}, n=300))
    for fixed, shape in (({}, [0.23, 1.4, 0.3]), ({"f0": [0.9, 0.5, 0.2]}, [0.23, 0.8])):
        L = Layout("gtr", fixed, () if fixed else ("f0",))
        assert kernel_for(L) is not None
        fast = Basis(L, s, kernel_for(L))(np.array(shape))
        slow = Basis(L, s, None)(np.array(shape))
        for a, b in zip(fast[1], slow[1]):
            np.testing.assert_allclose(np.broadcast_to(a if a.ndim == 2 else a[:, None], b.shape), b, rtol=1e-12,
                                       atol=1e-300)


def test_large_tables_select_on_a_subset_and_report_on_all_samples():
    # 50,000 MERL cells (> 2 × SELECT_N): candidates fitted on 20,000, scored on another 20,000
    wi, wo, above = cell_directions()
    ok = above & (wi[..., 2] > 0.2) & (wo[..., 2] > 0.2)
    idx = np.random.default_rng(1).choice(np.flatnonzero(ok), 50_000, replace=False)
    wi, wo = wi.reshape(-1, 3)[idx], wo.reshape(-1, 3)[idx]
    truth = make("microfacet", kd=[0.3, 0.2, 0.1], ks=0.5, alpha=0.2, f0=1.0)
    sel = select((wi, wo, truth.eval(wi, wo)), ["lambert", "microfacet"])
    assert sel.model_name == "microfacet" and sel.criterion == "cv"
    assert any("20000 of 50000" in n for n in sel.notes)
    assert any("more its rendered spheres show" in n for n in sel.notes)  # the highlight's samples are fitted (issue 29)
    assert sel.winner.n_used == 50_000  # refitted on all samples (warm-started) below REFIT_MAX
    assert sel.winner.metrics["cbrt_rel"] < 1e-3 and sel.winner.energy["ok"]
    np.testing.assert_allclose(sel.params["kd"], [0.3, 0.2, 0.1], rtol=1e-3)


def test_cli_refuses_an_unknown_candidate_before_fitting(tmp_path, capsys):
    from gonio.io.merl import MerlTable, write_merl

    path = tmp_path / "lambert.binary"  # Lambert albedo 0.5 in every cell: a valid table, without evaluating a model
    write_merl(path, MerlTable(np.full((90, 90, 180, 3), 0.5 / np.pi)))
    assert main(["fit", str(path), "--select", "--candidates", "foo,lambert"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "foo" in err and "unknown model" in err


def test_abc_smooth_kernel_matches_the_model():
    from gonio.fit.kernels import kernel_for
    from gonio.fit.layout import Basis, Layout

    s = prepare(synth("abc-smooth", {"kd": 0.01, "A": 50.0, "B": 3e3, "C": 1.7, "eta": 2.3}, n=300))
    for fixed, shape in (({}, [3e3, 1.7, 2.3]), ({"eta": 1.6}, [20.0, 0.9])):
        L = Layout("abc-smooth", fixed)
        assert kernel_for(L) is not None
        fast = Basis(L, s, kernel_for(L))(np.array(shape))
        slow = Basis(L, s, None)(np.array(shape))
        for a, b in zip(fast[1], slow[1]):
            np.testing.assert_allclose(np.broadcast_to(a[:, None], b.shape), b, rtol=1e-12,
                                       atol=1e-300)


def test_polished_metal_peak_that_widens_towards_grazing_is_fitted_by_abc_smooth(merl_cells):
    # a Rayleigh-Rice peak (its width in theta_h grows as 1/cos theta_d, as on measured chrome) with a
    # dielectric-like Fresnel rise: the fit finds the narrow basin (B ~ 4e4 of [1e-2, 1e8], eta ~ 2) rather
    # than the metal-like eta = 100 one, and nothing is reported at a bound
    wi, wo = merl_cells[0][:6000], merl_cells[1][:6000]
    truth = make("abc-smooth", kd=[0.002, 0.0015, 0.0017], A=[3500.0, 3700.0, 3700.0], B=3.6e4, C=1.76, eta=2.3)
    d = prepare((wi, wo, truth.eval(wi, wo)), source="chrome-like")
    r = fit(d, "abc-smooth", report=False, n_starts=1)
    assert r.params["B"] == pytest.approx(3.6e4, rel=0.05) and r.params["eta"] == pytest.approx(2.3, rel=0.05)
    np.testing.assert_allclose(r.params["kd"], [0.002, 0.0015, 0.0017], rtol=0.05)
    assert r.at_bound == {}


def test_log_searched_width_far_from_its_floor_is_not_reported_at_a_bound():
    from gonio.fit.fit import bound_report
    from gonio.fit.layout import model_class

    cls = model_class("blinn-phong")  # exponent in [0, 1e6], searched in log space from 1
    assert bound_report(cls, {"exponent": 500.0}, {"exponent": 1.0}) == {}
    assert bound_report(cls, {"exponent": 1.0}, {"exponent": 1.0}) == {"exponent": {"value": "lower 1"}}
    assert "exponent" in bound_report(cls, {"exponent": 1e6}, {"exponent": 1.0})


def test_fix_accepts_the_names_fit_prints_at_the_api_level():
    from gonio.fit.layout import model_class, resolve_fixed

    cls = model_class("lambert+2ggx")
    assert resolve_fixed(cls, {"f0": 1.0}) == {"lobe1.f0": 1.0, "lobe2.f0": 1.0}
    assert resolve_fixed(cls, {"lobe1.f0": 1.0}) == {"lobe1.f0": 1.0}
    assert resolve_fixed(cls, {"lobe2.ks.r": 0.1, "lobe2.ks.g": 0.2, "lobe2.ks.b": 0.3}) == {"lobe2.ks": [0.1, 0.2, 0.3]}
    with pytest.raises(ConfigError, match=r"unknown parameter; lambert\+2ggx has diffuse.albedo, .*lobe1.f0") as e:
        resolve_fixed(cls, {"lobe3.f0": 1.0})
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match=r"also give lobe1.ks.g, lobe1.ks.b"):
        resolve_fixed(cls, {"lobe1.ks.r": 0.1})
    s = synth("lambert+ggx", {"diffuse.albedo": 0.1, "lobe1.ks": 0.4, "lobe1.alpha": 0.2}, n=600)
    r = fit(s, "lambert+ggx", fixed={"f0": 1.0, "diffuse.albedo.r": 0.1, "diffuse.albedo.g": 0.1,
                                     "diffuse.albedo.b": 0.1}, report=False)
    assert r.params["lobe1.f0"] == [1.0, 1.0, 1.0] and r.params["diffuse.albedo"] == [0.1, 0.1, 0.1]
    assert "lobe1.f0" not in r.uncertainty
    import gonio

    r2 = gonio.fit(s, "lambert+ggx", fix={"lobe1.f0": 1.0}, report=False)  # the --fix name at the top level
    assert r2.params["lobe1.f0"] == [1.0, 1.0, 1.0] and "lobe1.f0" not in r2.uncertainty
    with pytest.raises(ConfigError, match=r"^fix = \{'f0': 1\.0\}: unknown parameter|unknown parameter; lambert has albedo"):
        gonio.fit(s, "lambert", fix={"f0": 1.0})


def test_cv_folds_in_threads_score_as_in_turn(monkeypatch):
    import gonio.fit.select as sel
    from gonio.fit.losses import LOSSES

    d = prepare(synth("lambert+ggx", {"diffuse.albedo": 0.1, "lobe1.ks": 0.4, "lobe1.alpha": 0.2}, n=600))
    start = fit(d, "lambert+ggx", report=False).params
    kw = {"report": False}
    monkeypatch.setattr(sel, "free_cores", lambda: 1)
    serial = sel._cv_score(d, "lambert+ggx", LOSSES["robust"], 3, 0, kw, start=start)
    monkeypatch.setattr(sel, "free_cores", lambda: 3)
    threaded = sel._cv_score(d, "lambert+ggx", LOSSES["robust"], 3, 0, kw, start=start)
    assert threaded == pytest.approx(serial, rel=1e-12)


def test_free_cores_counts_allowed_cpus_minus_load(monkeypatch):
    import os

    from gonio.fit.select import free_cores

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.2, 0.0, 0.0))
    assert free_cores() == 2
    monkeypatch.setattr(os, "getloadavg", lambda: (7.5, 0.0, 0.0))
    assert free_cores() == 1
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)  # taskset -c 0
    monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    assert free_cores() == 1


def test_an_error_measure_that_could_not_be_computed_is_said_so_not_printed_as_none():
    from gonio.fit.result import FitResult

    r = FitResult("lambert", {"albedo": 0.5}, {"albedo": 0.01}, "chi2", 1.0, 0.1, 10, 1,
                  metrics={"cbrt_rel": 0.2, "image_rel": None})
    line = next(x for x in r.summary_lines() if x.startswith("  error:"))
    assert "None" not in line and "image_rel n/a" in line and "too sparse" in line
    r.metrics["image_rel"] = 0.05
    line = next(x for x in r.summary_lines() if x.startswith("  error:"))
    assert "image_rel 0.05" in line and "n/a" not in line
