"""The fast default path of the fit: f0 profiled out exactly, analytic Jacobian, batched bounded solves.

Each piece is checked against the slower independent computation it replaces."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.errors import ConfigError
from gonio.fit import fit, prepare
from gonio.fit.fit import _Problem
from gonio.fit.kernels import _ggx_spec_dalpha, _spec, jacobian_for, profile_for
from gonio.fit.layout import Layout, make_basis
from gonio.fit.losses import LOSSES
from gonio.fit.solve import GRAM_BLOCK, Projection, ProfiledProjection, bounded_lsq, bounded_lsq_batch, weighted_gram

from .conftest import synth

TRUTH = {"kd": [0.3, 0.12, 0.06], "ks": [0.8, 0.7, 0.6], "alpha": 0.2, "f0": 0.3}


@pytest.fixture(scope="module")
def data():
    return prepare(synth("microfacet", TRUTH, n=1500))


@pytest.mark.parametrize("alpha", [0.03, 0.2, 0.7])
def test_ggx_dalpha_matches_central_differences(data, alpha):
    h = 1e-6 * alpha
    fd = (_spec(data, "ggx", alpha + h) - _spec(data, "ggx", alpha - h)) / (2 * h)
    np.testing.assert_allclose(_ggx_spec_dalpha(data, alpha), fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())


@pytest.mark.parametrize("model, fixed, tied", [("microfacet", {"distribution": "ggx"}, ("f0",)),
                                                 ("microfacet", {"distribution": "beckmann"}, ("f0",)),
                                                 ("microfacet", {"kd": 0.0}, ("f0",)),
                                                 ("lambert+ggx", {}, ("lobe1.f0",)),
                                                 ("microfacet", {"f0": 1.0}, ()),
                                                 ("lambert+beckmann", {"lobe1.f0": 1.0}, ())])
@pytest.mark.parametrize("loss", ["cosine", "chi2"])
def test_analytic_jtj_matches_finite_differences(data, model, fixed, tied, loss):
    L = Layout(model, fixed, tied)
    assert jacobian_for(L) is not None and (profile_for(L) is not None) == bool(tied)
    prob = _Problem(data, L, LOSSES[loss], make_basis(L, data))
    colour = np.array([[0.3, 0.12, 0.06], [0.8, 0.7, 0.6]])[-L.K:]
    p = L.pack(colour, np.array([0.2, 0.3])[:L.S])
    slow = prob.jtj(p)  # central differences of the model values (no Jacobian kernel set)
    prob.jacobian = jacobian_for(L)
    fast = prob.jtj(p)
    np.testing.assert_allclose(fast, slow, rtol=1e-5, atol=1e-7 * np.abs(slow).max())


@pytest.mark.parametrize("loss", ["cosine", "chi2"])
def test_profiled_cost_is_the_projected_cost_minimized_over_f0(data, loss):
    L = Layout("microfacet", {}, ("f0",))
    w = LOSSES[loss].weight(data.y, data.cos_i, data.sigma)
    prof = ProfiledProjection(profile_for(L), L, data, w, L.shape.index("f0"))
    plain = Projection(make_basis(L, data), np.ascontiguousarray(w), data.y, L.colour_lo, L.colour_hi)
    for alpha in (0.05, 0.2, 0.5):
        cost, colour = prof(np.array([alpha]))
        shape = prof.full_shape(np.array([alpha]))
        ref_cost, ref_colour = plain(shape)  # the generic projection at the (alpha, f0) found
        assert cost == pytest.approx(ref_cost, rel=1e-9)
        np.testing.assert_allclose(colour, ref_colour, rtol=1e-7, atol=1e-12)
        # no f0 on a fine grid does better
        grid = [plain(np.array([alpha, t]))[0] for t in np.geomspace(1e-3, 1.0, 60)]
        assert cost <= min(grid) * (1 + 1e-12)


@pytest.mark.parametrize("model, tied", [("microfacet", "f0"), ("lambert+ggx", "lobe1.f0")])
def test_profiled_costs_over_f0_equal_the_gram_matrices_formed_at_each_f0(data, model, tied):
    """The profile's grid of f0 is costed from G(t) = G0 + t G1 + t2 G2 (ProfiledProjection._pieces): the same costs
    and colours as T(t) H T(t)^T formed at every t and solved one t at a time (bounds active at some t)."""
    L = Layout(model, {}, (tied,))
    prof_kernel = profile_for(L)
    w = LOSSES["chi2"].weight(data.y, data.cos_i, data.sigma)
    prof = ProfiledProjection(prof_kernel, L, data, w, L.shape.index(prof_kernel.tied))
    H, h = weighted_gram(prof_kernel.elements(data, L, np.array([0.2])), prof.w, prof.yT)
    t = np.geomspace(1e-3, 1.0, 97)
    cost, colour = prof._costs(t, prof._pieces(H, h), colours=True)
    T = prof_kernel.transform(L, t)
    bound = 0
    for i in range(t.size):
        want = 0.0
        for c in range(3):
            G, b = T[i] @ H[c] @ T[i].T, T[i] @ h[c]
            a = bounded_lsq(G, b, L.colour_lo, L.colour_hi)
            bound += bool(np.any(a == L.colour_lo) or np.any(a == L.colour_hi))
            np.testing.assert_allclose(colour[i, c], a, rtol=1e-9, atol=1e-12)
            want += 0.5 * max(prof.c0[c] - 2.0 * b @ a + a @ G @ a, 0.0)
        assert cost[i] == pytest.approx(want, rel=1e-9)
    assert bound  # the bounded path was exercised


def _batched_and_scalar(seed, n, rows, lo, hi, singular):
    """``n`` random bounded least-squares problems ``min ½aᵀGa − bᵀa`` over the box (``G = AᵀA``, ``A`` of
    ``rows`` × len(lo); with ``singular`` its first two columns equal): the batched solver's answers, the scalar
    solver's, and the problems' G and b."""
    rng = np.random.default_rng(seed)
    k = len(lo)
    A = rng.normal(size=(n, rows, k))
    if singular:
        A[..., 1] = A[..., 0]
    G = np.einsum("nij,nik->njk", A, A)
    b = rng.normal(scale=2.0, size=(n, k))
    got = bounded_lsq_batch(G, b, lo, hi)
    want = np.stack([bounded_lsq(G[i], b[i], lo, hi) for i in range(n)])
    return got, want, G, b


def _objective(a, G, b):
    """``½aᵀGa − bᵀa`` of each problem's answer ``a`` (n, k) → (n,)."""
    return 0.5 * np.einsum("ni,nij,nj->n", a, G, a) - np.einsum("ni,ni->n", b, a)


