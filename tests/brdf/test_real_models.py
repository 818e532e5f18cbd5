"""Models added for real measurements (issue 14): Löw 2012 ABC, Burley 2012 GTR."""

import math

import numpy as np
import pytest

from gonio.brdf import MODELS, make
from gonio.brdf.gtr import gtr_d
from gonio.geometry import from_spherical


def _dirs(n=200, seed=3):
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 1.4, (2, n))
    p = rng.uniform(0, 2 * np.pi, (2, n))
    return from_spherical(t[0], p[0]), from_spherical(t[1], p[1])


@pytest.mark.parametrize("alpha", [0.02, 0.2, 0.7])
@pytest.mark.parametrize("gamma", [0.6, 1.0, 1.5, 2.0, 4.0])
def test_gtr_distribution_is_normalized(alpha, gamma):
    # ∫ D cos θh dω = 2π ∫ D(t) t dt over t = cos θh in [0, 1]; substitute t = 1 − s² to resolve the peak
    x, w = np.polynomial.legendre.leggauss(400)
    s = (x + 1) / 2
    t = 1 - s * s
    integral = 2 * np.pi * np.sum(w / 2 * gtr_d(t, alpha, gamma) * t * 2 * s)
    assert integral == pytest.approx(1.0, rel=2e-3)


def test_gtr_with_gamma_2_is_ggx():
    wi, wo = _dirs()
    a = make("gtr", kd=0.1, ks=[0.5, 0.4, 0.3], alpha=0.15, gamma=2.0, f0=0.3).eval(wi, wo)
    b = make("microfacet", kd=0.1, ks=[0.5, 0.4, 0.3], alpha=0.15, f0=0.3).eval(wi, wo)
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-14)


def _dj_abc(wi, wo, kd, A, B, C, ior):
    """djb::abc::eval of jdupuy/dj_brdf (dj_brdf.h), transcribed sample by sample."""
    out = []
    for i, o in zip(wi, wo):
        h = (i + o) / np.linalg.norm(i + o)
        c = min(max(float(i @ h), 0.0), 1.0)
        g = math.sqrt(ior * ior + c * c - 1.0)
        t1, t2 = c * (g + c) - 1.0, c * (g - c) + 1.0
        F = 0.5 * (g - c) ** 2 / (g + c) ** 2 * (1 + t1 * t1 / (t2 * t2))
        G = min(1.0, 2 * h[2] * i[2] / (h @ i), 2 * h[2] * o[2] / (h @ o))
        D = np.asarray(A) / (1 + B * (1 - h[2])) ** C
        out.append(np.asarray(kd) / np.pi + F * D * G / (np.pi * i[2] * o[2]))
    return np.array(out)


def test_abc_matches_dj_brdf_evaluation():
    wi, wo = _dirs(100)
    p = dict(kd=[0.002692, 0.002520, 0.003088], A=[986.846741, 771.035522, 696.134583], B=64661.257812,
             C=1.905420, eta=99.999413)  # dj_brdf.h, "chrome"
    want = _dj_abc(wi, wo, p["kd"], p["A"], p["B"], p["C"], p["eta"])
    np.testing.assert_allclose(make("abc", **p).eval(wi, wo), want, rtol=1e-9)


@pytest.mark.parametrize("name", ["abc", "abc-smooth", "gtr"])
def test_new_models_reciprocal_zero_below_horizon_and_finite(name):
    wi, wo = _dirs()
    m = make(name, kd=0.2, A=3.0, B=50.0, C=1.5) if name != "gtr" else make(name, kd=0.2, ks=0.5, alpha=0.2, gamma=1.2)
    np.testing.assert_allclose(m.eval(wi, wo), m.eval(wo, wi), rtol=1e-12)
    below = wo * np.array([1, 1, -1])
    assert np.all(m.eval(wi, below) == 0)
    grazing = from_spherical(np.full(5, np.pi / 2 - 1e-12), np.linspace(0, 3, 5))
    assert np.all(np.isfinite(m.eval(grazing, grazing[::-1])))


def test_abc_smooth_peaks_at_the_mirror_direction():
    m = make("abc-smooth", kd=0.0, A=1.0, B=1e4, C=2.0, eta=1.5)
    wi = from_spherical(0.5, 0.0)
    mirror = from_spherical(0.5, np.pi)
    off = from_spherical(0.6, np.pi)
    assert m.eval(wi, mirror)[0] > 100 * m.eval(wi, off)[0]


def test_registered():
    assert {"abc", "abc-smooth", "gtr"} <= set(MODELS)
