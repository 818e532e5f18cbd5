"""The data-driven microfacet model of Dupuy et al. 2015 (gonio.brdf.dupuy, gonio.fit.dupuy; issue 29)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.brdf.dupuy import G1_NODES, N_FRESNEL, ndf_nodes, normalization, smith_g1_table
from gonio.errors import ConfigError, DataError
from gonio.fit.data import prepare
from gonio.fit.dupuy import power_iteration
from gonio.fit.fit import fit
from gonio.fit.metrics import cbrt_error
from gonio.fit.result import FitResult


def _ggx(theta, alpha):
    c2 = np.cos(theta) ** 2
    return alpha ** 2 / (np.pi * (c2 * (alpha ** 2 - 1) + 1) ** 2)


def _cosine_pairs(n, seed):
    rng = np.random.default_rng(seed)

    def dirs():
        th, ph = np.arccos(np.sqrt(rng.random(n))), 2 * np.pi * rng.random(n)
        return np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)

    return dirs(), dirs()


@pytest.fixture(scope="module")
def plastic():
    """6,000 cosine-distributed pairs of a GGX plastic (coloured diffuse, grey f0 0.05, alpha 0.15), exact."""
    wi, wo = _cosine_pairs(6000, 2)
    truth = make("microfacet", kd=[0.3, 0.12, 0.05], ks=1.0, alpha=0.15, f0=0.05)
    return prepare((wi, wo, truth.eval(wi, wo))), truth


def test_smith_g1_from_a_tabulated_ggx_distribution_is_ggx_smith_g1():
    alpha = 0.2
    ndf = _ggx(ndf_nodes(90), alpha)
    assert normalization(ndf) == pytest.approx(1.0, abs=2e-3)
    g1 = smith_g1_table(ndf)
    tk = np.linspace(0, np.pi / 2, G1_NODES)[:-1]
    exact = 2 / (1 + np.sqrt(1 + alpha ** 2 * np.tan(tk) ** 2))
    assert np.max(np.abs(g1[:-1] - exact)) < 1e-3


def test_power_iteration_recovers_the_distribution_from_back_scattering():
    # f(k, k) = F D(k) G1(k) / (4 cos^2) with G1 = cos / A(k): the iteration's fixed point is D
    alpha = 0.3
    theta = ndf_nodes(90)
    d_true = _ggx(theta, alpha)
    g1 = np.interp(theta, np.linspace(0, np.pi / 2, G1_NODES), smith_g1_table(d_true))
    retro = 0.7 * d_true * g1 / (4 * np.cos(theta) ** 2 + 1e-300)
    d = power_iteration(retro[:-1].tolist() + [0.0])
    ok = theta < np.radians(75)
    assert np.max(np.abs(d[ok] - d_true[ok]) / d_true[ok]) < 0.01


def test_fit_recovers_a_microfacet_plastic_and_its_colours(plastic):
    d, truth = plastic
    r = fit(d, "dupuy2015")
    assert r.model_name == "dupuy2015"
    assert np.allclose(r.params["kd"], [0.3, 0.12, 0.05], atol=0.01)
    fr = np.asarray(r.params["fresnel"])
    assert fr.shape == (N_FRESNEL, 3) and np.allclose(fr[0], 0.05, atol=0.01)  # grey Fresnel at normal incidence
    assert cbrt_error(r.model.eval(d.wi, d.wo), d.y, d.cos_i) < 0.01
    assert r.energy["ok"] and r.goodness
    assert "Dupuy et al. 2015" in r.notes[0]


def test_fit_json_round_trips_and_is_evaluable(plastic, tmp_path):
    d, _ = plastic
    r = fit(d, "dupuy2015", report=False, image_weight=0)
    path = tmp_path / "fit.json"
    r.to_json(path)
    import gonio

    back = gonio.load(str(path))
    assert np.allclose(back.eval(d.wi[:50], d.wo[:50]), r.model.eval(d.wi[:50], d.wo[:50]), rtol=1e-12)
    assert "table 90: " in "\n".join(r.summary_lines())  # a table is summarized, not printed in full
    assert FitResult.from_json(path.read_text()).model_name == "dupuy2015"


def test_bad_tables_are_one_line_errors():
    with pytest.raises(ConfigError, match="dupuy2015.ndf.*list of 2 to"):
        make("dupuy2015", ndf=[1.0], fresnel=[[0.5] * 3] * 4)
    with pytest.raises(ConfigError, match="dupuy2015.fresnel.*rows of 3"):
        make("dupuy2015", ndf=[1.0, 1.0], fresnel=[0.5, 0.5])
    with pytest.raises(ConfigError, match="dupuy2015.fresnel.*in \\[0, 1\\]"):
        make("dupuy2015", ndf=[1.0, 1.0], fresnel=[[1.5, 0, 0], [0, 0, 0]])
    with pytest.raises(ConfigError, match="zero everywhere"):
        make("dupuy2015", ndf=[0.0, 0.0], fresnel=[[0.5] * 3] * 2)
    with pytest.raises(ConfigError, match="none can be fixed"):
        fit((np.array([[0, 0, 1.0]] * 50), np.array([[0, 0, 1.0]] * 50), np.ones((50, 3))), "dupuy2015",
            fixed={"kd": 0.1})
    with pytest.raises(ConfigError, match="only the data-driven model"):
        fit((np.array([[0, 0, 1.0]] * 50), np.array([[0, 0, 1.0]] * 50), np.ones((50, 3))), "lambert", image_weight=1)


def test_too_few_samples_for_its_tables_is_a_data_error():
    wi, wo = _cosine_pairs(30, 5)
    with pytest.raises(DataError, match="cannot determine the .* parameters of dupuy2015"):
        fit((wi, wo, np.full((30, 3), 0.1)), "dupuy2015")


def test_fresnel_on_a_bound_is_named_and_has_no_uncertainty():
    # a pure red conductor: the green and blue Fresnel entries sit on 0
    wi, wo = _cosine_pairs(4000, 7)
    truth = make("microfacet", kd=0.0, ks=1.0, alpha=0.2, f0=[0.9, 0.0, 0.0])
    r = fit(prepare((wi, wo, truth.eval(wi, wo) + 1e-4)), "dupuy2015", report=False, image_weight=0)
    assert "fresnel" in r.at_bound and "g" in r.at_bound["fresnel"]
    assert np.isnan(np.asarray(r.uncertainty["fresnel"])[:, 1]).any()
    assert np.all(np.isfinite(np.asarray(r.uncertainty["fresnel"])[:3, 0]))


def test_mitsuba_export_is_the_closest_analytic_material_with_its_error(plastic, tmp_path):
    from gonio.io.exports import exported, to_mitsuba

    d, _ = plastic
    r = fit(d, "dupuy2015", report=False, image_weight=0)
    with pytest.raises(ConfigError, match="approx=True"):  # no tabulated-NDF plugin: never silently approximate
        to_mitsuba(r, tmp_path / "a.xml")
    to_mitsuba(r, tmp_path / "b.xml", approx=True)
    assert (tmp_path / "b.xml").is_file()
    ex = exported(r, "mitsuba", approx=True)
    assert 0 < ex.error < 0.2  # the closest analytic material, its error stated


def test_cli_fits_it_and_writes_a_json_gonio_loads(plastic, tmp_path, capsys):
    import gonio
    from gonio.cli.main import main
    from gonio.io.csv import write_csv
    from gonio.samples import SampleSet

    d, _ = plastic
    src = write_csv(tmp_path / "plastic.csv", SampleSet(d.wi[:3000], d.wo[:3000], d.y[:3000], 0.01 * d.y[:3000] + 1e-6))
    out = tmp_path / "fit.json"
    assert main(["fit", str(src), "--model", "dupuy2015", "--image-weight", "0", "--json", str(out)]) == 0
    assert "dupuy2015" in capsys.readouterr().out
    assert gonio.load(str(out)).eval(d.wi[:5], d.wo[:5]).shape == (5, 3)
    assert main(["fit", str(src), "--model", "lambert", "--image-weight", "1"]) == 2  # one line, before any fit
    assert "--image-weight" in capsys.readouterr().err


def test_conductor_variant_gives_a_metal_like_table_a_metal_f0_and_a_complex_index():
    from gonio.brdf.fresnel import conductor

    wi, wo = _cosine_pairs(5000, 11)
    truth = make("microfacet", kd=0.0, ks=0.6, alpha=0.1, f0=[0.95, 0.64, 0.54])  # copper-like, scaled by 0.6
    d = prepare((wi, wo, truth.eval(wi, wo)))
    r = fit(d, "dupuy2015-conductor", report=False, image_weight=0)
    f0 = conductor(np.ones(1), np.asarray(r.params["eta"]), np.asarray(r.params["k"]))[0]
    assert np.all(f0 >= 0.5), r.params  # a metal's reflectance, not a dielectric's 0.04 under a bright lobe
    assert f0[0] > f0[1] > f0[2] - 0.02  # copper's colour is in its index
    assert np.allclose(np.asarray(r.params["ks"]) * f0, [0.57, 0.384, 0.324], rtol=0.1)
    assert r.rms_rel < 0.05
    assert set(r.uncertainty) >= {"kd", "ks", "eta", "k", "ndf"}


def test_the_conductor_scan_is_the_bounded_least_squares_at_every_point():
    from gonio.brdf.fresnel import conductor
    from gonio.fit.dupuy_conductor import _BINS, _Channel

    rng = np.random.default_rng(3)
    n = 4000
    theta_d, spec, w = rng.uniform(0, 1.5, n), rng.uniform(0, 2, n), rng.uniform(0.5, 1.5, n)
    y = 0.02 + 0.3 * spec * rng.uniform(0.8, 1.2, n)
    ch = _Channel(theta_d, spec, y, w)
    eta, k = np.array([0.2, 1.5, 3.0, 9.0, 1.0]), np.array([3.0, 0.0, 2.5, 0.1, 0.0])
    obj, kd, ks = ch.solve_many(eta, k)  # all points at once
    b = np.minimum((theta_d / (0.5 * np.pi) * _BINS).astype(int), _BINS - 1)
    g = np.linspace(0, 1, 201)
    for j in range(eta.size):
        f = conductor(ch.cos, eta[j], k[j])[b]  # F constant within a theta_d bin, as the channel takes it

        def direct(a, s_):
            return np.sum(w * (a / np.pi + s_ * f * spec - y) ** 2)

        assert obj[j] == pytest.approx(direct(kd[j], ks[j]), rel=1e-9)
        assert 0 <= kd[j] <= 1 and 0 <= ks[j] <= 1
        assert obj[j] <= min(direct(a, s_) for a in g[::10] for s_ in g) * (1 + 1e-9)  # no box point is lower
        assert ch.solve(eta[j], k[j]) == pytest.approx((obj[j], kd[j], ks[j]), rel=1e-12, abs=1e-15)


def test_the_viewer_and_report_render_it(plastic):
    from gonio.report import sphere_images  # what the viewer's /sphere.png and the report's panels draw

    d, _ = plastic
    r = fit(d, "dupuy2015", report=False, image_weight=0)
    rad, img, _ = sphere_images(r.model, 30.0, size=32)
    assert np.all(np.isfinite(rad)) and rad.max() > 0 and img.max() > 0


def test_gonio_models_summarizes_its_tables(capsys):
    from gonio.cli.main import main

    assert main(["models"]) == 0
    out = capsys.readouterr().out
    assert "default table 90: " in out and "default table 10x3: 0.04 .. 0.04" in out


def test_bounded_steps_never_leave_their_bounds():
    # BVLS holds the scaled variable on its bound; unscaling rounded it past (-5e-29 < 0): Dupuy2015 then refused
    # its own table (a cross-validation fold of 20 sparse poses crashed `select`, issue 27)
    from gonio.fit.dupuy import _bounded_normal

    rng = np.random.default_rng(1)
    for _ in range(60):
        a = rng.normal(size=(30, 12)) * np.exp(8 * rng.normal(size=12))  # columns of wildly different scale
        a[:, rng.integers(0, 12, 3)] = 0.0  # nodes no sample constrains
        ata = a.T @ a + np.diag(np.where(np.diag(a.T @ a) == 0, 1e-6, 0.0))
        b = rng.normal(size=30)
        for lo, hi in ((0.0, np.inf), (0.0, 1.0)):
            x = _bounded_normal(ata, a.T @ b, lo, hi)
            assert np.all(np.isfinite(x)) and x.min() >= lo and x.max() <= hi


def test_whole_empty_ranges_of_the_tables_are_filled_from_measured_nodes_and_named():
    # a sparse set with nothing at the peak (theta_h < 6 deg) and nothing past theta_h 30 deg or theta_d 50 deg
    wi, wo = _cosine_pairs(4000, 5)
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    th, td = np.degrees(np.arccos(h[:, 2])), np.degrees(np.arccos(np.sum(wi * h, axis=1)))
    keep = np.flatnonzero((th > 6) & (th < 30) & (td < 50))[:150]
    truth = make("microfacet", kd=[0.3, 0.12, 0.05], ks=1.0, alpha=0.5, f0=0.05)
    d = prepare((wi[keep], wo[keep], truth.eval(wi[keep], wo[keep])))
    r = fit(d, "dupuy2015", report=False, image_weight=0)
    ndf, fr = np.asarray(r.params["ndf"]), np.asarray(r.params["fresnel"])
    assert np.all(np.isfinite(ndf)) and ndf.min() >= 0 and np.all(np.isfinite(fr))
    deg = np.degrees(ndf_nodes(len(ndf)))
    se = np.asarray(r.uncertainty["ndf"])
    lo, hi = deg < 5, deg > 31  # no sample's hat weight reaches these nodes
    measured = ~np.isnan(se)
    assert np.isnan(se[lo]).all() and np.isnan(se[hi]).all()
    first, last = np.flatnonzero(measured)[[0, -1]]
    # held at the nearest measured node beyond the data (the peak and the tail are not the ridge's zero)
    assert np.allclose(ndf[lo], ndf[first]) and np.allclose(ndf[hi], ndf[last]) and ndf[hi].min() > 0
    notes = " ".join(r.notes)
    assert "not measured" in notes and "of D (theta_h 0-" in notes and "of F (theta_d" in notes
    assert "not identified" in notes