def test_batched_bounded_lsq_equals_the_scalar_one():
    lo, hi = np.array([0.0, 0.0, -1.0]), np.array([1.0, 1.0, np.inf])
    got, want, _, _ = _batched_and_scalar(4, 200, 6, lo, hi, singular=False)
    np.testing.assert_allclose(got, want, atol=1e-9)
    assert np.any(got == 0.0) and np.any(got == 1.0)  # bounds were active in some problems


@pytest.mark.parametrize("k", [2, 3])
def test_the_kkt_shortcut_is_the_enumerated_minimum_where_it_applies(k):
    """bounded_lsq_batch first solves the active set that clipping suggests and keeps it where the KKT conditions
    hold (gonio.fit.solve._kkt_guess): there it is the enumeration's answer; elsewhere the enumeration decides."""
    from gonio.fit.solve import _enumerated, _kkt_guess

    lo, hi = np.zeros(k), np.r_[1.0, np.full(k - 1, np.inf)]
    rng = np.random.default_rng(11)
    A = rng.normal(size=(400, 8, k))
    G = np.einsum("nij,nik->njk", A, A)
    b = rng.normal(scale=2.0, size=(400, k))
    x, good = _kkt_guess(G, b, lo, hi)
    want = _enumerated(G, b, lo, hi)
    assert 0.3 < good.mean() < 1.0  # settles most, not all
    np.testing.assert_allclose(x[good], want[good], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(bounded_lsq_batch(G, b, lo, hi), np.clip(want, lo, hi), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("singular", [False, True])
def test_two_colours_in_closed_form_equal_the_scalar_solver(singular):
    """K = 2 (a diffuse and a specular weight) is solved in closed form (gonio.fit.solve._two_colours); a singular
    free block (two identical columns) falls back to the minimum-norm path."""
    lo, hi = np.array([0.0, 0.0]), np.array([1.0, np.inf])
    got, want, G, b = _batched_and_scalar(6, 300, 5, lo, hi, singular)
    val = lambda a: _objective(a, G, b)  # noqa: E731
    assert np.all((got >= lo) & (got <= hi))
    if singular:
        assert np.all(val(got) <= val(want) + 1e-9)
    else:
        np.testing.assert_allclose(got, want, atol=1e-12)
        assert np.any(got == 0.0) and np.any(got[:, 0] == 1.0) and np.any((got > 0).all(axis=1))


def test_batched_bounded_lsq_with_singular_free_blocks_equals_the_scalar_one():
    # two identical columns: every active set that frees both is singular (the minimum-norm fallback)
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.0, 2.0])
    got, want, G, b = _batched_and_scalar(5, 50, 6, lo, hi, singular=True)
    val = lambda a: _objective(a, G, b)  # noqa: E731
    assert np.all((got >= lo) & (got <= hi))
    # at least as low as the scalar solver's (whose least-squares solutions of the singular blocks may miss a
    # feasible point of the null space), and no lower than any point of a grid over the box
    assert np.all(val(got) <= val(want) + 1e-9)
    grid = np.stack(np.meshgrid(*[np.linspace(0, h, 21) for h in hi], indexing="ij"), -1).reshape(-1, 3)
    brute = (0.5 * np.einsum("gi,nij,gj->ng", grid, G, grid) - b @ grid.T).min(axis=1)
    assert np.all(val(got) <= brute + 1e-9)


