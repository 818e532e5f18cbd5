"""Every model finite and >= 0 at the extremes; reciprocity; n-dimensional input shapes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gonio.brdf import MODELS, make
from gonio.geometry import from_spherical

from .strategies import NAMES, build, models, param_specs, special_pairs, unit_angles


def _edge_models(name):
    """The model with every numeric parameter at its low end, then at its high end (1e3 for inf)."""
    for end in ("lo", "hi"):
        values = {}
        for key, spec in param_specs(name).items():
            if spec.kind == "choice":
                continue
            v = getattr(spec, end)
            v = v if np.isfinite(v) else 1e3
            if spec.kind == "table":  # a tabulated function (dupuy2015): every entry at the end (a zero D is refused)
                shape = np.shape(spec.default)
                v = np.where(np.arange(shape[0]).reshape((-1,) + (1,) * (len(shape) - 1)) == 1, max(v, 1e-3), v)
                v = np.broadcast_to(v, shape).tolist()
            values[key] = v
        yield build(name, values)
        for key, spec in param_specs(name).items():
            if spec.kind == "choice":
                for c in spec.choices:
                    yield build(name, {**values, key: c})


@pytest.mark.parametrize("name", NAMES)
def test_finite_nonnegative_at_parameter_edges_and_special_directions(name):
    wi, wo = special_pairs()
    for model in _edge_models(name):
        f = model.eval(wi, wo)
        assert f.shape == wi.shape[:-1] + (3,)
        assert np.all(np.isfinite(f)), model
        assert np.all(f >= 0), model
        below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
        assert np.all(f[below] == 0.0)


@pytest.mark.parametrize("name", ["phong", "blinn-phong", "ashikhmin-shirley", "lafortune2"])
def test_huge_and_zero_exponents(name):
    wi, wo = special_pairs()
    keys = [k for k in param_specs(name) if k.endswith(("exponent", ".n", "nu", "nv"))]
    for e in (0.0, 1e-3, 1.0, 1e6):
        f = build(name, {k: e for k in keys}).eval(wi, wo)
        assert np.all(np.isfinite(f)) and np.all(f >= 0)


def test_tiny_alpha_mirror_peak_is_large_but_finite():
    wi = from_spherical(0.4, 0.0)
    wo = from_spherical(0.4, np.pi)
    for d in ("ggx", "beckmann"):
        f = make("microfacet", alpha=1e-4, distribution=d).eval(wi, wo)
        assert np.all(np.isfinite(f)) and f[0] > 1e6
    assert np.isfinite(make("cook-torrance", roughness=1e-4).eval(wi, wo)).all()
    assert np.isfinite(make("ward", alpha_x=1e-4, alpha_y=1e-4).eval(wi, wo)).all()


@given(models(), st.lists(st.tuples(unit_angles, unit_angles), min_size=1, max_size=8))
def test_property_finite_nonnegative(model, pairs):
    a = np.array(pairs)
    wi = from_spherical(a[:, 0, 0], a[:, 0, 1])
    wo = from_spherical(a[:, 1, 0], a[:, 1, 1])
    sw, so = special_pairs()
    f = model.eval(np.concatenate([wi, sw, wo]), np.concatenate([wo, so, wi]))
    assert np.all(np.isfinite(f)) and np.all(f >= 0)


RECIPROCAL = [n for n in NAMES if n == "lafortune2" or n not in MODELS or MODELS[n].reciprocal]


@given(models(RECIPROCAL), st.lists(st.tuples(unit_angles, unit_angles), min_size=1, max_size=8))
def test_property_reciprocity(model, pairs):
    a = np.array(pairs)
    wi = from_spherical(a[:, 0, 0], a[:, 0, 1])
    wo = from_spherical(a[:, 1, 0], a[:, 1, 1])
    np.testing.assert_allclose(model.eval(wi, wo), model.eval(wo, wi), rtol=1e-9, atol=1e-300)


def test_every_registered_model_claims_reciprocity():
    # All the models of issue #2 are reciprocal; the flag is what the property test selects on.
    assert all(cls.reciprocal for cls in MODELS.values())


@pytest.mark.parametrize("name", NAMES)
def test_nd_shapes_and_broadcasting(name):
    model = build(name, {k: (s.default if s.default is not None else 0.5) for k, s in param_specs(name).items()})
    rng = np.random.default_rng(1)
    wi = from_spherical(rng.uniform(0, 1.5, (2, 3, 4)), rng.uniform(0, 6, (2, 3, 4)))
    wo = from_spherical(rng.uniform(0, 1.5, (3, 1)), rng.uniform(0, 6, (3, 1)))
    f = model.eval(wi, wo)
    assert f.shape == (2, 3, 4, 3)
    flat = model.eval(*np.broadcast_arrays(wi, wo[None])).reshape(-1, 3)
    np.testing.assert_array_equal(f.reshape(-1, 3), flat)
    assert model.eval(wi[0, 0, 0], wo[0, 0]).shape == (3,)
    f32 = model.eval(wi, wo, dtype=np.float32)
    assert f32.dtype == np.float32 and f32.shape == f.shape


def test_isotropic_models_invariant_under_azimuthal_rotation():
    rng = np.random.default_rng(2)
    ti, to, pi_, po = rng.uniform(0, 1.5, 50), rng.uniform(0, 1.5, 50), rng.uniform(0, 6, 50), rng.uniform(0, 6, 50)
    for name in ("phong", "blinn-phong", "microfacet", "cook-torrance", "oren-nayar", "lafortune", "lambert+2ggx"):
        m = build(name, {k: (s.default if s.default is not None else 0.5) for k, s in param_specs(name).items()})
        a = m.eval(from_spherical(ti, pi_), from_spherical(to, po))
        b = m.eval(from_spherical(ti, pi_ + 0.7), from_spherical(to, po + 0.7))
        np.testing.assert_allclose(a, b, rtol=1e-9)
    w = make("ward", alpha_x=0.1, alpha_y=0.4)
    a = w.eval(from_spherical(ti, pi_), from_spherical(to, po))
    b = w.eval(from_spherical(ti, pi_ + 0.7), from_spherical(to, po + 0.7))
    assert not np.allclose(a, b)


@pytest.mark.parametrize("name", ["cook-torrance", "microfacet", "ashikhmin-shirley"])
def test_schlick_near_normal_incidence_is_reciprocal_and_accurate(name):
    # Found by hypothesis: with f0 ≈ 0 the Fresnel term is (1 − cos θd)⁵ and 1 − cos θd computed as
    # 1 − wo·h cancels (relative error 1e-9 at θd = 1e-3 rad, so f(wi, wo) ≠ f(wo, wi)).
    f0_key = "rs" if name == "ashikhmin-shirley" else "f0"
    kd_key = "rd" if name == "ashikhmin-shirley" else "kd"
    model = make(name, **{f0_key: 0.0, kd_key: 0.0})
    theta = np.array([0.0, 1e-4, 2e-3, 0.3])
    wi = from_spherical(np.zeros_like(theta), np.zeros_like(theta))
    wo = from_spherical(theta, np.zeros_like(theta))
    f, g = model.eval(wi, wo), model.eval(wo, wi)
    np.testing.assert_allclose(f, g, rtol=1e-13, atol=0)
    # and the Fresnel factor itself against the cancellation-free closed form (1 − cos(θ/2))⁵
    from gonio.brdf.fresnel import one_minus_cos_d, schlick
    from gonio.brdf.microfacet import half_vector

    h = half_vector(wi, wo)
    exact = (2.0 * np.sin(theta / 4.0) ** 2) ** 5
    np.testing.assert_allclose(schlick(0.0, 1.0, one_minus_cos_d(wi, wo, h)), exact, rtol=1e-12)


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
@pytest.mark.parametrize("name, params", [
    ("abc", dict(kd=0.0, A=1000.0, B=0.01, C=0.001, eta=1.0)),  # η = 1: F is exactly 0, rounding decides the rest
    ("abc", dict(kd=0.1, A=2.0, B=800.0, C=0.7, eta=1.6)),
    ("abc-smooth", dict(kd=0.0, A=1000.0, B=0.01, C=0.001, eta=1.0)),
    ("ashikhmin-shirley", dict(rd=0.2, rs=0.5, nu=100, nv=20)),
    ("cook-torrance", dict(kd=0.2, ks=0.5, roughness=0.2, f0=0.04)),
])
def test_models_of_cos_theta_d_are_reciprocal_to_the_last_bit(name, params, backend):
    """Their formulas take cos θd as the mean of wi·h and wo·h (gonio.brdf.pairs.cos_d), which is symmetric in
    (wi, wo) bit for bit: values that are only rounding (F of η = 1: 4.6e-30 one way, 0 the other before) cannot
    break reciprocity."""
    pytest.importorskip("numba") if backend == "compiled" else None
    rng = np.random.default_rng(7)
    t, p = rng.uniform(0, np.pi / 2, (4000, 2)), rng.uniform(0, 2 * np.pi, (4000, 2))
    wi = np.concatenate([from_spherical(t[:, 0], p[:, 0]), from_spherical(np.array([1.0]), np.array([5.0]))])
    wo = np.concatenate([from_spherical(t[:, 1], p[:, 1]), from_spherical(np.array([1.5]), np.array([1.0]))])
    model = make(name, **params)
    a, b = model.eval(wi, wo, backend=backend), model.eval(wo, wi, backend=backend)
    assert a.tobytes() == b.tobytes()
