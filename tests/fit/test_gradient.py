"""The exact gradient of the projected cost (gonio.fit.gradient) against central differences, and the fits that
use it against the same fits by finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.fit import fit
from gonio.fit.data import prepare
from gonio.fit.gradient import map_jacobian
from gonio.fit.layout import Layout, auto_tied, linked_lobes, make_basis, model_class, resolve_fixed, separated
from gonio.fit.losses import LOSSES
from gonio.fit.solve import Projection

from .conftest import synth

TWO = {"diffuse.albedo": [0.2, 0.3, 0.1], "lobe1.ks": [0.6, 0.6, 0.8], "lobe1.alpha": 0.06,
       "lobe2.ks": [0.3, 0.2, 0.1], "lobe2.alpha": 0.45, "lobe1.f0": 0.3, "lobe2.f0": 0.6}


@pytest.fixture(scope="module")
def data():
    return prepare(synth("lambert+2ggx", TWO, n=400))


def _projection(d, name, fixed=(), linked=True):
    cls = model_class(name)
    fixed = resolve_fixed(cls, dict(fixed))
    L = Layout(cls, fixed, auto_tied(cls, fixed), linked_lobes(cls) if linked else ())
    proj = Projection(make_basis(L, d), np.ascontiguousarray(LOSSES["chi2"].weights_of(d)), d.y, L.colour_lo,
                      L.colour_hi)
    return L, proj


def _central(proj, space, u, h=1e-6):
    out = np.empty(u.size)
    for j in range(u.size):
        up, dn = u.copy(), u.copy()
        up[j] += h
        dn[j] -= h
        out[j] = (proj(space.to_shape(up))[0] - proj(space.to_shape(dn))[0]) / (2 * h)
    return out


@pytest.mark.parametrize("name, fixed, linked", [
    ("lambert+2ggx", {}, True),  # widths, tied f0s and the link's ratio, through the lobes' width-ratio map
    ("lambert+2ggx", {"f0": 1.0}, False),
    ("microfacet", {}, False),
    ("microfacet", {"f0": [0.5, 0.6, 0.7]}, False),  # a fixed per-channel Fresnel: (N, 3) bases
    ("microfacet", {"ks": 0.3, "f0": [0.5, 0.5, 0.5]}, False),  # a fixed ks: the lobe is in the offset
    ("oren-nayar+ggx", {}, False),  # Oren-Nayar's sigma (its kernel's derivative) beside a GGX lobe
])
def test_the_gradient_is_the_central_difference_of_the_cost(data, name, fixed, linked):
    L, proj = _projection(data, name, fixed, linked)
    assert proj.has_gradient
    space = separated(L) or L
    u_lo, u_hi, _ = space.search_space()
    rng = np.random.default_rng(4)
    for u in [*rng.uniform(u_lo, u_hi, (4, L.S)), u_lo + 0.3 * (u_hi - u_lo)]:
        cost, g = proj.value_and_grad(space.to_shape(u))
        assert cost == proj(space.to_shape(u))[0]
        gu = map_jacobian(space, u).T @ g
        fd = _central(proj, space, u)
        np.testing.assert_allclose(gu, fd, rtol=1e-4, atol=1e-7 * cost)


def test_the_oren_nayar_kernel_is_the_model(data):
    """The kernel's basis (gonio.fit.kernels._oren_nayar) times the albedo is the model's value at every sample."""
    from gonio.brdf import make
    from gonio.fit.kernels import KERNELS

    L = Layout("oren-nayar")
    for sigma in (0.0, 0.2, 1.3):
        _, (B,) = KERNELS["oren-nayar"](data, L, {"sigma": sigma})
        want = make("oren-nayar", albedo=[0.2, 0.5, 0.9], sigma=sigma).eval(data.wi, data.wo)
        np.testing.assert_allclose(B[:, None] * [0.2, 0.5, 0.9], want, rtol=1e-13)


def test_the_gradient_follows_a_colour_held_at_its_linked_bound(data):
    """lobe1.ks ≤ 1/w for lobe2.ks = w · lobe1.ks ≤ 1: at w = 4 with a broad second lobe the strong narrow lobe
    (ks 0.6-0.8) is held at its bound 0.25 in R and G (not B), a bound that moves with w — the gradient in w
    includes that (module docstring of gonio.fit.gradient)."""
    L, proj = _projection(data, "lambert+2ggx")
    s = np.array([0.06, 0.3, 0.9, 0.6, 4.0])  # lobe1.alpha, lobe1.f0, lobe2.alpha, lobe2.f0, lobe2.ks/lobe1.ks
    assert L.shape[-1] == "lobe2.ks/lobe1.ks"
    _, colour = proj(s)
    ks1 = colour[L.colour.index("lobe1.ks")]
    assert ks1[0] == ks1[1] == 0.25 and ks1[2] < 0.25
    cost, g = proj.value_and_grad(s)
    fd = np.empty(s.size)
    for j in range(s.size):
        h = 1e-6 * s[j]
        up, dn = s.copy(), s.copy()
        up[j] += h
        dn[j] -= h
        fd[j] = (proj(up)[0] - proj(dn)[0]) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=1e-5)


def test_a_two_lobe_fit_with_the_gradient_is_the_fit_by_finite_differences(data, monkeypatch):
    """The exact gradient changes the path of L-BFGS-B, not the optimum: the same parameters to 1e-5 and the same
    cost to 1e-9 as the search by finite differences (what every fit did before)."""
    exact = fit(data, "lambert+2ggx", n_starts=1, report=False)
    monkeypatch.setattr(Projection, "has_gradient", property(lambda self: False))
    numeric = fit(data, "lambert+2ggx", n_starts=1, report=False)
    assert exact.cost == pytest.approx(numeric.cost, rel=1e-9)
    for name, value in numeric.params.items():
        if name != "distribution" and not isinstance(value, str):
            np.testing.assert_allclose(exact.params[name], value, rtol=1e-5, atol=1e-7, err_msg=name)
