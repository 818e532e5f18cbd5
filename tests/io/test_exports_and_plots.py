"""CSV/NPZ round trips, `gonio export|tabulate|plot` on NPZ exports and MERL files, PNG sanity."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.errors import ConfigError, DataError
from gonio.geometry import from_spherical
from gonio.io.csv import COLUMNS, read_csv, write_csv
from gonio.io.merl import FILE_SIZE, read_merl
from gonio.io.npz import build_metadata, read_npz, write_npz
from gonio.samples import LOW_SIGNAL, SampleSet

MODEL = make("microfacet", kd=[0.3, 0.2, 0.1], ks=0.8, alpha=0.2, f0=0.04)
MANIFEST = {"material": {"label": "red plastic", "model": "microfacet"}, "rig": {"name": "sim", "arm_m": 0.3},
            "software": {"version": "0.1.0"}, "camera": {"detector_solid_angle_sr": 2.5e-5},
            "cosine_convention": "BRDF, not BRDF·cos"}


def session_samples(seed=0) -> SampleSet:
    """An isotropic-plan-like set: θi every 15°, wo on a 5° × 10° grid, 2 % noise."""
    rng = np.random.default_rng(seed)
    ti, to, po = np.meshgrid(np.radians(np.arange(0, 76, 15.0)), np.radians(np.arange(0, 86, 5.0)),
                             np.radians(np.arange(0, 360, 10.0)), indexing="ij")
    wi = from_spherical(ti.ravel(), 0.0 * ti.ravel())
    wo = from_spherical(to.ravel(), po.ravel())
    f = MODEL.eval(wi, wo)
    sigma = 0.02 * f + 1e-3
    flags = np.where(rng.random(len(f)) < 0.02, LOW_SIGNAL, 0)
    return SampleSet(wi, wo, f + rng.normal(size=f.shape) * sigma, sigma, flags=flags,
                     pose=np.arange(len(f)), n_pixels=rng.integers(50, 100, len(f)))


@pytest.fixture(scope="module")
def npz_session(tmp_path_factory):
    path = tmp_path_factory.mktemp("exp") / "session.npz"
    write_npz(path, session_samples(), build_metadata(MANIFEST))
    return path


def test_csv_round_trip_and_header(tmp_path):
    s = session_samples()
    path = write_csv(tmp_path / "s.csv", s)
    lines = path.read_text().splitlines()
    assert lines[0].split(",")[:10] == ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b",
                                        "sigma_r", "sigma_g", "sigma_b"]
    assert lines[0].split(",") == list(COLUMNS) and len(lines) == len(s) + 1
    back = read_csv(path)
    np.testing.assert_array_equal(back.f, s.f)
    np.testing.assert_array_equal(back.sigma, s.sigma)
    np.testing.assert_array_equal(back.flags, s.flags)
    np.testing.assert_array_equal(back.pose, s.pose)
    np.testing.assert_allclose(back.wi, s.wi, atol=1e-14)
    np.testing.assert_allclose(back.wo, s.wo, atol=1e-14)
    (tmp_path / "bad.csv").write_text("theta_i_deg,r\n1,2\n")
    with pytest.raises(DataError, match="bad.csv: CSV header lacks column 'phi_i_deg'"):
        read_csv(tmp_path / "bad.csv")


@pytest.mark.parametrize("column, value", [("flags", "1.5"), ("flags", "1e30"), ("flags", "-1"),
                                           ("n_pixels", "-4"), ("pose", "-2"), ("pose", "nan"), ("pose", "2.5")])
def test_an_integer_column_that_is_not_an_integer_in_range_is_one_line_naming_the_line(tmp_path, column, value):
    """flags 1.5 was read as 1, 1e30 as INT64_MIN, negative pixel counts and poses as given (found by QA,
    qa-hostile)."""
    s = session_samples()
    lines = write_csv(tmp_path / "s.csv", s).read_text().splitlines()
    row = lines[3].split(",")
    row[COLUMNS.index(column)] = value
    lines[3] = ",".join(row)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=rf"bad.csv: line 4: {column} = .*: must be an integer in") as refused:
        read_csv(tmp_path / "bad.csv")
    assert "np.float64" not in str(refused.value)  # the value as the file has it, not numpy's repr


def test_npz_round_trip_without_pickle(tmp_path):
    s = session_samples()
    meta = build_metadata(MANIFEST, note="x")
    path = write_npz(tmp_path / "s.npz", s, meta)
    with np.load(path, allow_pickle=False) as z:  # plain arrays only
        m = json.loads(str(z["metadata"][0]))
        assert set(z.files) >= {f"samples/{c}" for c in SampleSet.columns()}
    assert m["cosine_convention"] == "BRDF, not BRDF·cos" and m["units"]["f"] == "1/sr"
    assert m["material_label"] == "red plastic" and m["detector_solid_angle_sr"] == 2.5e-5
    assert m["rig"]["name"] == "sim" and m["software_version"] == "0.1.0" and m["exported_by"].startswith("gonio")
    back = read_npz(path)
    for c in SampleSet.columns():
        np.testing.assert_array_equal(getattr(back.samples, c), getattr(s, c))
    assert back.table is None and back.metadata["note"] == "x"
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(DataError, match="junk.npz: cannot read NPZ"):
        read_npz(tmp_path / "junk.npz")


@pytest.fixture(scope="module")
def merl_filled(npz_session, tmp_path_factory):
    """``gonio export SESSION.npz --format merl --fill-deg 1``: the table (read only by the tests) and what the
    command printed."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("merl") / "t.binary"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["export", str(npz_session), "--format", "merl", "-o", str(out), "--fill-deg", "1"])
    return code, out, buf.getvalue()