def test_projected_cost_is_the_residual_cost_to_rounding_when_the_data_dwarf_the_misfit():
    # chi2 weights of 1e-5 relative noise: sum(w y^2) is ~1e10 x the cost, where c0 - 2 b.a + a.G.a cancelled to
    # ~1e-6 of the cost -- noise the shape search's finite-difference gradients then chased
    s = synth("microfacet", TRUTH, n=600, noise=1e-5)
    d = prepare(s)
    L = Layout("microfacet", {"f0": TRUTH["f0"]})  # the true model: a misfit at the noise level
    w = LOSSES["chi2"].weight(d.y, d.cos_i, d.sigma)
    proj = Projection(make_basis(L, d), np.ascontiguousarray(w), d.y, L.colour_lo, L.colour_hi)
    for alpha in (0.15, 0.2, 0.2 + 1e-7):
        cost, colour = proj(np.array([alpha]))
        m = L.eval(colour, np.array([alpha]), d.wi, d.wo)
        direct = 0.5 * float(np.sum(w * (m - d.y) ** 2))
        assert cost == pytest.approx(direct, rel=1e-11)

SUM_TRUTH = {"diffuse.albedo": TRUTH["kd"], "lobe1.ks": TRUTH["ks"], "lobe1.alpha": TRUTH["alpha"],
             "lobe1.f0": TRUTH["f0"]}


@pytest.mark.parametrize("loss", ["cosine", "chi2"])
@pytest.mark.parametrize("model, truth, pre", [("microfacet", TRUTH, ""), ("lambert+ggx", SUM_TRUTH, "lobe1.")])
def test_fast_default_fit_reaches_the_generic_optimum(loss, model, truth, pre):
    s = synth(model, truth, n=1500)
    fast = fit(s, model, loss=loss)
    slow = fit(s, model, loss=loss, kernel=None)  # model evaluation, 2-D (alpha, f0) search, FD Jacobian
    assert fast.cost <= slow.cost * (1 + 1e-7)
    assert fast.cost == pytest.approx(slow.cost, rel=1e-6)
    for k in (pre + "alpha", pre + "f0"):
        assert fast.params[k] == pytest.approx(slow.params[k], rel=1e-3)
        assert fast.uncertainty[k] == pytest.approx(slow.uncertainty[k], rel=1e-3)
    np.testing.assert_allclose(fast.params[pre + "ks"], slow.params[pre + "ks"], rtol=1e-3)
    np.testing.assert_allclose(fast.uncertainty[pre + "ks"], slow.uncertainty[pre + "ks"], rtol=1e-3)
    assert fast.params[pre + "f0"] == pytest.approx(TRUTH["f0"], rel=0.1)


