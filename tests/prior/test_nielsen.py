"""gonio.prior.nielsen (the baseline of benchmarks sparse): their directions are distinct and well conditioned,
their ridge regression recovers a material of the training set from enough samples."""

import numpy as np

from gonio.prior import nielsen as nl
from gonio.prior.build import fill_nodes
from tests.prior.conftest import GRID, node_values_of, synthetic_materials


def _candidates(n=400, seed=0):
    rng = np.random.default_rng(seed)
    ti, to = np.radians(rng.uniform(0, 70, (2, n)))
    po = rng.uniform(0, 2 * np.pi, n)
    wi = np.column_stack([np.sin(ti), np.zeros(n), np.cos(ti)])
    wo = np.column_stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)])
    return wi, wo


def test_condition_number_directions_are_distinct_and_better_than_random():
    values = fill_nodes(node_values_of(synthetic_materials(8)), GRID)
    model = nl.build_nielsen(values, GRID)
    wi, wo = _candidates()
    h = GRID.weights(wi, wo)
    order = nl.select_condition(model, h, 6)
    assert len(set(order.tolist())) == 6
    a = np.asarray(h @ model.basis)[:, :6]
    chosen = np.linalg.cond(a[order])
    rnd = np.median([np.linalg.cond(a[np.random.default_rng(s).choice(len(a), 6, replace=False)]) for s in range(20)])
    assert chosen < rnd


def test_ridge_reconstruction_recovers_a_training_material():
    mats = synthetic_materials(6)
    values = fill_nodes(node_values_of(mats), GRID)
    model = nl.build_nielsen(values, GRID)
    wi, wo = _candidates(300, 1)
    h = GRID.weights(wi, wo)
    f = nl.interpolate(values[2].T, h)
    coef = nl.reconstruct_coefficients(model, h, f, 1e-10)
    pred = nl.predict_nodes(model, coef)
    valid = model.w > 0.05
    rel = np.abs(pred[:, valid] - values[2].T[:, valid]) / values[2].T[:, valid]
    mean_rel = np.abs(nl.predict_nodes(model, 0 * coef)[:, valid] - values[2].T[:, valid]) / values[2].T[:, valid]
    # their cosine-weighted mapping is not linear between nodes: close, not exact
    assert np.median(rel) < 0.005 and np.median(rel) < 0.05 * np.median(mean_rel)
    choice = nl.choose_eta(values, GRID, h, nl.select_condition(model, h, 10), [10])
    assert choice[10][0] in nl.ETAS and 1 <= choice[10][1] <= 10
