"""Tabulation of scattered samples onto the MERL grid."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.brdf import make
from gonio.errors import DataError
from gonio.geometry import dirs_from_half_diff, from_spherical
from gonio.io.merl import cell_centres
from gonio.samples import SATURATED, SampleSet
from gonio.tabulate import check_isotropy, tabulate


def _hemisphere(rng, n):
    return from_spherical(np.arccos(rng.random(n)), 2 * np.pi * rng.random(n))


def _stratified_cell_samples(rng, cells, model, rel_sigma=0.01):
    """8 samples per cell at the centres of its 2×2×2 sub-cells (index space), random φh each."""
    offs = np.array([[a, b, c] for a in (0.25, 0.75) for b in (0.25, 0.75) for c in (0.25, 0.75)])
    u = (cells[:, None, :] + offs[None]).reshape(-1, 3)
    th = (u[:, 0] / 90) ** 2 * np.pi / 2
    td = u[:, 1] / 90 * np.pi / 2
    pd = u[:, 2] / 180 * np.pi + np.pi * rng.integers(0, 2, len(u))  # either reciprocal twin
    wi, wo = dirs_from_half_diff(th, 2 * np.pi * rng.random(len(u)), td, pd)
    f = model.eval(wi, wo)
    return SampleSet(wi, wo, f, rel_sigma * f)


@pytest.mark.parametrize("model, rtol", [
    (make("microfacet", kd=0.2, ks=1.0, alpha=0.2, f0=0.04), 0.01),
    (make("blinn-phong", kd=0.3, ks=0.5, exponent=50.0), 0.005),
])
def test_dense_analytic_model_matches_cell_centres(model, rtol):
    """Stated tolerance: 1 % (microfacet GGX α = 0.2) and 0.5 % (Blinn-Phong n = 50) relative at the
    cell centres, for stratified sampling (8 samples per cell) away from grazing (cos θ > 0.05)."""
    rng = np.random.default_rng(5)
    th_c, td_c, pd_c = cell_centres()
    cells = np.stack([rng.integers(0, 90, 4000), rng.integers(0, 90, 4000), rng.integers(0, 180, 4000)], axis=1)
    wi_c, wo_c = dirs_from_half_diff(th_c[cells[:, 0]], 0.0, td_c[cells[:, 1]], pd_c[cells[:, 2]])
    cells = cells[(wi_c[:, 2] > 0.05) & (wo_c[:, 2] > 0.05)][:600]
    samples = _stratified_cell_samples(rng, cells, model)
    tab = tabulate(samples, fill_deg=0)
    i, j, k = cells.T
    wi_c, wo_c = dirs_from_half_diff(th_c[i], 1.234, td_c[j], pd_c[k])
    expect = model.eval(wi_c, wo_c)
    got = tab.table.values[i, j, k]
    np.testing.assert_allclose(got, expect, rtol=rtol)
    assert (tab.table.count[i, j, k] == 8).all()
    assert tab.n_measured == len(np.unique(cells, axis=0)) and tab.n_filled == 0
    # the uncertainty of a mean of 8 samples with σ = 1 % is about 1 %/√8
    np.testing.assert_allclose(tab.table.sigma[i, j, k] / got, 0.01 / np.sqrt(8), rtol=0.05)


def test_scattered_lambert_is_reproduced_and_filled():
    rng = np.random.default_rng(6)
    n = 30_000
    wi, wo = _hemisphere(rng, n), _hemisphere(rng, n)
    model = make("lambert", albedo=[0.2, 0.5, 0.8])
    f = model.eval(wi, wo)
    tab = tabulate(SampleSet(wi, wo, f, np.full_like(f, 0.01)), fill_deg=2.0)
    v = tab.table.values
    ok = np.isfinite(v).all(axis=-1)
    np.testing.assert_allclose(v[ok], np.broadcast_to(np.array([0.2, 0.5, 0.8]) / np.pi, v[ok].shape), rtol=1e-12)
    assert tab.n_filled > 100_000 and tab.n_measured > 20_000
    filled = (tab.table.count == 0) & ok
    assert filled.sum() == tab.n_filled
    # lookups anywhere in the upper hemisphere (where measured or filled) give the albedo / π
    q_wi, q_wo = _hemisphere(rng, 1000), _hemisphere(rng, 1000)
    got = tab.table.lookup(q_wi, q_wo, "trilinear")
    good = np.isfinite(got).all(axis=1)
    assert good.mean() > 0.8
    np.testing.assert_allclose(got[good], np.broadcast_to([0.2 / np.pi, 0.5 / np.pi, 0.8 / np.pi], got[good].shape))


def test_weighted_mean_uncertainty_and_reciprocity():
    wi = np.array([[0.3, 0.1, 0.948683], [0.3, 0.1, 0.948683]])
    wo = np.array([[-0.2, 0.4, 0.894427], [-0.2, 0.4, 0.894427]])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    # second sample has wi and wo swapped: same cell by reciprocity
    s = SampleSet(np.array([wi[0], wo[1]]), np.array([wo[0], wi[1]]),
                  f=[[1.0, 1.0, 1.0], [2.0, 4.0, 2.0]], sigma=[[0.1, 0.1, 0.2], [0.2, 0.1, 0.2]])
    tab = tabulate(s, fill_deg=0)
    assert tab.n_measured == 1
    cell = np.argwhere(tab.table.count > 0)[0]
    assert tab.table.count[tuple(cell)] == 2
    w1, w2 = 1 / 0.1**2, 1 / 0.2**2
    np.testing.assert_allclose(tab.table.values[tuple(cell)], [(w1 + 2 * w2) / (w1 + w2), 2.5, 1.5])
    np.testing.assert_allclose(tab.table.sigma[tuple(cell)], [(w1 + w2) ** -0.5, 0.1 / np.sqrt(2), 0.2 / np.sqrt(2)])


def test_holes_filled_only_within_distance():
    rng = np.random.default_rng(7)
    # samples only in a small patch: θh cells 40..44, θd 20..24, all φd
    cells = np.stack(np.meshgrid(np.arange(40, 45), np.arange(20, 25), np.arange(0, 180, 1), indexing="ij"),
                     axis=-1).reshape(-1, 3)
    samples = _stratified_cell_samples(rng, cells, make("lambert", albedo=0.5))
    none = tabulate(samples, fill_deg=0)
    some = tabulate(samples, fill_deg=1.5)
    more = tabulate(samples, fill_deg=4.0)
    assert none.n_filled == 0 and 0 < some.n_filled < more.n_filled
    assert some.n_measured == none.n_measured == len(cells)
    # a filled cell next to the patch, a far one left not measured
    th_c, _, _ = cell_centres()
    assert np.isnan(some.table.values[10, 60, 5]).all()
    assert np.isfinite(some.table.values[45, 22, 7]).all() and some.table.count[45, 22, 7] == 0
    np.testing.assert_allclose(some.table.values[45, 22, 7], 0.5 / np.pi)
    # 1.5 deg in θh from cell 44 reaches index sqrt((θh44 + 1.5°)/(π/2))·90
    reach = int(np.sqrt((th_c[44] + np.radians(1.5)) / (np.pi / 2)) * 90)
    assert np.isnan(some.table.values[reach + 2, 22, 7]).all()


def test_anisotropic_data_refused_unless_forced():
    rng = np.random.default_rng(8)
    n = 200_000
    wi, wo = _hemisphere(rng, n), _hemisphere(rng, n)
    f = make("ward", kd=0.2, alpha_x=0.1, alpha_y=0.4).eval(wi, wo)
    s = SampleSet(wi, wo, f, 0.01 * f + 1e-4)
    assert check_isotropy(s).anisotropic
    with pytest.raises(DataError, match=r"mysession: the samples are anisotropic.*--format npz or csv"):
        tabulate(s, source="mysession", fill_deg=0)
    tab = tabulate(s, force_isotropic=True, fill_deg=0)
    assert tab.isotropy.anisotropic and tab.n_measured > 0
    iso = make("microfacet", kd=0.2, alpha=0.2).eval(wi, wo)
    assert not check_isotropy(SampleSet(wi, wo, iso, 0.01 * iso)).anisotropic


def test_flagged_and_invalid_samples_excluded():
    rng = np.random.default_rng(9)
    wi, wo = _hemisphere(rng, 100), _hemisphere(rng, 100)
    wo[:5, 2] *= -1  # below the horizon
    f = np.full((100, 3), 0.1)
    f[5] = np.nan
    flags = np.zeros(100, dtype=int)
    flags[6:10] = SATURATED
    tab = tabulate(SampleSet(wi, wo, f, np.full((100, 3), 0.01), flags=flags), fill_deg=0)
    assert (tab.n_used, tab.n_flagged, tab.n_invalid) == (90, 4, 6)
    assert tab.table.count.sum() == 90
    assert "90 tabulated, 4 flagged" in tab.summary()
    tab = tabulate(SampleSet(wi, wo, f, np.full((100, 3), 0.01), flags=flags), fill_deg=0, include_flagged=True)
    assert tab.n_used == 94
    with pytest.raises(DataError, match="no usable samples"):
        tabulate(SampleSet(wi[:5], wo[:5], f[:5], np.full((5, 3), 0.01)))
    with pytest.raises(DataError, match="fill distance"):
        tabulate(SampleSet(wi, wo, f, np.full((100, 3), 0.01)), fill_deg=-1)


def test_the_row_prefilter_of_the_fill_leaves_out_no_hole_with_a_measured_neighbour():
    """The fill asks its k-d tree only about holes in (θh, θd) rows that can be within the distance of a measured
    cell (gonio.tabulate._near_rows, a necessary condition). On a sparse set (a few incidence angles, where it
    leaves out most rows), no left-out hole has a measured cell (or its reciprocal twin) within the distance in the
    fill's embedding (wi, wo)/√2 — checked on 60,000 of them by the same k-d tree query; it fails with half the
    margin."""
    from scipy.spatial import cKDTree

    from gonio.io.merl import cell_directions
    from gonio.tabulate import _near_rows

    rng = np.random.default_rng(9)
    n = 600
    wi = from_spherical(np.radians(rng.choice([10.0, 35.0, 60.0], n)), np.zeros(n))
    wo = _hemisphere(rng, n)
    f = make("microfacet", kd=0.2, ks=0.5, alpha=0.3).eval(wi, wo)
    measured = tabulate(SampleSet(wi, wo, f, 0.01 * f), fill_deg=0).table.count > 0
    bound = 2.0 * np.sin(np.radians(4.0) / 2.0)
    near = _near_rows(measured, bound)
    c_wi, c_wo, above = cell_directions(0.0)
    emb = np.concatenate([c_wi, c_wo], axis=-1).reshape(-1, 6) / np.sqrt(2.0)
    twin = np.concatenate([c_wo, c_wi], axis=-1).reshape(-1, 6) / np.sqrt(2.0)
    m = np.flatnonzero(measured)
    tree = cKDTree(np.concatenate([emb[m], twin[m]]))
    out = np.flatnonzero(above & ~measured & ~near[..., None])
    kept = np.flatnonzero(above & ~measured & near[..., None])
    assert out.size > 100_000 and kept.size > 10_000  # most rows are left out; some are kept
    d, _ = tree.query(emb[rng.choice(out, 60_000, replace=False)], distance_upper_bound=bound)
    assert not np.isfinite(d).any()
    d, _ = tree.query(emb[rng.choice(kept, 10_000, replace=False)], distance_upper_bound=bound)
    assert np.isfinite(d).mean() > 0.1  # the kept rows do hold holes the fill fills
