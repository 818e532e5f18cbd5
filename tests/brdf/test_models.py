"""Model contract (make, params, bounds, errors, immutability), sums, Lafortune, float32, and
regression values (computed by this code, kept apart from tests/brdf/test_reference.py)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import MODELS, make
from gonio.brdf.fresnel import schlick_rational_power
from gonio.errors import ConfigError
from gonio.geometry import from_spherical

ISSUE_NAMES = {"lambert", "phong", "blinn-phong", "cook-torrance", "microfacet", "ward", "lafortune", "oren-nayar",
               "ashikhmin-shirley"}


def test_registry_has_every_model_of_the_issue_with_its_parameters():
    assert ISSUE_NAMES <= set(MODELS)
    expect = {"phong": ["kd", "ks", "exponent"], "blinn-phong": ["kd", "ks", "exponent"],
              "cook-torrance": ["kd", "ks", "roughness", "f0"], "microfacet": ["kd", "ks", "alpha", "f0", "distribution"],
              "ward": ["kd", "ks", "alpha_x", "alpha_y"], "oren-nayar": ["albedo", "sigma"],
              "ashikhmin-shirley": ["rd", "rs", "nu", "nv"]}
    for name, keys in expect.items():
        assert list(MODELS[name].PARAMS) == keys
        assert MODELS[name].name == name


@pytest.mark.parametrize("name,field,value", [
    ("microfacet", "alpha", -1), ("microfacet", "distribution", "gauss"), ("phong", "exponent", 2e6),
    ("ward", "alpha_x", float("nan")), ("cook-torrance", "f0", [0.1, 0.2]), ("oren-nayar", "sigma", "rough"),
])
def test_bad_parameter_names_model_field_and_value(name, field, value):
    with pytest.raises(ConfigError) as e:
        make(name, source="mat.toml", **{field: value})
    msg = str(e.value)
    assert msg.startswith("mat.toml: ") and f"{name}.{field}" in msg and repr(value)[:4] in msg


def test_unknown_model_and_parameter():
    with pytest.raises(ConfigError, match="unknown model"):
        make("glossy")
    with pytest.raises(ConfigError, match="microfacet.roughness"):
        make("microfacet", roughness=0.1)


def test_immutable_params_roundtrip_and_replace():
    m = make("microfacet", kd=[0.1, 0.2, 0.3], alpha=0.2, distribution="beckmann")
    with pytest.raises(AttributeError):
        m.alpha = 0.3
    assert make("microfacet", **m.params) == m
    assert m.replace(alpha=0.3).alpha == 0.3 and m.alpha == 0.2
    assert m.params["kd"] == [0.1, 0.2, 0.3]


def test_sum_is_one_model_with_namespaced_params_kinds_and_bounds():
    m = make("lambert+2ggx", **{"diffuse.albedo": [0.2, 0.3, 0.4], "lobe1.ks": 0.3, "lobe1.alpha": 0.05,
                                "lobe2.ks": 0.2, "lobe2.alpha": 0.4})
    assert list(m.params) == ["diffuse.albedo", "lobe1.ks", "lobe1.alpha", "lobe1.f0", "lobe2.ks", "lobe2.alpha",
                              "lobe2.f0"]
    assert {k: p.kind for k, p in m.PARAMS.items()}["lobe1.alpha"] == "scalar"
    assert m.PARAMS["lobe2.ks"].kind == "rgb"
    assert m.bounds()["lobe1.alpha"] == (1e-4, 1.0)
    rng = np.random.default_rng(3)
    wi = from_spherical(rng.uniform(0, 1.5, 20), rng.uniform(0, 6, 20))
    wo = from_spherical(rng.uniform(0, 1.5, 20), rng.uniform(0, 6, 20))
    parts = (make("lambert", albedo=[0.2, 0.3, 0.4]).eval(wi, wo)
             + make("microfacet", kd=0, ks=0.3, alpha=0.05).eval(wi, wo)
             + make("microfacet", kd=0, ks=0.2, alpha=0.4).eval(wi, wo))
    np.testing.assert_allclose(m.eval(wi, wo), parts, rtol=1e-12)
    assert make("lambert+2ggx", **m.params) == m
    assert make("oren-nayar+ggx+blinn-phong").name == "oren-nayar+ggx+blinn-phong"
    with pytest.raises(ConfigError, match="unknown term"):
        make("lambert+velvet")
    with pytest.raises(ConfigError, match=r"lambert\+ggx\.lobe1\.alpha"):
        make("lambert+ggx", **{"diffuse.albedo": 0.5, "lobe1.alpha": 0})


def test_lafortune_lobes_forms_agree():
    flat = {"kd": 0.1, "lobe1.cx": -1, "lobe1.cz": 1, "lobe1.n": 30, "lobe1.rho": 5,
            "lobe2.cx": -0.5, "lobe2.cz": 0.8, "lobe2.n": 4, "lobe2.rho": [1, 0.8, 0.6]}
    a = make("lafortune", **flat)
    b = make("lafortune", kd=0.1, lobes=[(-1, 1, 30, 5), {"cx": -0.5, "cz": 0.8, "n": 4, "rho": [1, 0.8, 0.6]}])
    assert a == b and a.n_lobes == 2 and len(a.bounds()) == 9
    assert make("lafortune", lobes=3).n_lobes == 3
    # One lobe with C = (-1, 1) is Phong with rho = ks (n+2)/(2 pi).
    wi = from_spherical(0.5, 0.2)
    wo = from_spherical(0.7, 3.0)
    ph = make("phong", kd=0.1, ks=0.5, exponent=30).eval(wi, wo)
    lf = make("lafortune", kd=0.1, lobes=[(-1, 1, 30, 0.5 * 32 / (2 * np.pi))]).eval(wi, wo)
    np.testing.assert_allclose(lf, ph, rtol=1e-12)
    with pytest.raises(ConfigError, match="lafortune.lobes"):
        make("lafortune", lobes=[(1, 2)])
    with pytest.raises(ConfigError, match="lafortune.lobes"):
        make("lafortune", lobes=20)


def test_float32_close_to_float64():
    rng = np.random.default_rng(4)
    wi = from_spherical(rng.uniform(0, 1.4, 200), rng.uniform(0, 6, 200))
    wo = from_spherical(rng.uniform(0, 1.4, 200), rng.uniform(0, 6, 200))
    for name in ("phong", "microfacet", "lambert+2ggx", "ward", "ashikhmin-shirley"):
        m = make(name) if name != "lambert+2ggx" else make(name, **{"diffuse.albedo": 0.5})
        f64, f32 = m.eval(wi, wo), m.eval(wi, wo, dtype=np.float32)
        assert f32.dtype == np.float32
        np.testing.assert_allclose(f32, f64, rtol=2e-3, atol=1e-6)


def test_schlick_rational_power_exact_at_ends_and_close_in_between():
    t = np.linspace(0, 1, 101)
    for s in (1.0, 10.0, 100.0):
        r = schlick_rational_power(t, s)
        assert r[0] == 0.0 and r[-1] == 1.0
        assert np.max(np.abs(r - t**s)) < 0.2  # a qualitative approximation (see the benchmark)
    np.testing.assert_allclose(schlick_rational_power(t, 1.0), t, rtol=1e-15)
    assert schlick_rational_power(0.0, 0.0) == 1.0


# --- regression values (computed by this implementation; guard against unintended changes) ----------
REGRESSION = [
    ("cook-torrance", dict(kd=0.1, ks=0.5, roughness=0.3, f0=0.04), 0.10528262505),
    ("ward", dict(kd=0.1, ks=0.3, alpha_x=0.1, alpha_y=0.3), 0.22145038015),
    ("oren-nayar", dict(albedo=0.8, sigma=0.5), 0.19976689409),
    ("ashikhmin-shirley", dict(rd=0.5, rs=0.05, nu=100, nv=10), 0.19879776808),
    ("blinn-phong", dict(kd=0.2, ks=0.5, exponent=50), 0.54064574680),
]


@pytest.mark.parametrize("name,params,expected", REGRESSION)
def test_regression_values(name, params, expected):
    wi = from_spherical(np.radians(40), 0.3)
    wo = from_spherical(np.radians(25), 3.0)
    assert make(name, **params).eval(wi, wo)[0] == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("name, params", [("ward", {}), ("lambert+ggx", {"diffuse.albedo": 0.5}), ("abc", {})])
def test_directions_that_are_not_unit_vectors_are_refused_not_evaluated(name, params):
    """A notebook user passing [0, 0, 2] got Ward's value halved, silently (found by QA, qa-user)."""
    model = make(name, **params)
    wi, wo = np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 0.8])
    assert np.all(np.isfinite(model.eval(wi, wo)))
    with pytest.raises(ValueError, match=r"wi: directions must be unit vectors; pair 0 has length 2"):
        model.eval(2 * wi, wo)
    with pytest.raises(ValueError, match=r"wo: .*unit vectors"):
        model.eval(wi, [1.2, 0.0, 1.6])
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\) arrays"):
        model.eval(wi[:2], wo[:2])
    rng = np.random.default_rng(0)  # a large call: checked on evenly spaced pairs, compiled path or not
    big = from_spherical(np.arccos(rng.uniform(0.2, 1, 100_000)), rng.uniform(0, 2 * np.pi, 100_000))
    model.eval(big, big[::-1])
    with pytest.raises(ValueError, match="wo: directions must be unit vectors"):
        model.eval(big, 3.0 * big)
    nan = big.copy()
    nan[0] = np.nan
    with pytest.raises(ValueError, match="pair 0 has length nan"):
        model.eval(nan, big)
