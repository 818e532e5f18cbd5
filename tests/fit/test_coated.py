"""A conductor under a thin dielectric coat (gonio.brdf.coated, issue 29): the Fresnel factor's limits and an
independent value, the model's reciprocity and energy, and a coated-metal table fitted and selected as one."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.brdf.coated import COAT_N_MAX, COAT_N_MIN, thin_coat_fresnel
from gonio.brdf.dupuy import ndf_nodes
from gonio.brdf.fresnel import conductor, dielectric, gulbrandsen_index

COS = np.linspace(0.0, 1.0, 201)
ETA, K = gulbrandsen_index(np.array([0.6, 0.8, 0.95]), np.array([0.2, 0.5, 0.9]))


def test_without_a_coat_it_is_the_bare_conductor_and_without_the_base_the_dielectric():
    np.testing.assert_allclose(thin_coat_fresnel(COS, 1.0, ETA, K, 1.0), conductor(COS, ETA, K), rtol=1e-12, atol=1e-15)
    for n in (COAT_N_MIN, 1.5, COAT_N_MAX):
        np.testing.assert_allclose(thin_coat_fresnel(COS, n, ETA, K, 0.0),
                                   np.broadcast_to(dielectric(COS, n)[:, None], (COS.size, 3)), rtol=1e-12, atol=1e-15)


def test_normal_incidence_matches_the_two_interfaces_written_with_complex_numbers():
    n, t = 1.6, np.array([0.7, 0.3, 0.05])
    r_coat = ((n - 1) / (n + 1)) ** 2
    m = (ETA + 1j * K) / n  # the metal against the coat
    r_metal = np.abs((m - 1) / (m + 1)) ** 2
    want = r_coat + (1 - r_coat) ** 2 * t * r_metal
    np.testing.assert_allclose(thin_coat_fresnel(np.ones(1), n, ETA, K, t)[0], want, rtol=1e-12)


def test_it_is_a_reflectance_rising_to_one_at_grazing():
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = rng.uniform(COAT_N_MIN, COAT_N_MAX)
        eta, k = gulbrandsen_index(rng.uniform(0.5, 0.99, 3), rng.uniform(0, 1, 3))
        f = thin_coat_fresnel(COS, n, eta, k, rng.uniform(0, 1, 3))
        assert np.all(f >= 0) and np.all(f <= 1 + 1e-12)
        np.testing.assert_allclose(f[0], 1.0, atol=1e-12)  # grazing: the coat reflects everything


def _coated(**kw):
    c2, a2 = np.cos(ndf_nodes(90)) ** 2, 0.15 ** 2  # a GGX D (Walter et al. 2007, eq. 33) at the table's nodes
    ndf = a2 / (np.pi * (c2 * (a2 - 1) + 1) ** 2)
    p = dict(kd=[0.02, 0.015, 0.01], ndf=ndf.tolist(), ks=0.9, eta=ETA, k=K, n=1.6, t=[0.4, 0.2, 0.1])
    return make("dupuy2015-coated", **{**p, **kw})


def test_the_model_is_reciprocal_and_conserves_energy():
    from gonio.brdf.albedo import directional_albedo
    from gonio.geometry import from_spherical

    rng = np.random.default_rng(1)
    wi = from_spherical(np.arccos(rng.uniform(0.05, 1, 500)), rng.uniform(0, 2 * np.pi, 500))
    wo = from_spherical(np.arccos(rng.uniform(0.05, 1, 500)), rng.uniform(0, 2 * np.pi, 500))
    m = _coated()
    np.testing.assert_array_equal(m.eval(wi, wo), m.eval(wo, wi))
    for n in (COAT_N_MIN, COAT_N_MAX):
        rho = directional_albedo(_coated(kd=0.0, ks=1.0, n=n, t=1.0), np.radians([0, 40, 80]))
        assert np.all(rho <= 1 + 5e-3) and np.all(rho > 0.3), rho


@pytest.fixture(scope="module")
def coated_table():
    """A coated metal's table (issue 29's alum-bronze in kind): a GGX-like D, a copper-like conductor under a coat of
    index 1.6 that lets 40/20/10 % through, 1 % noise."""
    from .conftest import synth

    m = _coated()
    return synth(m.name, m.params, n=1500)


def test_a_declared_metal_with_a_coat_gets_the_coated_fit_and_its_coat(coated_table, tmp_path):
    import gonio

    from gonio.fit.select import _not_a_metal, select

    sel = select(coated_table, ("dupuy2015-conductor", "dupuy2015-coated"), metal=True, widen=False)
    assert sel.model_name == "dupuy2015-coated", [(r["model"], r.get("score")) for r in sel.candidates]
    p = sel.params
    assert not _not_a_metal(p)
    sigma_n = sel.winner.uncertainty["n"]
    assert np.isfinite(sigma_n) and 0 < sigma_n < 0.05
    assert COAT_N_MIN <= p["n"] <= COAT_N_MAX and abs(p["n"] - 1.6) <= 3 * sigma_n
    f0 = conductor(np.ones(1), np.asarray(p["eta"]), np.asarray(p["k"]))[0]
    assert np.all(f0 >= 0.5 - 1e-9) and np.all(np.asarray(p["k"]) >= 0.94 - 1e-9)  # an absorbing conductor
    # what the data determine of the metal: the light it sends back through the coat at normal incidence, t F_c(0)
    # (t and the metal's F(0) trade off along it; the fit's note says so and prints the product)
    np.testing.assert_allclose(_through(p), _through(_coated().params), rtol=0.05)
    assert any("coat index" in n for n in sel.winner.notes) and any("trade off" in n for n in sel.winner.notes)
    sel.winner.to_json(tmp_path / "fit.json")  # the fit file loads as the same model
    wi, wo = coated_table.wi[:50], coated_table.wo[:50]
    np.testing.assert_allclose(gonio.load(str(tmp_path / "fit.json")).eval(wi, wo), sel.model.eval(wi, wo), rtol=1e-9)


def _through(p):
    m = (np.asarray(p["eta"]) + 1j * np.asarray(p["k"])) / p["n"]
    return np.asarray(p["t"]) * np.abs((m - 1) / (m + 1)) ** 2
