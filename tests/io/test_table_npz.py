"""An NPZ that holds a table and no samples (``gonio export TABLE.binary --format npz``) reads like the
MERL table it came from: fit, plot and MERL export use the table's cells; a CSV export is refused as for
the table itself, not written empty."""

from __future__ import annotations

import numpy as np
import pytest

import gonio
from gonio.brdf import make
from gonio.cli.main import main
from gonio.io.merl import MerlTable, cell_directions, read_merl, write_merl

MODEL = make("microfacet", kd=[0.3, 0.2, 0.1], ks=0.8, alpha=0.25, f0=0.04)


@pytest.fixture(scope="module")
def table_npz(tmp_path_factory):
    d = tmp_path_factory.mktemp("tnpz")
    wi, wo, ok = cell_directions()
    values = np.full((90, 90, 180, 3), np.nan)
    values[ok] = MODEL.eval(wi[ok], wo[ok])
    write_merl(d / "m.binary", MerlTable(values))
    assert main(["export", str(d / "m.binary"), "--format", "npz", "-o", str(d / "m.npz")]) == 0
    return d


def test_table_npz_loads_as_a_table(table_npz):
    data = gonio.load(table_npz / "m.npz")
    assert data.table is not None and data.samples is None
    assert len(data.to_samples()) == int(data.table.measured.sum())


def test_table_npz_fits_like_its_merl_table(table_npz):
    r = gonio.fit(table_npz / "m.npz", "microfacet", max_theta_deg=80)
    assert r.params["alpha"] == pytest.approx(0.25, rel=1e-3)


def test_table_npz_exports_back_to_the_same_merl_table(table_npz, capsys):
    out = table_npz / "back.binary"
    capsys.readouterr()
    assert main(["export", str(table_npz / "m.npz"), "--format", "merl", "-o", str(out)]) == 0
    values = read_merl(table_npz / "m.binary").values
    np.testing.assert_array_equal(read_merl(out).values, values)
    # what was written is a table, and it says how many cells hold values (it said "0 samples"; QA, qa-user)
    n = int(np.count_nonzero(np.isfinite(values).all(axis=-1)))
    assert f"(merl, a table of {n} cells with values)" in capsys.readouterr().out


def test_table_npz_csv_export_is_refused_not_written_empty(table_npz, capsys):
    out = table_npz / "m.csv"
    assert main(["export", str(table_npz / "m.npz"), "--format", "csv", "-o", str(out)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "without samples" in err[0] and not out.exists()


def test_filled_cells_stay_filled_through_an_npz(tmp_path):
    """A MERL export made with --fill, converted to NPZ: its interpolated cells are still not
    measurements (the sidecar's promise), so a fit of the NPZ uses the measured cells only."""
    wi, wo, ok = cell_directions()
    values = np.full((90, 90, 180, 3), np.nan)
    values[ok] = MODEL.eval(wi[ok], wo[ok])
    from gonio.samples import SampleSet

    keep = np.zeros(ok.shape, bool)
    keep[:14:7, :20:5, ::9] = True  # a patch near the specular peak: ~80,000 holes within 5° to fill, not 10⁶
    keep &= ok
    s = SampleSet(wi[keep], wo[keep], values[keep], 0.01 * values[keep])
    from gonio.io.npz import build_metadata, write_npz

    write_npz(tmp_path / "s.npz", s, build_metadata({}))
    assert main(["export", str(tmp_path / "s.npz"), "--format", "merl", "--fill", "5", "-o",
                 str(tmp_path / "f.binary")]) == 0
    merl = gonio.load(tmp_path / "f.binary")
    n_measured = int(merl.table.measured.sum() - merl.filled.sum())
    assert merl.filled.sum() > 0 and len(merl.to_samples()) == n_measured
    assert main(["export", str(tmp_path / "f.binary"), "--format", "npz", "-o", str(tmp_path / "f.npz")]) == 0
    back = gonio.load(tmp_path / "f.npz")
    assert back.filled is not None and np.array_equal(back.filled, merl.filled)
    assert len(back.to_samples()) == n_measured
    # a session's own NPZ export with --fill: its table's filled cells are those with no sample
    assert main(["export", str(tmp_path / "s.npz"), "--format", "npz", "--fill", "5", "-o",
                 str(tmp_path / "s2.npz")]) == 0
    s2 = gonio.load(tmp_path / "s2.npz")
    assert s2.filled is not None and int(s2.filled.sum()) == int(merl.filled.sum())


def test_savez_deflated_is_savez_compressed_at_another_level(tmp_path):
    """gonio.io.npz.savez_deflated writes np.savez_compressed's archive (the same entries, each entry's same
    uncompressed bytes: sizes and CRC-32 equal) at the faster DEFLATE level, and np.load reads the same arrays."""
    import zipfile

    from gonio.io.npz import NPZ_LEVEL, savez_deflated

    rng = np.random.default_rng(3)
    table = rng.random((9, 9, 18, 3))
    table[rng.random(table.shape[:3]) < 0.7] = np.nan
    arrays = {"samples/wi": rng.normal(size=(500, 3)), "table/values": table, "table/count": np.arange(7, dtype=np.int32),
              "table/filled": rng.random((4, 5)) < 0.5, "metadata": np.array(['{"é": 1}'])}
    with open(tmp_path / "numpy.npz", "wb") as fh:
        np.savez_compressed(fh, **arrays)
    with open(tmp_path / "gonio.npz", "wb") as fh:
        savez_deflated(fh, arrays)
    with zipfile.ZipFile(tmp_path / "numpy.npz") as a, zipfile.ZipFile(tmp_path / "gonio.npz") as b:
        assert [(i.filename, i.file_size, i.CRC, i.compress_type) for i in a.infolist()] == \
               [(i.filename, i.file_size, i.CRC, i.compress_type) for i in b.infolist()]
    with np.load(tmp_path / "numpy.npz") as a, np.load(tmp_path / "gonio.npz") as b:
        assert a.files == b.files
        for k in a.files:
            assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f")
    assert NPZ_LEVEL == 1