def test_cli_export_all_formats(npz_session, merl_filled, tmp_path, capsys):
    code, out, printed = merl_filled
    assert code == 0
    assert out.stat().st_size == FILE_SIZE
    assert "cells:" in printed
    table = read_merl(out)
    # the exported table reproduces the model at measured cells to within noise and cell size
    s = session_samples().good()
    got = table.lookup(s.wi, s.wo)
    ok = np.isfinite(got).all(axis=1) & (s.wi[:, 2] > 0.2) & (s.wo[:, 2] > 0.2)
    assert ok.mean() > 0.5
    rel = np.abs(got[ok] / MODEL.eval(s.wi[ok], s.wo[ok]) - 1)
    assert np.median(rel) < 0.03
    assert main(["export", str(npz_session), "--format", "csv", "-o", str(tmp_path / "s.csv")]) == 0
    assert len(read_csv(tmp_path / "s.csv")) == len(session_samples())
    assert main(["export", str(npz_session), "--format", "npz", "-o", str(tmp_path / "e.npz"), "--fill-deg", "0"]) == 0
    content = read_npz(tmp_path / "e.npz")
    assert content.table is not None and content.table.count.sum() == len(session_samples().good())
    assert content.metadata["material_label"] == "red plastic"
    assert content.metadata["tabulation"]["n_filled"] == 0
    # a MERL file as input: MERL and NPZ yes, CSV no
    assert main(["export", str(out), "--format", "npz", "-o", str(tmp_path / "m.npz")]) == 0
    np.testing.assert_array_equal(read_npz(tmp_path / "m.npz").table.measured, table.measured)
    assert main(["export", str(out), "--format", "csv", "-o", str(tmp_path / "m.csv")]) == 2
    assert "MERL table without samples" in capsys.readouterr().err


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["export", str(tmp_path / "nothing"), "--format", "csv", "-o", str(tmp_path / "x.csv")]) == 4
    err = capsys.readouterr().err
    assert "no such session directory or data file" in err and err.count("\n") == 1
    (tmp_path / "bad.binary").write_bytes(b"\x00" * 100)
    assert main(["plot", str(tmp_path / "bad.binary"), "--kind", "coverage", "-o", str(tmp_path / "c.png")]) == 4
    assert "bad.binary: not a MERL BRDF binary" in capsys.readouterr().err


def test_cli_tabulate_refuses_anisotropic(tmp_path, capsys):
    rng = np.random.default_rng(3)
    n = 100_000
    wi = from_spherical(np.arccos(rng.random(n)), 2 * np.pi * rng.random(n))
    wo = from_spherical(np.arccos(rng.random(n)), 2 * np.pi * rng.random(n))
    f = make("ward", kd=0.2, alpha_x=0.1, alpha_y=0.4).eval(wi, wo)
    write_npz(tmp_path / "a.npz", SampleSet(wi, wo, f, 0.01 * f + 1e-4), build_metadata({}))
    assert main(["tabulate", str(tmp_path / "a.npz"), "--fill-deg", "0"]) == 4
    assert "anisotropic" in capsys.readouterr().err
    # the NPZ export still works and says why it has no table
    assert main(["export", str(tmp_path / "a.npz"), "--format", "npz", "-o", str(tmp_path / "o.npz")]) == 0
    content = read_npz(tmp_path / "o.npz")
    assert content.table is None and "anisotropic" in content.metadata["table_omitted"]
    assert main(["tabulate", str(tmp_path / "a.npz"), "--fill-deg", "0", "--force-isotropic",
                 "-o", str(tmp_path / "f.binary")]) == 0
    assert read_merl(tmp_path / "f.binary").measured.sum() > 10_000