def test_profile_applies_only_where_it_is_exact():
    assert profile_for(Layout("lambert+ggx", {}, ("lobe1.f0",))) is not None
    assert profile_for(Layout("microfacet", {"f0": 1.0})) is None  # nothing tied
    assert profile_for(Layout("microfacet", {"kd": 0.1}, ("f0",))) is None  # a non-zero offset
    assert profile_for(Layout("microfacet", {"kd": 0.0}, ("f0",))) is not None  # ks alone
    assert profile_for(Layout("lambert+2ggx", {}, ("lobe1.f0", "lobe2.f0"))) is None  # two tied values
    assert profile_for(Layout("oren-nayar+ggx", {}, ("lobe1.f0",))) is None
    assert jacobian_for(Layout("microfacet", {"f0": [1.0, 0.5, 1.0]})) is None  # F varies per channel


def test_f0_on_its_bound_is_held_without_a_second_search():
    truth = {"kd": [0.3, 0.12, 0.06], "ks": [0.8, 0.7, 0.6], "alpha": 0.2, "f0": 1.0}
    s = synth("microfacet", truth, n=1500, noise=0.0)
    # reflectance falling towards grazing θd: the fit wants f0 > 1 and stops on the bound
    cos_d = np.linalg.norm(s.wi + s.wo, axis=1) / 2
    s = (s.wi, s.wo, s.f * (1.0 - 0.3 * (1.0 - cos_d))[:, None])
    r = fit(s, "microfacet", loss="cosine")
    held = fit(s, "microfacet", loss="cosine", fixed={"f0": 1.0})  # the fit it stands for
    assert r.params["f0"] == [1.0, 1.0, 1.0] and r.n_params == 7 and not r.identifiable
    assert any("held at 1" in n for n in r.notes)
    assert r.cost == pytest.approx(held.cost, rel=1e-6, abs=1e-12)
    assert r.params["alpha"] == pytest.approx(held.params["alpha"], rel=1e-6)
    np.testing.assert_allclose(r.params["ks"], held.params["ks"], rtol=1e-6)
    np.testing.assert_allclose(r.uncertainty["ks"], held.uncertainty["ks"], rtol=1e-3)


def test_a_search_on_a_subset_refined_on_all_lands_on_the_whole_data_optimum():
    big = prepare(synth("microfacet", TRUTH, n=2000))
    whole = fit(big, "microfacet", n_starts=1, report=False)
    coarse = fit(big, "microfacet", n_starts=1, report=False, search_n=300)  # searched on 300, refined on all
    assert coarse.cost <= whole.cost * (1 + 1e-6)
    assert coarse.params["alpha"] == pytest.approx(whole.params["alpha"], rel=1e-4)
    with pytest.raises(ConfigError, match="search_n"):
        fit(big, "microfacet", search_n=5)


