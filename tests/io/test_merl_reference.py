"""MERL conformance: ``MerlTable.lookup(method="nearest")`` lands in the cell the MERL reference reader
(``BRDFRead.cpp``: std_coords_to_half_diff_coords, theta_half_index, theta_diff_index, phi_diff_index,
lookup_brdf_val) reads, bit for bit, on its own 16×64×16×64 printed grid, on random directions and on
the boundary cases (exact in-plane pairs φd = 0 or π, whole-degree θd, wi = wo).

The port below is written here, independently of gonio, straight from the C code: scalar C-library
math (Python's ``math`` wraps the C library), operations in the C order, double precision. For speed
it runs elementwise over NumPy arrays (+ − × / sqrt are correctly rounded, so NumPy's equal C's; the
transcendental functions are the C library's, applied element by element).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.io.merl import SHAPE, MerlTable
from gonio.io.merl_index import directions_from_angles, reference_index

M_PI = 3.1415926535897932384626433832795
RES_TH, RES_TD, RES_PD = 90, 90, 360


def _elementwise(f, n=1):
    u = np.frompyfunc(f, n, 1)

    def call(*a):
        with np.errstate(invalid="ignore"):
            return np.asarray(u(*a), dtype=np.float64)

    return call


def _acos(x):
    return math.acos(x) if -1.0 <= x <= 1.0 else math.nan


cos, sin, acos, atan2 = _elementwise(math.cos), _elementwise(math.sin), _elementwise(_acos), _elementwise(math.atan2, 2)


# --- the port ------------------------------------------------------------------------------------------
def cross_product(v1, v2):
    return [v1[1] * v2[2] - v1[2] * v2[1], v1[2] * v2[0] - v1[0] * v2[2], v1[0] * v2[1] - v1[1] * v2[0]]


def normalize(v):
    length = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return [v[0] / length, v[1] / length, v[2] / length]


def rotate_vector(vector, axis, angle):
    cos_ang = cos(angle)
    sin_ang = sin(angle)
    out = [vector[0] * cos_ang, vector[1] * cos_ang, vector[2] * cos_ang]
    temp = axis[0] * vector[0] + axis[1] * vector[1] + axis[2] * vector[2]
    temp = temp * (1.0 - cos_ang)
    out[0] = out[0] + axis[0] * temp
    out[1] = out[1] + axis[1] * temp
    out[2] = out[2] + axis[2] * temp
    cross = cross_product(axis, vector)
    out[0] = out[0] + cross[0] * sin_ang
    out[1] = out[1] + cross[1] * sin_ang
    out[2] = out[2] + cross[2] * sin_ang
    return out


def half_diff_from_vectors(in_vec, out_vec):
    """The body of std_coords_to_half_diff_coords after the two vectors are built."""
    in_ = normalize(list(in_vec))
    half = normalize([(in_vec[0] + out_vec[0]) / 2.0, (in_vec[1] + out_vec[1]) / 2.0,
                      (in_vec[2] + out_vec[2]) / 2.0])
    theta_half = acos(half[2])
    fi_half = atan2(half[1], half[0])
    bi_normal = [0.0, 1.0, 0.0]
    normal = [0.0, 0.0, 1.0]
    temp = rotate_vector(in_, normal, -fi_half)
    diff = rotate_vector(temp, bi_normal, -theta_half)
    theta_diff = acos(diff[2])
    fi_diff = atan2(diff[1], diff[0])
    return theta_half, fi_half, theta_diff, fi_diff


def _on_unique(f, x):
    """f elementwise, computed once per distinct value (the grids repeat few angles)."""
    u, inv = np.unique(np.asarray(x, dtype=np.float64), return_inverse=True)
    return f(u)[inv].reshape(np.shape(x))


def std_vector(theta, fi):
    z = _on_unique(cos, theta)
    proj = _on_unique(sin, theta)
    return [proj * _on_unique(cos, fi), proj * _on_unique(sin, fi), z]


def std_coords_to_half_diff_coords(theta_in, fi_in, theta_out, fi_out):
    return half_diff_from_vectors(std_vector(theta_in, fi_in), std_vector(theta_out, fi_out))


def c_int(x):
    """(int) x: truncation toward zero; NaN → INT_MIN (x86-64 cvttsd2si)."""
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        return np.where(np.isnan(x), -(2 ** 31), np.trunc(np.nan_to_num(x))).astype(np.int64)


def theta_half_index(theta_half):
    theta_half_deg = (theta_half / (M_PI / 2.0)) * RES_TH
    temp = theta_half_deg * RES_TH
    with np.errstate(invalid="ignore"):
        temp = np.sqrt(temp)
    ret_val = c_int(temp)
    ret_val = np.where(ret_val < 0, 0, ret_val)
    ret_val = np.where(ret_val >= RES_TH, RES_TH - 1, ret_val)
    return np.where(theta_half <= 0.0, 0, ret_val)


def theta_diff_index(theta_diff):
    tmp = c_int(theta_diff / (M_PI * 0.5) * RES_TD)
    return np.where(tmp < 0, 0, np.where(tmp < RES_TD - 1, tmp, RES_TD - 1))


def phi_diff_index(phi_diff):
    phi_diff = np.where(phi_diff < 0.0, phi_diff + M_PI, phi_diff)
    tmp = c_int(phi_diff / M_PI * RES_PD / 2)
    return np.where(tmp < 0, 0, np.where(tmp < RES_PD // 2 - 1, tmp, RES_PD // 2 - 1))


def lookup_index(theta_half, theta_diff, fi_diff):
    """The flat index of lookup_brdf_val."""
    return (phi_diff_index(fi_diff) + theta_diff_index(theta_diff) * RES_PD // 2
            + theta_half_index(theta_half) * RES_PD // 2 * RES_TD)


def reference_flat_index_angles(ti, pi_, to, po):
    th, _, td, pd = std_coords_to_half_diff_coords(ti, pi_, to, po)
    return lookup_index(th, td, pd)


def reference_flat_index_vectors(wi, wo):
    th, _, td, pd = half_diff_from_vectors([wi[..., k] for k in range(3)], [wo[..., k] for k in range(3)])
    return lookup_index(th, td, pd)


# --- fixtures --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def table():
    """Every cell a different value, so equal values mean the same cell."""
    flat = np.arange(np.prod(SHAPE), dtype=np.float64).reshape(SHAPE)
    return MerlTable(np.stack([flat, flat + 0.25, flat + 0.5], axis=-1))


def gonio_flat_index(wi, wo):
    i_h, i_d, i_p = reference_index(wi, wo)
    return i_p + 180 * (i_d + 90 * i_h)


def printed_grid():
    """BRDFRead.cpp main(): n = 16; θin = i·0.5·π/n, φin = j·2π/(4n), θout = k·0.5·π/n, φout = l·2π/(4n)."""
    n = 16
    i, j, k, l = np.meshgrid(np.arange(n), np.arange(4 * n), np.arange(n), np.arange(4 * n), indexing="ij")
    f = np.float64
    return (i * f(0.5) * M_PI / n, j * f(2.0) * M_PI / (4 * n), k * f(0.5) * M_PI / n, l * f(2.0) * M_PI / (4 * n))


def test_the_ports_operation_order_matches_the_c_grid_expression():
    # i * 0.5 * M_PI / n is evaluated left to right in C
    assert printed_grid()[0][3, 0, 0, 0] == ((3 * 0.5) * M_PI) / 16


def test_printed_grid_matches_the_reference_reader_bit_for_bit(table):
    ti, pi_, to, po = printed_grid()
    expect = reference_flat_index_angles(ti, pi_, to, po)
    wi, wo = directions_from_angles(ti, pi_, to, po)
    vals = table.lookup(wi, wo, method="nearest")
    got = vals[..., 0].astype(np.int64)  # the table's red value is its own flat index
    mismatch = np.count_nonzero(got != expect)
    assert mismatch == 0, f"{mismatch} of {got.size} grid pairs land in another cell than BRDFRead.cpp"
    # the values read are the reference's (stored × scale of that very cell), bit for bit
    np.testing.assert_array_equal(vals, table.values.reshape(-1, 3)[expect])
    # the grid does exercise the boundaries: in-plane pairs on both sides fold into cells 0 and 179
    assert np.any(expect % 180 == 179) and np.any(expect % 180 == 0)


def test_lookup_by_angles_is_the_reference_lookup(table):
    ti, pi_, to, po = (a[::3, ::5, ::3, ::5] for a in printed_grid())
    np.testing.assert_array_equal(table.lookup_angles(ti, pi_, to, po, method="nearest"),
                                  table.values.reshape(-1, 3)[reference_flat_index_angles(ti, pi_, to, po)])


def test_random_directions_match(table):
    rng = np.random.default_rng(7)
    v = rng.normal(size=(2, 200_000, 3))
    v[..., 2] = np.abs(v[..., 2])
    wi, wo = v[0], v[1]  # not normalized: the reference normalizes `in` but halves the raw vectors
    np.testing.assert_array_equal(gonio_flat_index(wi, wo), reference_flat_index_vectors(wi, wo))


def test_in_plane_pairs_phi_d_zero_or_pi():
    # exact in-plane configurations: wi and wo in one plane through the normal, same or opposite sides,
    # at many azimuths and whole-degree and grid elevations
    deg = np.radians(np.arange(0.0, 90.0, 2.0))
    phis = np.concatenate([np.radians(np.arange(0.0, 360.0, 30.0)), [M_PI, M_PI / 2, -M_PI / 2]])
    T1, T2, P = np.meshgrid(deg, deg, phis, indexing="ij")
    for other in (P, P + M_PI):  # same side (φd ≈ 0/π) and opposite sides
        expect = reference_flat_index_angles(T1, P, T2, other)
        wi, wo = directions_from_angles(T1, P, T2, other)
        got = gonio_flat_index(wi, wo)
        assert np.count_nonzero(got != expect) == 0
        assert set(np.unique(expect % 180)) <= {0, 179, 89, 90} | set(np.unique(got % 180))


def test_in_plane_axis_aligned_vectors_and_signed_zeros():
    # vectors with exact zeros (including −0.0): the sign of zero decides atan2 = 0 or π, i.e. cell 0 or 179
    cases = []
    for s in (1.0, -1.0):
        for z in (0.0, -0.0):
            for a in np.radians([10.0, 30.0, 45.0, 60.0, 89.0]):
                for b in np.radians([0.0, 5.0, 30.0, 45.0, 80.0]):
                    cases.append(([s * math.sin(a), z, math.cos(a)], [s * -math.sin(b), z, math.cos(b)]))
                    cases.append(([z, s * math.sin(a), math.cos(a)], [z, s * math.sin(b), math.cos(b)]))
    wi = np.array([c[0] for c in cases])
    wo = np.array([c[1] for c in cases])
    expect = reference_flat_index_vectors(wi, wo)
    np.testing.assert_array_equal(gonio_flat_index(wi, wo), expect)
    assert {0, 179} <= set((expect % 180).tolist())


def test_whole_degree_theta_d():
    # pairs built at whole-degree θd (cell boundaries of the θd index) and φd at whole half-degrees
    from gonio.geometry import dirs_from_half_diff

    th = np.radians(np.array([0.0, 1.0, 7.0, 20.0, 33.0, 45.0]))
    td = np.radians(np.arange(0.0, 90.0, 1.0))
    pd = np.radians(np.arange(-180.0, 180.0, 7.5))
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    wi, wo = dirs_from_half_diff(TH, np.full_like(TH, 0.3), TD, PD)
    np.testing.assert_array_equal(gonio_flat_index(wi, wo), reference_flat_index_vectors(wi, wo))


def test_wi_equals_wo():
    t = np.radians(np.arange(0.0, 90.0, 0.5))
    p = np.radians(np.arange(0.0, 360.0, 10.0))
    T, P = np.meshgrid(t, p, indexing="ij")
    expect = reference_flat_index_angles(T, P, T, P)
    wi, wo = directions_from_angles(T, P, T, P)
    np.testing.assert_array_equal(gonio_flat_index(wi, wo), expect)
    # and with the very same array object for both
    np.testing.assert_array_equal(gonio_flat_index(wi, wi), reference_flat_index_vectors(wi, wi))


def test_nan_and_out_of_range_clamp_like_c():
    from gonio.io.merl_index import half_diff_index

    i_h, i_d, i_p = half_diff_index(np.array([np.nan, -1.0, 0.0, 2.0, M_PI / 2]),
                                    np.array([np.nan, -0.5, 0.0, 3.0, M_PI / 2]),
                                    np.array([np.nan, -M_PI, M_PI, -1e-300, 0.0]))
    assert i_h.tolist() == [0, 0, 0, 89, 89]
    assert i_d.tolist() == [0, 0, 0, 89, 89]
    assert i_p.tolist() == [0, 0, 179, 179, 0]
    assert (theta_half_index(np.array([M_PI / 2])) == 89).all()