def png_pixels(path) -> np.ndarray:
    """Decode a PNG with Pillow (a dependency of matplotlib), independent of our plotting code."""
    from PIL import Image

    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB")).astype(np.int64)


@pytest.mark.parametrize("kind", ["polar", "inplane", "coverage", "residual"])
def test_plots_render_non_trivial_png(npz_session, tmp_path, kind):
    pytest.importorskip("matplotlib", reason="matplotlib is the optional 'plots' extra")
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({"model": "microfacet", "params": MODEL.params, "loss": "x"}))
    png = tmp_path / f"{kind}.png"
    assert main(["plot", str(npz_session), "--kind", kind, "--theta-i", "45", "--model", str(fit),
                 "-o", str(png)]) == 0
    img = png_pixels(png)
    assert img.shape[0] >= 300 and img.shape[1] >= 500
    rgb = img[..., :3]
    assert (rgb.std(axis=(0, 1)) > 10).any()  # not blank
    colourful = (rgb.max(axis=-1) - rgb.min(axis=-1)) > 60
    assert colourful.mean() > 0.002  # data drawn in colour, not just axes


def test_plot_merl_input_and_bad_model(npz_session, merl_filled, tmp_path, capsys):
    pytest.importorskip("matplotlib", reason="matplotlib is the optional 'plots' extra")
    code, out, _ = merl_filled
    assert code == 0
    for kind in ("polar", "inplane", "coverage"):
        png = tmp_path / f"m_{kind}.png"
        assert main(["plot", str(out), "--kind", kind, "--theta-i", "30", "-o", str(png)]) == 0
        assert png_pixels(png)[..., :3].std() > 10
    assert main(["plot", str(out), "--kind", "residual", "-o", str(tmp_path / "r.png")]) == 2
    capsys.readouterr()
    assert main(["plot", str(out), "--kind", "polar", "--tol", "-1", "-o", str(tmp_path / "t.png")]) == 2
    assert capsys.readouterr().err.strip() == "gonio plot: error: --tol: tol = -1.0: must be in (0, 45] degrees"
    (tmp_path / "fit.json").write_text(json.dumps({"model": "nosuch", "params": {}}))
    assert main(["plot", str(npz_session), "--kind", "inplane", "--model", str(tmp_path / "fit.json"),
                 "-o", str(tmp_path / "x.png")]) == 2
    assert "nosuch" in capsys.readouterr().err
    assert main(["plot", str(npz_session), "--kind", "polar", "--theta-i", "7", "-o", str(tmp_path / "x.png")]) == 4
    assert "no samples within 2.5 deg of theta_i = 7 deg" in capsys.readouterr().err


def test_plot_without_matplotlib_says_how_to_install(npz_session, tmp_path, monkeypatch, capsys):
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib -> ImportError
    code = main(["plot", str(npz_session), "--kind", "coverage", "-o", str(tmp_path / "c.png")])
    err = capsys.readouterr().err
    assert code != 0 and "pip install 'gonio[plots]'" in err and err.count("\n") == 1
    assert not (tmp_path / "c.png").exists()
    with pytest.raises(ConfigError):
        from gonio import plots

        plots.figure()


def test_cli_on_a_session_written_through_the_store(tmp_path, capsys):
    from gonio.session.store import SessionStore

    s = session_samples(seed=4)
    d = tmp_path / "session"
    store = SessionStore.create(d, {"material": {"label": "store plastic", "model": "microfacet"},
                                    "rig": {"name": "sim"}})
    for pose in range(0, len(s), 200):  # one record per block of samples
        store.append(pose // 200, s.subset(slice(pose, pose + 200)))
    store.finish("completed")
    store.close()
    assert main(["export", str(d), "--format", "npz", "-o", str(tmp_path / "s.npz"), "--fill-deg", "0"]) == 0
    content = read_npz(tmp_path / "s.npz")
    assert len(content.samples) == len(s) and content.table is not None
    np.testing.assert_array_equal(content.samples.f, s.f)
    assert content.metadata["material_label"] == "store plastic"
    assert content.metadata["session_cosine_convention"] and content.metadata["software_version"]
    assert main(["export", str(d), "--format", "csv", "-o", str(tmp_path / "s.csv")]) == 0
    assert len(read_csv(tmp_path / "s.csv")) == len(s)
    assert main(["tabulate", str(d), "--fill-deg", "0"]) == 0
    assert f"{len(s.good())} tabulated" in capsys.readouterr().out
    pytest.importorskip("matplotlib", reason="matplotlib is the optional 'plots' extra")
    assert main(["plot", str(d), "--kind", "inplane", "--theta-i", "30", "-o", str(tmp_path / "i.png")]) == 0
    assert png_pixels(tmp_path / "i.png").std() > 10
