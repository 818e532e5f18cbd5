"""gonio.lights: inverse-square law, cosine law, spot cone, linearity, validation."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.errors import ConfigError
from gonio.lights import DirectionalLight, PointLight, SpotLight, total_irradiance


def test_point_light_inverse_square_and_cosine_law():
    light = PointLight([0, 0, 2.0], intensity=[4.0, 2.0, 1.0])
    to_l, e = light.illuminate([[0, 0, 0], [2.0, 0, 0]], [0, 0, 1])
    np.testing.assert_allclose(to_l[0], [0, 0, 1])
    np.testing.assert_allclose(e[0], [1.0, 0.5, 0.25])  # I / r^2
    r2, cos = 8.0, 2 / np.sqrt(8)
    np.testing.assert_allclose(e[1], np.array([4.0, 2.0, 1.0]) * cos / r2)
    # Behind the surface: clamped at 0.
    assert np.all(light.illuminate([0, 0, 0], [0, 0, -1])[1] == 0)


def test_point_light_polynomial_attenuation_and_point_at_light_is_finite():
    light = PointLight([0, 0, 1.0], 1.0, attenuation=(0.0, 0.0, 1.0))  # no falloff
    np.testing.assert_allclose(light.illuminate([0, 0, -9.0], [0, 0, 1])[1], 1.0)
    light = PointLight([0, 0, 1.0], 1.0, attenuation=(1.0, 2.0, 3.0))
    np.testing.assert_allclose(light.incident([0, 0, -1.0])[1], 1 / (4 + 4 + 3))
    assert np.all(np.isfinite(PointLight([0, 0, 0.0]).illuminate([0, 0, 0.0], [0, 0, 1])[1]))


def test_directional_light_everywhere_the_same():
    light = DirectionalLight([0, -1, -1], irradiance=2.0)
    pts = np.random.default_rng(0).normal(size=(4, 5, 3))
    to_l, e = light.illuminate(pts, [0, 0, 1])
    assert to_l.shape == e.shape == (4, 5, 3)
    np.testing.assert_allclose(to_l, np.broadcast_to([0, 1 / np.sqrt(2), 1 / np.sqrt(2)], (4, 5, 3)))
    np.testing.assert_allclose(e, 2.0 / np.sqrt(2))


def test_spot_light_hotspot_falloff_smooth_between():
    spot = SpotLight([0, 0, 1.0], [0, 0, -1], intensity=1.0, hotspot=np.radians(10), falloff=np.radians(30),
                     attenuation=(0, 0, 1))
    angles = np.radians([0, 9.9, 20, 29.9, 30.1, 80])
    pts = np.stack([np.tan(angles), np.zeros(6), np.zeros(6)], axis=-1)
    _, e = spot.incident(pts)
    assert e[0, 0] == 1.0 and e[1, 0] == 1.0
    assert 0 < e[3, 0] < e[2, 0] < 1
    assert e[4, 0] == 0 and e[5, 0] == 0
    c = spot.cone(np.cos(np.radians(np.linspace(0, 40, 200))))
    assert np.all(np.diff(c) <= 0)  # monotone, continuous falloff


def test_lights_add_linearly():
    a = PointLight([0.3, 0, 1.0], 2.0)
    b = SpotLight([0, 0.2, 1.5], [0, 0, -1], 3.0)
    c = DirectionalLight([0.1, 0, -1], 0.5)
    pts = np.random.default_rng(1).uniform(-0.2, 0.2, (10, 3)) * [1, 1, 0]
    n = [0, 0, 1.0]
    total = total_irradiance([a, b, c], pts, n)
    np.testing.assert_allclose(total, sum(light.illuminate(pts, n)[1] for light in (a, b, c)))
    np.testing.assert_allclose(total_irradiance([a, a], pts, n), 2 * a.illuminate(pts, n)[1])


@pytest.mark.parametrize("make,field", [
    (lambda: PointLight([0, 0]), "point_light.position"),
    (lambda: PointLight([0, 0, 1], intensity=-1), "point_light.intensity"),
    (lambda: PointLight([0, 0, 1], attenuation=(0, 0, 0)), "point_light.attenuation"),
    (lambda: DirectionalLight([0, 0, 0]), "directional_light.direction"),
    (lambda: SpotLight([0, 0, 1], [0, 0, -1], hotspot=0.5, falloff=0.2), "spot_light.hotspot"),
])
def test_bad_light_parameters(make, field):
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        make()
    with pytest.raises(AttributeError):
        PointLight([0, 0, 1]).intensity = 2
