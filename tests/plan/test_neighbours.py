"""The k-d tree planning paths (gonio.plan.neighbours) agree exactly with the dense O(N²) references:
same MST weight (Prim), same greedy nearest-neighbour order, exact k-nearest lists; with unequal
speed/acceleration ratios (the k-d tree bound is then not tight) and continuous-rotation joints."""

import math

import numpy as np
import pytest

from gonio.plan import make_plan, neighbours as nb, ordering as o
from gonio.plan.ordering import MotionModel, mst_move_time, nearest_neighbour_order
from gonio.rig.kinematics import load_rig

_NAMES = ("a", "b", "c", "d")


@pytest.fixture(scope="module")
def rig_model():
    return MotionModel.from_rig(load_rig())


MODELS = {
    "equal_ratio": lambda m: m,
    "unequal": lambda m: MotionModel(_NAMES, [1.0, 2.0, 0.5, 0.7], [3.0, 1.0, 2.0, 0.4]),
    "wrap": lambda m: MotionModel(_NAMES, [1.0, 2.0, 0.5, 0.7], [3.0, 1.0, 2.0, 0.4], [True, False, False, True]),
}


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_random_poses_match_dense_reference(rig_model, kind):
    model = MODELS[kind](rig_model)
    q = np.random.default_rng(3).uniform(-3.0, 3.0, (400, 4))
    assert mst_move_time(q, model) == pytest.approx(o._mst_move_time_dense(q, model), rel=1e-12)
    start = np.array([0.1, -0.2, 0.3, 2.9])
    assert mst_move_time(q, model, start=start) == pytest.approx(
        o._mst_move_time_dense(q, model, start=start), rel=1e-12)
    np.testing.assert_array_equal(nearest_neighbour_order(q, model, seed=5),
                                  o._nearest_neighbour_order_dense(q, model, seed=5))
    np.testing.assert_array_equal(nearest_neighbour_order(q, model, start=start),
                                  o._nearest_neighbour_order_dense(q, model, start=start))
    idx, dist = nb.knn(q, model, 7)
    full = model.move_time(q[:, None, :], q[None, :, :])
    np.fill_diagonal(full, np.inf)
    np.testing.assert_allclose(dist, np.sort(full, axis=1)[:, :7], rtol=0, atol=0)
    np.testing.assert_allclose(np.take_along_axis(full, idx, 1), dist, rtol=0, atol=0)


def test_grid_plan_with_ties_matches_dense_reference(rig_model):
    """A regular grid: many equal move times (ties) and clusters far apart (Borůvka's fallback)."""
    plan = make_plan("grid", order="raster", theta_step=math.radians(15), phi_step=math.radians(45))
    q = plan.joints
    assert mst_move_time(q, rig_model) == pytest.approx(o._mst_move_time_dense(q, rig_model), rel=1e-12)
    np.testing.assert_array_equal(nearest_neighbour_order(q, rig_model),
                                  o._nearest_neighbour_order_dense(q, rig_model))


def test_clusters_far_apart_are_joined(rig_model):
    """Tight clusters far from each other: no neighbour list leaves its cluster, the MST still spans."""
    rng = np.random.default_rng(0)
    centres = rng.uniform(-3, 3, (6, 4))
    q = np.concatenate([c + rng.normal(0, 1e-3, (40, 4)) for c in centres])
    assert mst_move_time(q, rig_model) == pytest.approx(o._mst_move_time_dense(q, rig_model), rel=1e-12)


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_short_lists_leave_components_unresolved(rig_model, kind):
    """With 1-5 neighbours per pose most of Borůvka's components cannot read their cheapest edge from
    the lists: only the members whose unlisted neighbours may beat the component's listed edge are
    searched (seeded with that edge); the weight is still Prim's."""
    model = MODELS[kind](rig_model)
    q = np.random.default_rng(3).uniform(-3.0, 3.0, (400, 4))
    prim = o._mst_move_time_dense(q, model)
    for k in (1, 2, 3, 5):
        assert nb.mst_weight(q, model, k=k) == pytest.approx(prim, rel=1e-12)


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_cheapest_outgoing_edges_by_both_paths(rig_model, kind):
    """Borůvka's cheapest edge out of each component, found by the batched k-nearest queries or (kmax=0)
    only by the radius-bounded search over the other components, equals a dense scan."""
    model = MODELS[kind](rig_model)
    rng = np.random.default_rng(2)
    q = np.concatenate([c + rng.uniform(-0.3, 0.3, (150, 4)) for c in rng.uniform(-3, 3, (3, 4))])
    lab = np.repeat(np.arange(3) * 150, 150)  # three large components, labelled by their first pose
    lab[::37] = 7  # and a sparse fourth one inside them
    comps = np.unique(lab)
    full = model.move_time(q[:, None, :], q[None, :, :])
    expect = [full[np.ix_(lab == c, lab != c)].min() for c in comps]
    tree, sq = nb._tree(q, model, q), nb._scaled_like(q, q, model)
    for kmax in (64, 26, 0):  # batched; one batch then the radius search; the radius search alone
        u, v, w = nb._outgoing(q, model, lab, comps, tree, sq, 26, kmax=kmax)
        np.testing.assert_allclose(w, expect, rtol=1e-12)
        np.testing.assert_allclose(model.move_time(q[u], q[v]), w, rtol=1e-12)
        assert np.all(lab[u] == comps) and np.all(lab[v] != comps)
    # seeded with a known (not the cheapest) edge per component, only a few members searched: the
    # seed stands where no searched member beats it, and a cheaper edge replaces it
    u0 = np.array([np.flatnonzero(lab == c)[0] for c in comps])
    v0 = np.array([np.flatnonzero(lab != c)[0] for c in comps])
    w0 = model.move_time(q[u0], q[v0])
    u, v, w = nb._outgoing(q, model, lab, comps, tree, sq, 26, members=np.zeros(0, np.int64), seed=(u0, v0, w0))
    np.testing.assert_array_equal(w, w0)
    u, v, w = nb._outgoing(q, model, lab, comps, tree, sq, 26, members=np.flatnonzero(lab == comps[0]),
                           seed=(u0, v0, w0))
    np.testing.assert_allclose(w, [expect[0], *w0[1:]], rtol=1e-12)
    # the radius search alone from a finite best (without wrap joints it searches only the poses near the
    # members' bounding box): still the cheapest edges
    u, v, w = nb._outgoing(q, model, lab, comps, tree, sq, 26, kmax=0, seed=(u0, v0, w0))
    np.testing.assert_allclose(w, expect, rtol=1e-12)
    np.testing.assert_allclose(model.move_time(q[u], q[v]), w, rtol=1e-12)


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_radius_inverts_the_floor(rig_model, kind):
    """Beyond _radius(w) every move takes longer than w, and just inside it one may not: the radius
    bounding the search of Borůvka's fallback is the inverse of the k-d tree floor F."""
    model = MODELS[kind](rig_model)
    for w in (1e-4, 0.05, 0.5, 1.0, 3.0, 20.0):
        r = nb._radius(model, w)
        assert nb._floor(model, r) >= w * (1 - 1e-9)
        assert nb._floor(model, (r - 1e-12) * (1 - 1e-6)) < w  # less the widening for round-off
    assert nb._radius(model, np.inf) == np.inf