@pytest.mark.parametrize("n", [1, GRAM_BLOCK, 2 * GRAM_BLOCK + 3])
@pytest.mark.parametrize("per_channel", [False, True])
def test_weighted_gram_is_its_definition_over_every_block(n, per_channel):
    """weighted_gram's blocked matrix products give H[c, i, j] = Σ w[n, c] eᵢ[n] eⱼ[n] and h[c, j] = Σ w eⱼ y[c]
    (constant elements as floats) for sizes within one block, on a block's edge and beyond it."""
    rng = np.random.default_rng(n)
    elems = [rng.random(n), 0.5, rng.normal(size=n), 1.0]
    w = rng.random((n, 3)) if per_channel else rng.random(n)
    yT = np.ascontiguousarray(rng.normal(size=(3, n)))
    E = np.stack([np.broadcast_to(np.asarray(e, float), (n,)) for e in elems])
    W = w.T if per_channel else np.broadcast_to(w, (3, n))
    H, h = weighted_gram(elems, w, yT)
    np.testing.assert_allclose(H, np.einsum("cn,in,jn->cij", W, E, E), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(h, np.einsum("cn,jn,cn->cj", W, E, yT), rtol=1e-12, atol=1e-12)
    H2, none = weighted_gram(elems, w)
    assert none is None and np.array_equal(H2, H)


@pytest.mark.parametrize("per_channel", [False, True])
def test_weighted_gram_is_the_sum_of_its_blocks_products_to_the_bit(per_channel):
    """weighted_gram of 2.5 blocks is, bit for bit, the blocks' own weighted_gram added in order (each block's
    products depend on that block's numbers only: not on how the whole vectors or weights are laid out), and
    per-channel weights read channels first (the transpose of a contiguous (3, N) array) give the same bits."""
    n = 2 * GRAM_BLOCK + GRAM_BLOCK // 2
    rng = np.random.default_rng(7)
    elems = [1.0 / np.pi, rng.random(n) * 1e3, rng.normal(size=n)]
    w = rng.random((n, 3)) if per_channel else rng.random(n)
    yT = np.ascontiguousarray(rng.normal(size=(3, n)))
    H, h = weighted_gram(elems, w, yT)
    H_sum, h_sum = np.zeros_like(H), np.zeros_like(h)
    for s in range(0, n, GRAM_BLOCK):
        b = slice(s, s + GRAM_BLOCK)
        Hb, hb = weighted_gram([e if np.ndim(e) == 0 else e[b].copy() for e in elems], w[b].copy(), yT[:, b].copy())
        H_sum += Hb
        h_sum += hb
    assert np.array_equal(H, H_sum) and np.array_equal(h, h_sum)
    if per_channel:
        HT, hT = weighted_gram(elems, np.ascontiguousarray(w.T).T, yT)
        assert np.array_equal(HT, H) and np.array_equal(hT, h)


def test_remembered_weights_give_the_losses_own_residuals_and_weights(data):
    """The weights a loss remembers on the data (root_weights_of, channel_weights_of) are the bits of its
    own formulas: the robust loss's residuals from them equal _robust_residual's, and the channel weights
    are weights_of's values (one shared column for the cosine loss)."""
    robust, cosine = LOSSES["robust"], LOSSES["cosine"]
    m = data.y * 1.1 + 0.01
    assert np.array_equal(robust.residuals_of(m, data), robust.residual(m, data.y, data.cos_i, data.sigma))
    assert np.array_equal(robust.channel_weights_of(data), robust.weights_of(data))
    assert robust.channel_weights_of(data).T.flags.c_contiguous
    assert np.array_equal(cosine.channel_weights_of(data), cosine.weights_of(data)[:, 0])
    assert robust.root_weights_of(data) is robust.root_weights_of(data)
    assert np.array_equal(robust.weights_T_of(data), robust.weights_of(data).T) and np.array_equal(data.yT, data.y.T)
    L = Layout("ward", {})
    w = np.ascontiguousarray(robust.weights_of(data))
    shape = np.array([0.2, 0.3])[:L.S]
    alone = Projection(make_basis(L, data), w, data.y, L.colour_lo, L.colour_hi)(shape)
    given = Projection(make_basis(L, data), w, data.y, L.colour_lo, L.colour_hi,
                       (robust.weights_T_of(data), data.yT))(shape)
    assert alone[0] == given[0] and np.array_equal(alone[1], given[1])
    c = data.cos_i[:, None]
    m = data.y * 1.1 + 0.01
    assert data.fit_quality(m, 2)[0] == float(np.sqrt(np.sum((c * (m - data.y)) ** 2) / np.sum((c * data.y) ** 2)))


def test_a_coordinate_scan_evaluates_each_point_once_with_the_same_answers(data, monkeypatch):
    """A whole coordinate scan (gonio.fit.fit._coordinate_scan: its second cycle returns to points of the first far
    apart) fits in the projection's memo: every distinct point is evaluated once, and each answer is the one a fresh
    projection computes."""
    from gonio.fit.fit import _coordinate_scan

    L = Layout("ward", {})
    w = np.ascontiguousarray(LOSSES["chi2"].weight(data.y, data.cos_i, data.sigma))
    proj = Projection(make_basis(L, data), w, data.y, L.colour_lo, L.colour_hi)
    evaluated = []
    real = Projection._evaluate
    monkeypatch.setattr(Projection, "_evaluate", lambda self, s: evaluated.append(np.array(s)) or real(self, s))
    u_lo, u_hi, _ = L.search_space()
    asked = []

    def f(u):
        asked.append(np.array(u))
        return proj(L.to_shape(u))[0]

    _coordinate_scan(f, L.to_u(L.default_shape()), np.inf, u_lo, u_hi)
    distinct = {u.tobytes() for u in asked}
    assert len(asked) > len(distinct) > 40 and len(evaluated) == len(distinct)
    fresh = Projection(make_basis(L, data), w, data.y, L.colour_lo, L.colour_hi)
    for u in asked[::7]:
        assert proj(L.to_shape(u))[0] == fresh(L.to_shape(u))[0]
