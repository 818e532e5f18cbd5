"""The compiled BRDF path (numba, optional) against the NumPy reference, and sums sharing their geometry."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.brdf import compiled
from gonio.geometry import from_spherical

from .strategies import special_pairs

#: Every model with a compiled form, with parameters away from the defaults (RGB colours, f0 < 1).
COMPILED = [
    ("microfacet", dict(kd=[0.1, 0.2, 0.3], ks=[0.5, 0.4, 0.3], alpha=0.13, f0=[0.9, 0.5, 0.04])),
    ("microfacet", dict(kd=0.2, ks=0.7, alpha=0.3, f0=0.04, distribution="beckmann")),
    ("microfacet", dict(alpha=1e-4)),
    ("cook-torrance", dict(kd=0.2, ks=[0.5, 0.4, 0.3], roughness=0.25, f0=[0.04, 0.1, 0.9])),
    ("gtr", dict(kd=0.1, ks=0.6, alpha=0.15, gamma=1.0, f0=0.05)),
    ("gtr", dict(alpha=0.4, gamma=0.6)),
    ("abc", dict(kd=0.1, A=[2.0, 3.0, 4.0], B=800.0, C=0.7, eta=1.6)),
    ("lambert", dict(albedo=[0.2, 0.5, 0.8])),
    ("lambert+2ggx", {"diffuse.albedo": 0.3, "lobe1.ks": 0.3, "lobe1.alpha": 0.05, "lobe1.f0": 0.04,
                      "lobe2.ks": [0.2, 0.1, 0.3], "lobe2.alpha": 0.4}),
    ("lambert+beckmann+cook-torrance", {"diffuse.albedo": 0.1, "lobe1.alpha": 0.2, "lobe2.roughness": 0.3}),
    ("ashikhmin-shirley", dict(rd=[0.2, 0.5, 0.7], rs=[0.05, 0.5, 0.9], nu=100, nv=20)),
    ("abc-smooth", dict(kd=0.1, A=[2.0, 3.0, 4.0], B=800.0, C=0.7, eta=1.6)),
    # the ends of every shape parameter's range (narrowest and broadest lobes, flat and steep tails)
    ("microfacet", dict(alpha=1.0, f0=0.0)),
    ("microfacet", dict(alpha=1e-4, distribution="beckmann")),
    ("microfacet", dict(alpha=1.0, distribution="beckmann", f0=0.0)),
    ("cook-torrance", dict(roughness=1e-4, f0=1.0)),
    ("cook-torrance", dict(roughness=1.0, f0=0.0)),
    ("gtr", dict(alpha=1e-4, gamma=10.0)),
    ("gtr", dict(alpha=0.999, gamma=0.5, f0=0.0)),
    ("abc", dict(A=1e3, B=1e8, C=50.0, eta=100.0)),
    ("abc", dict(A=0.5, B=1e-2, C=1e-3, eta=1.0)),
    ("abc-smooth", dict(A=1e3, B=1e8, C=50.0, eta=100.0)),
    ("abc-smooth", dict(A=0.5, B=1e-2, C=1e-3, eta=1.0)),
    ("ashikhmin-shirley", dict(rd=1.0, rs=0.0, nu=0.0, nv=0.0)),
    ("ashikhmin-shirley", dict(rd=0.0, rs=1.0, nu=1e6, nv=1.0)),
]


def _directions():
    """Random pairs (some below the horizon), the special pairs (grazing, poles, wi = −wo) and wi = wo."""
    rng = np.random.default_rng(7)
    n = 600  # ≥ MIN_PAIRS with the rest, so backend="auto" takes the compiled path too
    wi = from_spherical(np.arccos(rng.uniform(-0.2, 1, n)), rng.uniform(0, 2 * np.pi, n))
    wo = from_spherical(np.arccos(rng.uniform(-0.2, 1, n)), rng.uniform(0, 2 * np.pi, n))
    sw, so = special_pairs()
    return np.concatenate([wi, sw, wi]), np.concatenate([wo, so, wi])


def _assert_same(a, b):
    assert a.shape == b.shape and np.all(np.isfinite(a))
    np.testing.assert_array_less(np.abs(a - b), 1e-12 * np.abs(b) + 1e-300)  # exact where b is 0


@pytest.mark.parametrize("name,params", COMPILED, ids=[f"{n}-{i}" for i, (n, _) in enumerate(COMPILED)])
def test_compiled_equals_numpy(name, params):
    pytest.importorskip("numba")
    model = make(name, **params)
    assert compiled.supports(model)
    wi, wo = _directions()
    ref = model.eval(wi, wo, backend="numpy")
    fast = model.eval(wi, wo, backend="compiled")
    _assert_same(fast, ref)
    below = (wi[:, 2] <= 0) | (wo[:, 2] <= 0)
    assert np.all(fast[below] == 0.0) and np.all(fast >= 0.0)
    assert compiled.wanted(model, wi, np.dtype(np.float64), "auto")
    np.testing.assert_array_equal(model.eval(wi, wo), fast)
    # n-d shapes and broadcasting go through the same flattening
    grid = model.eval(wi[:12].reshape(3, 4, 3), wo[:4], backend="compiled")
    _assert_same(grid, model.eval(wi[:12].reshape(3, 4, 3), wo[:4], backend="numpy"))


def test_every_compiled_model_is_compared():
    """Each registered model with a compiled form is in :data:`COMPILED` (a new one cannot skip the comparison)."""
    from gonio.brdf import MODELS

    def some(cls):  # the defaults, and the lower bound of a parameter without one
        return cls(**{k: spec.lo for k, spec in cls.PARAMS.items() if spec.default is None})

    with_form = {name for name, cls in MODELS.items() if compiled.supports(some(cls))}
    assert {"microfacet", "cook-torrance", "gtr", "abc", "abc-smooth", "ashikhmin-shirley"} <= with_form
    assert with_form - {"lambert+ggx", "lambert+2ggx", "lambert+beckmann", "lambert+2beckmann", "lambert+cook-torrance",
                        "lambert+2cook-torrance"} <= {name for name, _ in COMPILED}


def test_auto_loads_a_loop_only_for_an_array_that_repays_it(monkeypatch):
    if not compiled.available():
        pytest.skip("numba is not installed: auto is always NumPy")
    monkeypatch.setattr(compiled, "_LOADED", set())  # as in a new process: no loop loaded yet
    m = make("microfacet", alpha=0.3)
    wi, wo = _directions()
    f64 = np.dtype(np.float64)
    assert not compiled.wanted(m, wi, f64, "auto")  # 600 pairs: loading the loop would cost more than it saves
    assert compiled.wanted(m, np.broadcast_to(wi[:1], (compiled.COLD_PAIRS, 3)), f64, "auto")
    m.eval(wi, wo, backend="compiled")  # now loaded: auto uses it from MIN_PAIRS on
    assert compiled.wanted(m, wi, f64, "auto")
    assert not compiled.wanted(m, wi[:10], f64, "auto")


def test_backend_choice():
    m = make("ward", kd=0.2)
    assert not compiled.supports(m)
    assert not compiled.supports(make("lambert+ward", **{"diffuse.albedo": 0.2}))
    wi, wo = _directions()
    assert not compiled.wanted(make("microfacet"), wi[:10], np.dtype(np.float64), "auto")  # small: NumPy
    assert not compiled.wanted(make("microfacet"), wi, np.dtype(np.float32), "auto")
    if compiled.available():
        with pytest.raises(ValueError, match="no compiled form"):
            m.eval(wi, wo, backend="compiled")
    else:
        with pytest.raises(ValueError, match="gonio\\[fast\\]"):
            make("microfacet").eval(wi, wo, backend="compiled")
    with pytest.raises(ValueError, match="backend"):
        m.eval(wi, wo, backend="fast")


@pytest.mark.parametrize("backend", ["numpy", "compiled"])
def test_sum_shares_geometry_and_equals_terms_summed(backend):
    if backend == "compiled":
        pytest.importorskip("numba")
    wi, wo = _directions()
    params = {"diffuse.albedo": [0.2, 0.3, 0.1], "lobe1.ks": 0.3, "lobe1.alpha": 0.05, "lobe1.f0": 0.04,
              "lobe2.ks": 0.2, "lobe2.alpha": 0.4, "lobe2.f0": [0.9, 0.6, 0.3]}
    total = make("lambert+2ggx", **params).eval(wi, wo, backend=backend)
    terms = (make("lambert", albedo=params["diffuse.albedo"]).eval(wi, wo, backend="numpy")
             + make("microfacet", kd=0, ks=0.3, alpha=0.05, f0=0.04).eval(wi, wo, backend="numpy")
             + make("microfacet", kd=0, ks=0.2, alpha=0.4, f0=[0.9, 0.6, 0.3]).eval(wi, wo, backend="numpy"))
    _assert_same(total, terms)
    # a sum with a term that is not written as lobes: the others still share one geometry, same values
    mixed = make("lambert+ggx+ward", **{"diffuse.albedo": 0.2, "lobe1.alpha": 0.2, "lobe2.ks": 0.3})
    parts = sum(p.eval(wi, wo) for p in mixed.parts)
    _assert_same(mixed.eval(wi, wo, backend="numpy"), parts)


def test_kernel_cache_file_is_keyed_by_the_source(tmp_path, monkeypatch):
    monkeypatch.setenv("GONIO_KERNEL_CACHE", str(tmp_path))
    src = "def loop(x):\n    return x + 1\n"
    a = compiled._cached_module(src, "0.0")
    assert a is not None and a.loop(1) == 2 and a.__file__.startswith(str(tmp_path))
    assert compiled._cached_module(src, "0.0").__file__ == a.__file__  # same source: the same file (and numba cache)
    b = compiled._cached_module(src.replace("+ 1", "+ 2"), "0.0")
    c = compiled._cached_module(src, "0.1")  # another numba: another file
    assert len({a.__file__, b.__file__, c.__file__}) == 3 and b.loop(1) == 3
    monkeypatch.setenv("GONIO_KERNEL_CACHE", "off")
    assert compiled._cached_module(src, "0.0") is None
    monkeypatch.setenv("GONIO_KERNEL_CACHE", str(tmp_path / "file"))
    (tmp_path / "file").write_text("not a directory")
    assert compiled._cached_module(src, "0.0") is None  # not writable: compiled in memory instead
