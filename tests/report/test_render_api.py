"""The lit sphere from the top-level Python API: what a notebook user gets (gonio.render_sphere)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import gonio
from gonio.errors import ConfigError


def test_a_rendered_sphere_is_a_png_whose_pixels_are_its_tonemapped_radiance(tmp_path):
    r = gonio.render_sphere(gonio.make("lambert", albedo=[0.8, 0.4, 0.2]), [gonio.light_from_angles(30)], size=64)
    data = r._repr_png_()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    rgba = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert rgba.shape == (64, 64, 4)
    assert np.array_equal(rgba[..., 3] == 255, r.mask)  # transparent exactly off the sphere
    assert np.array_equal(rgba[..., 2::-1][r.mask], r.to_srgb()[r.mask])  # BGR(A) → RGB, the same pixels
    lit = r.to_srgb()[r.mask]
    assert np.all(lit[:, 0] >= lit[:, 1]) and np.all(lit[:, 1] >= lit[:, 2])  # the albedo's colour order
    path = r.save(tmp_path / "sphere.png")
    assert path.read_bytes() == data


def test_saving_a_sphere_under_another_extension_is_refused(tmp_path):
    r = gonio.render_sphere(gonio.make("lambert", albedo=0.5), [gonio.light_from_angles(0)], size=16)
    with pytest.raises(ConfigError, match="sphere.jpg"):
        r.save(tmp_path / "sphere.jpg")
    assert not (tmp_path / "sphere.jpg").exists()