@pytest.mark.parametrize("kind", sorted(MODELS))
def test_estimate_reuses_the_lists_ordering_built(rig_model, kind, monkeypatch):
    """optimize_order keeps its neighbour lists renumbered for the ordered poses; the spanning tree of
    those poses (estimate_plan's bound) reuses them instead of new k-d tree queries, with Prim's weight.
    Other poses (a different set, or one pose moved) build their own lists."""
    model = MODELS[kind](rig_model)
    q = np.random.default_rng(4).uniform(-3.0, 3.0, (300, 4))
    perm = o.optimize_order(q, model, seed=1)
    ordered = np.array(q[perm])  # a copy, as Plan stores it
    idx, dist = nb.recall(ordered, model)
    full = model.move_time(ordered[:, None, :], ordered[None, :, :])
    np.fill_diagonal(full, np.inf)
    np.testing.assert_array_equal(np.take_along_axis(full, idx, 1), dist)  # renumbered right
    np.testing.assert_array_equal(dist, np.sort(full, axis=1)[:, :dist.shape[1]])  # still the k nearest
    calls = []
    monkeypatch.setattr(nb, "knn", lambda *a, **k: calls.append(a) or (_ for _ in ()).throw(AssertionError))
    assert mst_move_time(ordered, model) == pytest.approx(o._mst_move_time_dense(ordered, model), rel=1e-12)
    assert not calls
    moved = ordered.copy()
    moved[0, 0] += 1e-9
    assert nb.recall(moved, model) is None and nb.recall(q, model) is None


def test_the_exhaustive_search_of_small_sets_answers_as_the_k_d_tree():
    """Up to nb.EXHAUSTIVE_MAX points (a session's plan, mostly) the queries are answered without scipy.spatial: the
    same distances, the same shapes, the same points nearer than the last one returned (ties at the last place may
    take either point), inf and index n for the missing ones; with and without a periodic box, ties included."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    box = np.array([6.0, 6.0, 50.0, 50.0])
    for trial in range(60):
        n = int(rng.integers(1, 40))
        data = rng.uniform(0, 1, (n, 4)) * box
        if trial % 3 == 0:
            data = np.round(data) % box  # many equal distances
        q = rng.uniform(0, 1, (5, 4)) * box
        k = int(rng.integers(1, n + 3))
        bound = np.inf if trial % 2 else float(rng.uniform(0, 10))
        for bx in (box, None):
            d1, i1 = cKDTree(data, boxsize=bx).query(q, k=k, p=np.inf, distance_upper_bound=bound)
            d2, i2 = nb._Exhaustive(data, boxsize=bx).query(q, k=k, p=np.inf, distance_upper_bound=bound)
            assert d1.shape == d2.shape == i2.shape and np.array_equal(d1, d2)
            assert np.array_equal(i1 == n, i2 == n)
            for r1, r2, dr in zip(i1.reshape(5, -1), i2.reshape(5, -1), d1.reshape(5, -1)):
                last = dr[np.isfinite(dr)].max(initial=-1.0)
                assert set(r1[dr < last]) == set(r2[dr < last])
        d1, _ = cKDTree(data, boxsize=box).query(q[0], k=k, p=np.inf)
        d2, _ = nb._Exhaustive(data, boxsize=box).query(q[0], k=k, p=np.inf)
        assert np.shape(d1) == np.shape(d2) and np.array_equal(d1, d2)


def test_a_small_plan_is_ordered_without_scipy_spatial_and_as_with_the_tree(rig_model, monkeypatch):
    plan = make_plan("in_plane", seed=0)
    assert len(plan) <= nb.EXHAUSTIVE_MAX
    monkeypatch.setattr(nb, "EXHAUSTIVE_MAX", 0)  # the k-d tree for every set
    tree = make_plan("in_plane", seed=0)
    assert np.array_equal(plan.poses, tree.poses)
    assert mst_move_time(plan.joints, rig_model) == mst_move_time(tree.joints, rig_model)
    import os
    import subprocess
    import sys
    from pathlib import Path

    code = ("import sys; from gonio.plan import make_plan; make_plan('in_plane', seed=0); "
            "print(any(m.startswith('scipy.spatial') for m in sys.modules))")
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout
    assert out == "False\n"
