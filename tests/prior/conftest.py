"""Synthetic priors from analytic models (no real data): small grids, so every test takes seconds."""

import numpy as np
import pytest

from gonio.brdf import make
from gonio.prior import PriorGrid, build_prior

GRID = PriorGrid(14, 10, 8)


def synthetic_materials(n: int, seed: int = 0):
    """``n`` Lambert + GGX materials with random colours and roughness (name, model)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        kd = rng.uniform(0.02, 0.3, 3)
        ks = rng.uniform(0.2, 1.0, 3)
        out.append((f"m{i}", make("microfacet", kd=kd, ks=ks, alpha=float(rng.uniform(0.15, 0.6)), f0=[0.05] * 3)))
    return out


def node_values_of(models, grid=GRID):
    wi, wo = grid.node_directions()
    return np.stack([m.eval(wi, wo) for _, m in models])


@pytest.fixture(scope="module")
def synthetic_prior():
    """A prior of 8 synthetic materials keeping every component, in-sample variances (residual ~ 0)."""
    mats = synthetic_materials(8)
    return build_prior(node_values_of(mats), [n for n, _ in mats], GRID, calibrate=False,
                       weight=np.full(GRID.size, 1.0 / GRID.size))
