"""The scalable 2-opt/Or-opt local search (gonio.plan.localsearch.improve): it returns a permutation
that keeps the start first and the free end last, never makes a path longer, and orders as well as the
previous O(N²) search (reference_search) on small sets; for rigs with wrap joints and a fixed start too."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio.plan import ordering as o
from gonio.plan.localsearch import improve
from gonio.plan.ordering import MotionModel, optimize_order, path_move_time

_NAMES = ("a", "b", "c", "d")
MODELS = {
    "equal_ratio": MotionModel(_NAMES, [0.7, 0.8, 0.7, 0.8], [1.4, 1.6, 1.4, 1.6]),
    "wrap": MotionModel(_NAMES, [1.0, 2.0, 0.5, 0.7], [3.0, 1.0, 2.0, 0.4], [True, False, False, True]),
}


def _improve(q, model, order, start=None, k=8, **kw):
    """improve() on the cycle start + ``order`` + end, as optimize_order calls it."""
    n = q.shape[0]
    idx, dist = o._neighbours(q, model, k)
    nbr_i, nbr_c = idx.tolist(), dist.tolist()
    s = ([], []) if start is None else o._start_neighbours(q, model, start, k)
    cost = o._scalar_cost(o._Graph(q, model, start))
    tour = np.concatenate([[n], order, [n + 1]])
    out = improve(tour, cost, nbr_i + [s[0], []], nbr_c + [s[1], []], n, start is not None, **kw)
    assert out[0] == n and out[-1] == n + 1
    return out[1:-1]


@settings(max_examples=30, deadline=None)
@given(n=st.integers(2, 80), seed=st.integers(0, 2**31 - 1), kind=st.sampled_from(sorted(MODELS)),
       fixed=st.booleans(), grid=st.booleans())
def test_never_longer_and_a_permutation(n, seed, kind, fixed, grid):
    rng = np.random.default_rng(seed)
    model = MODELS[kind]
    q = rng.uniform(-3.0, 3.0, (n, 4))
    if grid:  # ties and repeated poses, as grids produce
        q = np.round(q)
    start = rng.uniform(-3.0, 3.0, 4) if fixed else None
    order = rng.permutation(n)
    got = _improve(q, model, order, start=start)
    assert sorted(got.tolist()) == list(range(n))
    before = path_move_time(q, order, model, start=start)
    after = path_move_time(q, got, model, start=start)
    assert after <= before + 1e-9
    if n >= 12 and not grid:
        assert after < before  # a random order of spread poses is never 2-opt optimal


def test_bounded_visits_still_a_permutation_and_no_longer():
    rng = np.random.default_rng(5)
    q = rng.uniform(-1.5, 1.5, (400, 4))
    order = rng.permutation(400)
    model = MODELS["equal_ratio"]
    one = _improve(q, model, order, max_passes=0.01)  # a handful of node visits
    full = _improve(q, model, order)
    assert sorted(one.tolist()) == list(range(400))
    lengths = [path_move_time(q, x, model) for x in (order, one, full)]
    assert lengths[0] > lengths[1] > lengths[2]


@pytest.mark.parametrize("kind", sorted(MODELS))
@pytest.mark.parametrize("fixed", [False, True])
def test_as_good_as_the_previous_search(kind, fixed):
    model = MODELS[kind]
    new, old = [], []
    for seed in range(4):
        rng = np.random.default_rng(seed)
        q = rng.uniform(-1.5, 1.5, (150, 4))
        start = rng.uniform(-1.5, 1.5, 4) if fixed else None
        new.append(path_move_time(q, optimize_order(q, model, start=start, seed=seed), model, start=start))
        old.append(path_move_time(q, o._optimize_order_reference(q, model, start=start, seed=seed), model,
                                  start=start))
    assert sum(new) <= 1.01 * sum(old)
