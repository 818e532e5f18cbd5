"""MERL binary: independent writer, round trips, lookups, bad files."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from gonio.errors import DataError
from gonio.geometry import dirs_from_half_diff
from gonio.io.merl import (FILE_SIZE, SHAPE, MerlTable, cell_centres, cell_directions, grid_index,
                           read_merl, write_merl)

N = 90 * 90 * 180
SCALES = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)


def independent_stored() -> np.ndarray:
    """Stored values, channel-major, flat index = φd + 180·(θd + 90·θh), straight from the spec."""
    flat = np.arange(N, dtype=np.float64)
    stored = np.stack([flat * 1e-3 + 1.0, flat * 2e-3 + 2.0, flat * 3e-3 + 3.0])
    stored[:, ::97] = -1.0  # not measured
    return stored


@pytest.fixture(scope="module")
def independent_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "independent.binary"
    stored = independent_stored()
    with open(path, "wb") as fh:
        fh.write(struct.pack("<3i", 90, 90, 180))
        for c in range(3):
            fh.write(struct.pack(f"<{N}d", *stored[c].tolist()))
    return path


def test_file_size_constant():
    assert FILE_SIZE == 12 + 3 * 1_458_000 * 8 == 34_992_012


def test_independent_file_reads_back_exactly(independent_file):
    assert independent_file.stat().st_size == FILE_SIZE
    table = read_merl(independent_file)
    stored = independent_stored()
    assert table.values.shape == (90, 90, 180, 3)
    for c in range(3):
        expect = stored[c] * SCALES[c]
        expect[stored[c] < 0] = np.nan
        got = table.values[..., c].ravel()  # C order over (θh, θd, φd) == the spec's flat index
        np.testing.assert_array_equal(got, expect)
    # one cell spelled out: θh 7, θd 11, φd 13, green
    flat = 13 + 180 * (11 + 90 * 7)
    assert table.values[7, 11, 13, 1] == stored[1, flat] * (1.15 / 1500.0)
    assert np.isnan(table.values.reshape(-1, 3)[97 * 5]).all()


def test_nearest_lookup_uses_spec_index(independent_file):
    table = read_merl(independent_file)
    th, td, pd = np.radians([10.0, 40.0, 70.0]), np.radians([5.2, 33.3, 61.7]), np.radians([20.3, 250.6, 91.7])
    wi, wo = dirs_from_half_diff(th, np.radians([0.0, 77.0, 300.0]), td, pd)
    got = table.lookup(wi, wo, "nearest")
    for k in range(3):
        ih = min(int(np.sqrt(th[k] / (np.pi / 2)) * 90), 89)
        id_ = min(int(td[k] / (np.pi / 2) * 90), 89)
        ip = min(int(np.mod(pd[k], np.pi) / np.pi * 180), 179)
        np.testing.assert_array_equal(got[k], table.values[ih, id_, ip])


def test_write_read_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    values = rng.uniform(0.0, 50.0, SHAPE + (3,))
    values[rng.random(SHAPE) < 0.2] = np.nan
    values[0, 0, 0] = [-1e-3, 0.0, 2.0]  # noise below zero is written as 0, not as "not measured"
    path = write_merl(tmp_path / "t.binary", MerlTable(values))
    assert path.stat().st_size == FILE_SIZE
    back = read_merl(path)
    np.testing.assert_array_equal(np.isnan(back.values[1:]), np.isnan(values[1:]))
    np.testing.assert_allclose(back.values[1:], values[1:], rtol=1e-15, atol=0, equal_nan=True)
    np.testing.assert_allclose(back.values[0, 0, 0], [0.0, 0.0, 2.0], rtol=1e-15)
    assert not (tmp_path / "t.binary.tmp").exists()


def _table_from(fn) -> MerlTable:
    i, j, k = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    v = fn(i.astype(float), j.astype(float), k.astype(float))
    return MerlTable(np.stack([v, 2 * v, 3 * v], axis=-1))


def _dirs(th_idx, td_idx, pd_idx, phi_h=0.3):
    """Directions whose continuous index-space coordinates are (th_idx, td_idx, pd_idx) (+ ½ = centre)."""
    th = (np.asarray(th_idx) / 90) ** 2 * (np.pi / 2)
    td = np.asarray(td_idx) / 90 * (np.pi / 2)
    pd = np.asarray(pd_idx) / 180 * np.pi
    return dirs_from_half_diff(th, np.full_like(th, phi_h), td, pd)


def test_trilinear_is_linear_in_index_space():
    table = _table_from(lambda i, j, k: 1.0 + 0.5 * i + 0.25 * j + 0.125 * k)
    # random points strictly between cell centres, away from edges and the φd seam
    rng = np.random.default_rng(2)
    u = np.stack([rng.uniform(3, 40, 200), rng.uniform(3, 30, 200), rng.uniform(3, 170, 200)])
    wi, wo = _dirs(*u)
    got = table.lookup(wi, wo, method="trilinear")
    expect = 1.0 + 0.5 * (u[0] - 0.5) + 0.25 * (u[1] - 0.5) + 0.125 * (u[2] - 0.5)
    np.testing.assert_allclose(got[:, 0], expect, rtol=1e-9)
    np.testing.assert_allclose(got[:, 2], 3 * expect, rtol=1e-9)
    # at cell centres trilinear == nearest
    wi, wo = _dirs(np.array([10.5, 50.5]), np.array([20.5, 7.5]), np.array([33.5, 120.5]))
    np.testing.assert_allclose(table.lookup(wi, wo, "trilinear"), table.lookup(wi, wo, "nearest"), rtol=1e-9)


def test_trilinear_is_periodic_at_the_phi_d_seam():
    table = _table_from(lambda i, j, k: np.where(k == 179, 10.0, np.where(k == 0, 20.0, 0.0)))
    # φd = 0 (and = π, its reciprocal twin) lies halfway between the centres of cells 179 and 0
    for pd_idx in (0.0, 180.0, 360.0 - 1e-9):
        wi, wo = _dirs(np.array([20.5]), np.array([30.5]), np.array([pd_idx]))
        np.testing.assert_allclose(table.lookup(wi, wo, "trilinear")[0, 0], 15.0, rtol=1e-6)
    # swapping wi and wo (reciprocity) gives the same value everywhere
    rng = np.random.default_rng(3)
    wi, wo = _dirs(rng.uniform(0, 60, 50), rng.uniform(0, 40, 50), rng.uniform(0, 180, 50))
    np.testing.assert_allclose(table.lookup(wi, wo, "trilinear"), table.lookup(wo, wi, "trilinear"), atol=1e-9)


def test_lookup_not_measured_horizon_and_shapes():
    table = _table_from(lambda i, j, k: 1.0 + 0 * i)
    values = table.values.copy()
    values[20, 30, :] = np.nan
    table = MerlTable(values)
    wi, wo = _dirs(np.full((2, 2), 20.5), np.full((2, 2), 30.5), np.full((2, 2), 50.5))
    assert table.lookup(wi, wo).shape == (2, 2, 3)
    assert np.isnan(table.lookup(wi, wo)).all()
    assert np.isnan(table.lookup(wi, wo, "trilinear")).all()
    # next to a hole, trilinear renormalizes over the measured corners
    wi, wo = _dirs(np.array([21.0]), np.array([30.5]), np.array([50.5]))
    np.testing.assert_allclose(table.lookup(wi, wo, "trilinear"), [[1.0, 2.0, 3.0]])
    # below the horizon: exactly 0
    below = np.array([[0.0, 0.6, -0.8]])
    assert (table.lookup(below, np.array([[0.0, 0.0, 1.0]])) == 0).all()
    with pytest.raises(ValueError, match="method"):
        table.lookup(wi, wo, "cubic")


def test_cell_directions_fall_in_their_own_cells():
    wi, wo, above = cell_directions(phi_h=1.1)
    th, td, pd = cell_centres()
    from gonio.geometry import half_diff_from_dirs

    a = half_diff_from_dirs(wi[::7, ::5, ::11], wo[::7, ::5, ::11])
    i_h, i_d, i_p = grid_index(a[0], a[2], a[3])
    I, J, K = np.meshgrid(np.arange(0, 90, 7), np.arange(0, 90, 5), np.arange(0, 180, 11), indexing="ij")
    assert (i_h == I).all() and (i_d == J).all() and (i_p == K).all()
    assert above[0, 0, 0] and not above[89, 89, 0]
    assert th[0] == pytest.approx((0.5 / 90) ** 2 * np.pi / 2)


def test_to_samples_uses_measured_cells_above_horizon():
    table = _table_from(lambda i, j, k: 0.1 + 0 * i)
    values = table.values.copy()
    values[:, 45:] = np.nan
    s = MerlTable(values).to_samples()
    assert len(s) > 0 and (s.wi[:, 2] > 0).all() and (s.wo[:, 2] > 0).all()
    np.testing.assert_allclose(s.f, np.tile([0.1, 0.2, 0.3], (len(s), 1)))
    assert (s.sigma > 0).all()


# -- bad files --------------------------------------------------------------------------------

def _sparse(path, size, header=(90, 90, 180), patch=None):
    with open(path, "wb") as fh:
        fh.write(struct.pack("<3i", *header))
        fh.truncate(size)
        if patch is not None:
            fh.seek(patch[0])
            fh.write(patch[1])
    return path


@pytest.mark.parametrize(
    "size, header, patch, message",
    [
        (12 + 800, (90, 90, 180), None, "truncated: 812 bytes"),
        (8, (90, 90, 180), None, "truncated header"),
        (10, (90, 90, 180), None, "truncated header"),  # not a multiple of the int32 size
        (0, (90, 90, 180), None, "truncated header"),
        (FILE_SIZE + 8, (90, 90, 180), None, "trailing data"),
        (FILE_SIZE, (90, 90, 360), None, r"header dims \(90, 90, 360\)"),
        (FILE_SIZE, (90, 90, 180), (12 + 8 * (N + 5), struct.pack("<d", float("nan"))), "NaN or inf.*channel G"),
    ],
)
def test_bad_files_raise_data_error_naming_file(tmp_path, size, header, patch, message):
    path = _sparse(tmp_path / "bad.binary", size, header, patch)
    if size < 12:
        path.write_bytes(path.read_bytes()[:size])
    with pytest.raises(DataError, match=message) as info:
        read_merl(path)
    assert "bad.binary" in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="nothere.binary: cannot read"):
        read_merl(tmp_path / "nothere.binary")


def test_bad_table_shape_and_inf():
    with pytest.raises(DataError, match="shape"):
        MerlTable(np.zeros((90, 90, 360, 3)))
    v = np.zeros(SHAPE + (3,))
    v[1, 2, 3, 0] = np.inf
    with pytest.raises(DataError, match="infinite"):
        write_merl("/tmp/never-written.binary", MerlTable(v))


@pytest.mark.parametrize("phi_h", [0.0, 0.7])
def test_cell_directions_are_the_inverse_of_the_half_difference_map_at_every_cell(phi_h):
    wi, wo, above = cell_directions(phi_h)
    th, td, pd = np.meshgrid(*cell_centres(), indexing="ij")
    wi2, wo2 = dirs_from_half_diff(th, np.full_like(th, phi_h), td, pd)
    np.testing.assert_allclose(wi, wi2, atol=1e-14)
    np.testing.assert_allclose(wo, wo2, atol=1e-14)
    assert np.array_equal(above, (wi2[..., 2] > 0) & (wo2[..., 2] > 0))


def test_cell_directions_are_computed_once_and_shared_read_only():
    """The φh = 0 directions are one process-wide read-only copy (a caller cannot change what the next one gets);
    another φh gives new arrays, the φh = 0 ones turned about z."""
    wi, wo, above = cell_directions()
    again = cell_directions(0.0)
    assert all(a is b for a, b in zip((wi, wo, above), again))
    for a in (wi, wo, above):
        assert not a.flags.writeable
        with pytest.raises(ValueError):
            a[0, 0, 0] = 0
    wi_t, wo_t, above_t = cell_directions(0.7)
    assert wi_t.flags.writeable and wi_t is not wi and np.array_equal(above_t, above)
    c, s = np.cos(0.7), np.sin(0.7)
    np.testing.assert_array_equal(wi_t[..., 0], c * wi[..., 0] - s * wi[..., 1])
    np.testing.assert_array_equal(wo_t[..., 1], s * wo[..., 0] + c * wo[..., 1])
    np.testing.assert_array_equal(wi_t[..., 2], wi[..., 2])


@pytest.mark.parametrize("shape", [(3,), (7, 3), (90, 90, 180, 3), (5, 4, 3), (6, 2), (4,), ()])
def test_all_channels_is_np_all_over_the_last_axis(shape):
    """gonio.samples.all_channels (MerlTable.measured, tabulation's and the cell accumulator's valid samples, the
    goodness-of-fit's equal neighbours) gives np.all(mask, axis=-1), for RGB arrays and any other last axis; and a
    table's measured cells are those finite in every channel."""
    from gonio.samples import all_channels

    rng = np.random.default_rng(len(shape))
    mask = rng.random(shape) < 0.8
    assert np.array_equal(all_channels(mask), np.all(mask, axis=-1))
    if shape == (90, 90, 180, 3):
        values = np.where(mask, rng.random(shape), np.where(rng.random(shape) < 0.5, np.nan, np.inf))
        measured = MerlTable(values).measured
        assert measured.shape == SHAPE and np.array_equal(measured, np.all(np.isfinite(values), axis=-1))


def test_trilinear_reads_the_same_cells_whatever_the_grid_layout(independent_file):
    """The trilinear lookup's corner values (gonio.io.merl._cell_reader: one np.take on a flat view of a C-ordered
    grid or of a channels-first one, as read_merl returns a file's) are the grid's values[ih, id, ip], and the lookup
    gives the same bits for a table read from a file, its C-ordered copy and a Fortran-ordered one (indexed as a
    grid), with holes and on a one-channel grid."""
    from gonio.io.merl import _cell_reader, trilinear

    table = read_merl(independent_file)
    rng = np.random.default_rng(11)
    values = table.values.copy()
    values[rng.random(SHAPE) < 0.3] = np.nan
    ih, id_, ip = rng.integers(0, 90, 1000), rng.integers(0, 90, 1000), rng.integers(0, 180, 1000)
    flat = (ih * 90 + id_) * 180 + ip
    for grid in (table.values, np.ascontiguousarray(table.values), values, values[..., :1].copy()):
        assert np.array_equal(_cell_reader(grid)(flat), grid[ih, id_, ip], equal_nan=True)
        assert np.array_equal(_cell_reader(grid)(flat.reshape(20, 50)),  # any shape, e.g. (lights, pixels)
                              grid[ih.reshape(20, 50), id_.reshape(20, 50), ip.reshape(20, 50)], equal_nan=True)
    assert _cell_reader(np.asfortranarray(values)) is None
    wi, wo = rng.normal(size=(2, 5000, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi, wo = wi / np.linalg.norm(wi, axis=1)[:, None], wo / np.linalg.norm(wo, axis=1)[:, None]
    wo[:10] = wi[:10]
    for a, b in ((table.values, np.ascontiguousarray(table.values)), (values, np.asfortranarray(values))):
        assert trilinear(a, wi, wo).tobytes() == trilinear(b, wi, wo).tobytes()
        assert trilinear(a, wi.reshape(50, 100, 3), wo.reshape(50, 100, 3)).tobytes() == \
               trilinear(b, wi.reshape(50, 100, 3), wo.reshape(50, 100, 3)).tobytes()
