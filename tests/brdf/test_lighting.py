"""The lighting-model form of lecture notes 000 (gonio.brdf.lighting.shade)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf.lighting import shade
from gonio.errors import ConfigError
from gonio.lights import DirectionalLight, PointLight


def test_hand_computed_value():
    light = DirectionalLight([0, 0, -1], irradiance=[1.0, 0.5, 0.25])
    v = np.array([np.sin(0.2), 0, np.cos(0.2)])
    c = shade([0, 0, 0], [0, 0, 1], v, [light], ka=0.1, ca=[1, 1, 1], kd=0.6, ks=0.3, s=20)
    h = (v + [0, 0, 1]) / np.linalg.norm(v + [0, 0, 1])
    expect = 0.1 + np.array([1.0, 0.5, 0.25]) * (0.6 * 1.0 + 0.3 * h[2] ** 20)
    np.testing.assert_allclose(c, expect)


def test_schlick_option_and_ambient_only_behind():
    lights = [PointLight([0.5, 0, 1.0], 2.0), DirectionalLight([0, 0.3, -1], 0.7)]
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.1, 0.1, (3, 4, 3))
    v = np.array([0.2, -0.1, 1.0])
    exact = shade(pts, [0, 0, 1], v, lights, ka=0.05, ca=1, s=30)
    fast = shade(pts, [0, 0, 1], v, lights, ka=0.05, ca=1, s=30, schlick=True)
    assert exact.shape == fast.shape == (3, 4, 3)
    assert np.all(fast >= exact * 0.999)  # t/(s - s t + t) >= t^s on [0, 1] for s >= 1
    # Lights behind the surface: only the ambient term is left.
    back = shade(pts, [0, 0, -1], v, lights, ka=0.05, ca=[1, 2, 3], s=30)
    np.testing.assert_allclose(back, np.broadcast_to([0.05, 0.1, 0.15], (3, 4, 3)))


@pytest.mark.parametrize("s", [0.0, 1e6])
def test_extreme_shininess_is_finite(s):
    c = shade(np.zeros((5, 3)), [0, 0, 1], [[0, 0, 1], [1, 0, 0], [0, 0, -1], [1, 0, 1e-17], [0, 0, 0]],
              [DirectionalLight([1, 0, -1e-3])], s=s, schlick=bool(s))
    assert np.all(np.isfinite(c)) and np.all(c >= 0)


def test_bad_input():
    with pytest.raises(ConfigError, match="lighting.s"):
        shade([0, 0, 0], [0, 0, 1], [0, 0, 1], [], s=-1)
    with pytest.raises(ConfigError, match="lighting.kd"):
        shade([0, 0, 0], [0, 0, 1], [0, 0, 1], [], kd=[1, 2])
