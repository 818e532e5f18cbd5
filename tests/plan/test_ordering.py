"""Lab-time ordering: the move-time model, the optimized order vs the raster baseline and the MST bound."""

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio.plan.ordering import (
    MotionModel, estimate, mst_move_time, nearest_neighbour_order, optimize_order, path_move_time, raster_order,
)
from gonio.rig.kinematics import load_rig, trapezoid_time

MODEL = MotionModel(("a", "b", "c", "d"), [0.7, 0.8, 0.7, 0.8], [1.4, 1.6, 1.4, 1.6])


def test_move_time_matches_the_rig_profile():
    rig = load_rig()
    m = MotionModel.from_rig(rig)
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-2, 2, (2, 500, 4))
    b[:50] = a[:50]  # zero moves
    b[50:100, 1:] = a[50:100, 1:]  # single-joint moves, some below the triangular knee
    b[50:75, 0] = a[50:75, 0] + rng.uniform(0, 0.05, 25)
    np.testing.assert_allclose(m.move_time(a, b), rig.move_time(a, b), rtol=1e-13, atol=0)
    expect = trapezoid_time(b - a, rig.max_speed, rig.max_accel)
    np.testing.assert_allclose(m.sequential_move_time(a, b), expect.sum(-1), rtol=1e-13)


def test_trapezoid_hand_values():
    m = MotionModel(("x",), [1.0], [2.0])
    # triangular: d = 0.25 < v²/a = 0.5 -> 2*sqrt(0.25/2); trapezoidal: d = 2 -> 2/1 + 1/2
    np.testing.assert_allclose(m.move_time([[0.0]], [[0.25], [2.0]]), [2 * np.sqrt(0.125), 2.5])


def test_wrap_joint_takes_the_short_way():
    m = MotionModel(("az",), [1.0], [1e9], wrap=[True])
    np.testing.assert_allclose(m.move_time([[0.1]], [[2 * np.pi - 0.1]]), [0.2], rtol=1e-6)


def brute_force_path(q, model):
    best = np.inf
    for perm in itertools.permutations(range(len(q))):
        best = min(best, path_move_time(q, perm, model))
    return best


@pytest.mark.parametrize("seed", range(5))
def test_small_sets_optimum_between_bound_and_result(seed):
    q = np.random.default_rng(seed).uniform(-1.5, 1.5, (7, 4))
    opt = brute_force_path(q, MODEL)
    order = optimize_order(q, MODEL, time_budget=None)
    got = path_move_time(q, order, MODEL)
    assert mst_move_time(q, MODEL) <= opt + 1e-9
    assert opt - 1e-9 <= got <= 1.15 * opt


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 60), seed=st.integers(0, 2**31 - 1), cluster=st.booleans())
def test_optimized_between_bound_and_raster(n, seed, cluster):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1.5, 1.5, (n, 4))
    if cluster:  # repeated and nearly repeated poses, as grids produce
        q = np.round(q * 2) / 2
    order = optimize_order(q, MODEL, seed=seed, time_budget=None, initial=raster_order(q))
    assert sorted(order.tolist()) == list(range(n))
    e = estimate(q, q, order, MODEL, pose_time=0.5)
    assert e.lower_bound <= e.optimized + 1e-9
    assert e.optimized <= e.raster_concurrent + 1e-9
    assert e.raster_concurrent <= e.raster + 1e-9


def test_thousand_poses_well_below_raster_and_near_bound():
    q = np.random.default_rng(3).uniform(-1.5, 1.5, (800, 4))
    order = optimize_order(q, MODEL, time_budget=None)
    e = estimate(q, q, order, MODEL, pose_time=0.0)
    assert e.optimized < 0.5 * e.raster
    assert e.optimized < 1.15 * e.lower_bound  # MST bound is tight on random sets within ~10 %


def test_fixed_start_is_counted():
    q = np.array([[1.0, 0, 0, 0], [2.0, 0, 0, 0]])
    start = np.zeros(4)
    order = optimize_order(q, MODEL, start=start, time_budget=None)
    assert order.tolist() == [0, 1]
    assert path_move_time(q, order, MODEL, start=start) == pytest.approx(
        float(MODEL.move_time(start, q[0]) + MODEL.move_time(q[0], q[1])))
    assert mst_move_time(q, MODEL, start=start) == pytest.approx(path_move_time(q, order, MODEL, start=start))


def test_nearest_neighbour_is_a_permutation_and_seeded():
    q = np.random.default_rng(1).uniform(-1, 1, (50, 4))
    a, b = nearest_neighbour_order(q, MODEL, seed=4), nearest_neighbour_order(q, MODEL, seed=4)
    assert sorted(a.tolist()) == list(range(50)) and a.tolist() == b.tolist()


def test_raster_order_is_lexicographic():
    p = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 2, 0], [0, 0, 1, 5.0]])
    assert raster_order(p).tolist() == [3, 2, 1, 0]


@pytest.mark.parametrize("fixed", [False, True])
def test_renumbered_search_makes_the_same_moves(fixed):
    """optimize_order runs the local search on the poses renumbered in the starting tour's order: the
    same order as the search on the poses' own numbering (ties included: poses on a coarse lattice)."""
    from gonio.plan import neighbours as nb
    from gonio.plan.localsearch import improve
    from gonio.plan.ordering import _Graph, _scalar_cost, _start_neighbours

    q = np.round(np.random.default_rng(8).uniform(-1.5, 1.5, (700, 4)) * 3) / 3
    start = np.array([0.2, -0.1, 0.3, 0.0]) if fixed else None
    got = optimize_order(q, MODEL, start=start, seed=3)
    n = len(q)
    cands = [nearest_neighbour_order(q, MODEL, start=start, seed=3), raster_order(q)]
    best = cands[int(np.argmin([path_move_time(q, c, MODEL, start=start) for c in cands]))]
    idx, dist = nb.knn(q, MODEL, 10)
    s_idx, s_cost = ([], []) if start is None else _start_neighbours(q, MODEL, start, 10)
    tour = improve(np.concatenate([[n], best, [n + 1]]), _scalar_cost(_Graph(q, MODEL, start)),
                   idx.tolist() + [s_idx, []], dist.tolist() + [s_cost, []], n, fixed)
    np.testing.assert_array_equal(got, tour[1:-1])


def test_initial_must_be_a_permutation():
    q = np.random.default_rng(1).uniform(-1, 1, (20, 4))
    for bad in ([0] * 20, list(range(19)), list(range(1, 21))):
        with pytest.raises(ValueError, match="permutation"):
            optimize_order(q, MODEL, initial=bad)
