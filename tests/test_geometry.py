"""gonio.geometry: conversions, frames, Rusinkiewicz angles, normal transforms — and their edges."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gonio import geometry as g
from gonio.errors import ConfigError

angle_t = st.floats(0.0, np.pi / 2)
angle_p = st.floats(0.0, 2 * np.pi, exclude_max=True)


def test_spherical_convention():
    # φ from +x toward +y: θ=90°, φ=90° is +y.
    np.testing.assert_allclose(g.from_spherical(np.pi / 2, np.pi / 2), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(g.from_spherical(0.0, 1.234), [0, 0, 1])
    theta, phi = g.to_spherical([0.0, -1.0, 0.0])
    assert theta == pytest.approx(np.pi / 2) and phi == pytest.approx(3 * np.pi / 2)


def test_pole_has_defined_phi():
    theta, phi = g.to_spherical(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]))
    np.testing.assert_array_equal(phi, 0.0)
    np.testing.assert_allclose(theta, [0.0, np.pi, 0.0])


def test_spherical_accurate_near_pole():
    # arccos(z) loses all digits at θ = 1e-9; atan2 keeps them.
    v = g.from_spherical(1e-9, 0.3)
    assert g.to_spherical(v)[0] == pytest.approx(1e-9, rel=1e-12)


@given(angle_t, angle_p)
def test_spherical_round_trip(theta, phi):
    t2, p2 = g.to_spherical(g.from_spherical(theta, phi))
    assert t2 == pytest.approx(theta, abs=1e-12)
    if np.sin(theta) > 1e-9:  # φ is meaningless at the pole
        assert np.cos(p2 - phi) == pytest.approx(1.0, abs=1e-12)


def test_reflect_matches_lecture_formula():
    L = g.normalize([1.0, 2.0, 3.0])
    n = g.normalize([0.2, -0.1, 1.0])
    R = g.reflect(L, n)
    np.testing.assert_allclose(R, 2 * np.dot(L, n) * n - L)
    assert np.dot(R, n) == pytest.approx(np.dot(L, n))


def test_half_vector_of_opposite_directions_is_normal():
    wi = g.from_spherical(np.pi / 2, 0.0)
    h = g.half_vector(wi, -wi)
    np.testing.assert_array_equal(h, [0, 0, 1])
    assert np.all(np.isfinite(g.half_diff_from_dirs(wi, -wi)))


def test_normalize_zero_vector_is_defined():
    np.testing.assert_array_equal(g.normalize(np.zeros((2, 3))), [[0, 0, 1], [0, 0, 1]])


@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))
def test_orthonormal_basis(x, y, z):
    n = np.array([x, y, z])
    if np.linalg.norm(n) < 1e-6:
        return
    n = g.normalize(n)
    t, b = g.orthonormal_basis(n)
    m = np.stack([t, b, n])
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(m) == pytest.approx(1.0)


def test_frame_uses_tangent_and_is_right_handed():
    f = g.frame_from_normal([0, 0, 2.0], tangent=[1.0, 1.0, 0.5])
    np.testing.assert_allclose(f[0], g.normalize([1.0, 1.0, 0.0]), atol=1e-15)
    np.testing.assert_allclose(f[1], np.cross(f[2], f[0]))
    # tangent parallel to the normal falls back to a valid frame
    f2 = g.frame_from_normal([0, 0, 1.0], tangent=[0, 0, 5.0])
    np.testing.assert_allclose(f2 @ f2.T, np.eye(3), atol=1e-12)


def test_local_world_round_trip_nd():
    rng = np.random.default_rng(1)
    n = g.normalize(rng.normal(size=(4, 5, 3)))
    frames = g.frame_from_normal(n)
    v = rng.normal(size=(4, 5, 3))
    np.testing.assert_allclose(g.to_world(g.to_local(v, frames), frames), v, atol=1e-12)
    np.testing.assert_allclose(g.to_local(n, frames), np.broadcast_to([0, 0, 1.0], n.shape), atol=1e-12)


def test_rusinkiewicz_known_values():
    # Mirror configuration: h = n, θh = 0, θd = θi, and φd = φi (φh = 0 by convention).
    wi = g.from_spherical(0.5, 0.0)
    wo = g.from_spherical(0.5, np.pi)
    th, ph, td, pd = g.half_diff_from_dirs(wi, wo)
    assert th == pytest.approx(0.0, abs=1e-12) and td == pytest.approx(0.5)
    # Retro-reflection: wi = wo, so d = +z (θd = 0) and h = wi.
    th, ph, td, pd = g.half_diff_from_dirs(wi, wi)
    assert th == pytest.approx(0.5) and td == pytest.approx(0.0, abs=1e-7)


@given(angle_t, angle_p, angle_t, angle_p)
def test_rusinkiewicz_round_trip(ti, pi_, to, po):
    wi, wo = g.dirs_from_angles(ti, pi_, to, po)
    angles = g.half_diff_from_dirs(wi, wo)
    assert all(np.isfinite(a) for a in angles)
    if np.linalg.norm(wi + wo) < 1e-6:
        return  # wi = −wo: no half vector, documented fallback
    wi2, wo2 = g.dirs_from_half_diff(*angles)
    np.testing.assert_allclose(wi2, wi, atol=1e-9)
    np.testing.assert_allclose(wo2, wo, atol=1e-9)


def test_rusinkiewicz_vectorized_matches_scalar():
    rng = np.random.default_rng(2)
    wi = g.normalize(np.abs(rng.normal(size=(3, 4, 3))))
    wo = g.normalize(np.abs(rng.normal(size=(3, 4, 3))))
    batch = g.half_diff_from_dirs(wi, wo)
    for idx in [(0, 0), (2, 3), (1, 2)]:
        single = g.half_diff_from_dirs(wi[idx], wo[idx])
        np.testing.assert_allclose([b[idx] for b in batch], single, atol=1e-14)


def test_half_diff_from_dirs_is_its_docstring_to_the_bit():
    """half_diff_from_dirs rotates wi component by component: the very numbers of rotate_y(rotate_z(wi, −φh), −θh)
    with h = half_vector(wi, wo), wi = −wo and zero vectors included, broadcasting a single wi."""
    rng = np.random.default_rng(5)
    wi, wo = rng.normal(size=(2, 2000, 3))
    wo[:5] = -wi[:5]
    wi[5:8] = 0.0
    for a, b in ((wi, wo), (wi[0], wo), (wi[:, None][:4], wo[None, :6])):
        th, ph, td, pd = g.half_diff_from_dirs(a, b)
        a, b = g.normalize(a), g.normalize(b)
        th0, ph0 = g.to_spherical(g.half_vector(a, b))
        td0, pd0 = g.to_spherical(g.rotate_y(g.rotate_z(a, -ph0), -th0))
        for x, y in ((th, th0), (ph, ph0), (td, td0), (pd, pd0)):
            assert x.shape == y.shape and np.array_equal(x, y)


def test_normal_transform_inverse_transpose_under_nonuniform_scale():
    # A 45° plane x + y = 0 squashed along x: normals transformed like points go wrong.
    m = np.diag([2.0, 1.0, 1.0])
    n = g.normalize([1.0, 1.0, 0.0])
    tangent = np.array([1.0, -1.0, 0.0])
    n2 = g.transform_normals(m, n)
    assert np.dot(n2, m @ tangent) == pytest.approx(0.0, abs=1e-15)
    assert abs(np.dot(g.normalize(m @ n), m @ tangent)) > 0.3  # the naive way is wrong
    m4 = np.eye(4)
    m4[:3, :3] = m
    m4[:3, 3] = [5, 6, 7]
    np.testing.assert_allclose(g.transform_normals(m4, n), n2)
    with pytest.raises(ConfigError, match="singular"):
        g.transform_normals(np.diag([1.0, 0.0, 1.0]), n)
