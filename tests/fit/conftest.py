"""Synthetic data for the fitting tests: samples generated from analytic models with seeded noise."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.geometry import from_spherical
from gonio.samples import SampleSet


def synth(name: str, params: dict, n: int = 1500, noise: float = 0.01, seed: int = 1, theta_i=None) -> SampleSet:
    """``n`` samples of model ``name`` at random directions (θ < 78°), multiplicative Gaussian noise of
    relative size ``noise`` and matching ``sigma``; ``theta_i`` (radians) fixes the incidence angle."""
    rng = np.random.default_rng(seed)
    ti = np.arccos(rng.uniform(0.21, 1.0, n)) if theta_i is None else np.full(n, theta_i)
    to = np.arccos(rng.uniform(0.21, 1.0, n))
    wi = from_spherical(ti, rng.uniform(0, 2 * np.pi, n))
    wo = from_spherical(to, rng.uniform(0, 2 * np.pi, n))
    # put a third of the outgoing directions near the mirror direction so sharp lobes are sampled
    k = n // 3
    mirror = wi[:k] * np.array([-1.0, -1.0, 1.0])
    jitter = from_spherical(np.abs(rng.normal(0, 0.15, k)), rng.uniform(0, 2 * np.pi, k))
    from gonio.geometry import frame_from_normal, to_world

    wo[:k] = to_world(jitter, frame_from_normal(mirror))
    ok = wo[:, 2] > 0.2
    wi, wo = wi[ok], wo[ok]
    f = make(name, **params).eval(wi, wo)
    y = f * (1.0 + noise * rng.standard_normal(f.shape))
    sigma = np.maximum(noise * f, 1e-9)
    return SampleSet(wi, wo, y, sigma)


@pytest.fixture
def make_samples():
    return synth
