"""`gonio measure --sim --material` renders measured materials (issue 27 item 5): a MERL table, a fit JSON, besides the
TOML of an analytic model; the manifest records the file and its SHA-256, resume reads the same file again, and a
malformed or changed material file is one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.fit.result import FitResult
from gonio.io.merl import MerlTable, write_merl
from gonio.io.table_brdf import TableBRDF
from gonio.session.store import load_session

SMALL = ["--sim", "--quiet", "--sim-resolution", "240x180", "--plan", "in_plane", "--theta-i-step", "30",
         "--theta-o-step", "30", "--theta-max", "60", "--seed", "4"]
#: the default material of `gonio measure --sim` (sim/materials/default.toml)
PARAMS = dict(kd=[0.3, 0.12, 0.06], ks=0.8, alpha=0.25, f0=0.04, distribution="ggx")


@pytest.fixture(scope="module")
def analytic(tmp_path_factory):
    """The default (analytic) material measured with the same seed and plan: the truth the table is compared to."""
    d = tmp_path_factory.mktemp("analytic") / "s"
    assert main(["measure", *SMALL, "--out", str(d)]) == 0
    return load_session(d)[1]


@pytest.fixture(scope="module")
def merl_file(tmp_path_factory):
    """The default material tabulated on the MERL grid, with the grazing cells (θd index ≥ 80) not measured."""
    table = MerlTable.from_brdf(make("microfacet", **PARAMS))
    values = table.values.copy()
    values[:, 80:] = np.nan
    path = tmp_path_factory.mktemp("merl") / "plastic.binary"
    write_merl(path, MerlTable(values))
    return path


def test_a_merl_table_is_measured_as_the_model_it_tabulates_and_resume_reads_the_same_file(
        tmp_path, capsys, analytic, merl_file):
    d = tmp_path / "s"
    # a dead camera stops the first run: the resume rebuilds the simulated material from the manifest
    code = main(["measure", *SMALL, "--material", str(merl_file), "--sim-frame-faults", "black=1", "--out", str(d)])
    out = capsys.readouterr().out
    assert code not in (0, None)
    assert out.count("not measured") == 1 and "nearest measured cell" in out  # the holes: filled, said once
    m = json.loads((d / "manifest.json").read_text())
    assert m["material"] == {"label": "plastic (MERL table)", "file": str(merl_file.resolve()), "kind": "merl",
                             "sha256": __import__("hashlib").sha256(merl_file.read_bytes()).hexdigest()}
    m["sim"]["frame_faults"] = ""  # the camera was repaired
    (d / "manifest.json").write_text(json.dumps(m))
    assert main(["resume", str(d), "--quiet"]) == 0
    manifest, samples = load_session(d)
    assert manifest["exit_status"] == "completed" and np.array_equal(samples.pose, analytic.pose)
    assert np.all(np.isfinite(samples.f))
    # the same seed renders the same noise: the two sessions differ by the table's interpolation only, far
    # below the noise; and the measured values scatter about the analytic model as the stated sigma says
    ok = (samples.flags == 0) & (analytic.flags == 0)
    assert ok.sum() > 0.5 * len(samples)
    diff = np.abs(samples.f - analytic.f)[ok]
    assert np.median(diff / analytic.sigma[ok]) < 0.2 and np.median(diff / analytic.f[ok]) < 2e-3
    truth = make("microfacet", **PARAMS).eval(samples.wi, samples.wo)
    z = np.abs(samples.f - truth)[ok] / samples.sigma[ok]
    assert np.mean(z < 2) > 0.85


def test_a_changed_or_missing_material_file_is_refused_at_resume_in_one_line(tmp_path, capsys, merl_file):
    d = tmp_path / "s"
    table = tmp_path / "t.binary"
    table.write_bytes(merl_file.read_bytes())
    assert main(["measure", *SMALL, "--material", str(table), "--sim-frame-faults", "black=1", "--out", str(d)]) != 0
    capsys.readouterr()
    before = (d / "samples.jsonl").read_bytes()
    raw = bytearray(table.read_bytes())
    raw[-8:] = np.float64(0.5).tobytes()  # one cell changed
    table.write_bytes(bytes(raw))
    assert main(["resume", str(d), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(table.resolve()) in err and "changed since the session started" in err
    table.unlink()
    assert main(["resume", str(d), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no such file" in err
    assert (d / "samples.jsonl").read_bytes() == before


def test_a_fit_json_is_measured_as_the_fitted_model(tmp_path, capsys):
    fit = FitResult(model_name="lambert", params={"albedo": [0.5, 0.25, 0.125]}, uncertainty={"albedo": [0.01] * 3},
                    loss="chi2", cost=1.0, rms_rel=0.01, n_used=10, n_params=3)
    path = tmp_path / "fit.json"
    fit.to_json(path)
    d = tmp_path / "s"
    assert main(["measure", *SMALL, "--material", str(path), "--out", str(d)]) == 0
    manifest, samples = load_session(d)
    assert manifest["material"]["kind"] == "fit" and manifest["material"]["label"] == "fit (fitted model)"
    good = samples.good()
    np.testing.assert_allclose(np.mean(good.f, axis=0) * np.pi, [0.5, 0.25, 0.125], rtol=0.03)


@pytest.mark.parametrize("name, content, named", [
    ("short.binary", (90).to_bytes(4, "little") * 2 + (180).to_bytes(4, "little") + b"\0" * 64, "truncated"),
    ("table.binary", b"version https://git-lfs.github.com/spec/v1\noid sha256:ab\n", "Git LFS pointer"),
    ("fit.json", b'{"model": "glitter", "params": {}}', "glitter"),
    ("fit.json", b'{"model": "lambert", "params": {"albedo": [2, 0, 0]}}', "albedo"),
    ("fit.json", b'[1, 2', "not valid JSON"),
    ("t.npz", b"PK\x03\x04garbage", "t.npz"),
    ("m.png", b"\x89PNG\r\n\x1a\n" + b"\0" * 32, "PNG"),
])
def test_a_malformed_material_file_is_one_line_and_nothing_is_written(tmp_path, capsys, name, content, named):
    path = tmp_path / name
    path.write_bytes(content)
    d = tmp_path / "s"
    assert main(["measure", *SMALL, "--material", str(path), "--out", str(d)]) not in (0, None)
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(path) in err and named in err and "Traceback" not in err
    assert not d.exists()


def test_a_directory_as_material_is_refused_in_one_line(tmp_path, capsys):
    assert main(["measure", *SMALL, "--material", str(tmp_path), "--out", str(tmp_path / "s")]) not in (0, None)
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "a directory" in err


def test_table_brdf_interpolates_as_the_table_lookup_and_never_renders_nan():
    rng = np.random.default_rng(1)
    model = make("microfacet", **PARAMS)
    table = MerlTable.from_brdf(model)
    wi = rng.normal(size=(4000, 3))
    wo = rng.normal(size=(4000, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    wi[:50] = wo[:50]  # the retro-reflection pole
    full = TableBRDF(table, "t")
    f = full.eval(wi, wo)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    assert full.n_filled == 0 and full.fill_note() == ""
    # the weights of MerlTable.lookup's trilinear interpolation, on the table without holes
    # (φd is ill-conditioned at the wi = wo pole: there the two computations of it may differ)
    np.testing.assert_allclose(f[50:], full.table.lookup(wi[50:], wo[50:]), rtol=1e-6, atol=1e-12)
    assert np.all(np.isfinite(f[:50]))
    assert np.all(f[~above] == 0)
    # a table with a block of cells not measured: filled with the nearest measured cell, never NaN
    values = table.values.copy()
    values[20:30, 10:20] = np.nan
    holes = TableBRDF(MerlTable(values), "h")
    g = holes.eval(wi, wo)
    assert np.all(np.isfinite(g)) and holes.n_filled == 10 * 10 * 180
    assert "18,000 of" in holes.fill_note()
    # near the specular peak the interpolated table is the model to a fraction of a percent
    good = above & (model.eval(wi, wo)[:, 0] > 0)
    assert np.median(np.abs(f[good] / model.eval(wi, wo)[good] - 1)) < 2e-3
    empty = MerlTable.empty()
    with pytest.raises(Exception, match="holds no value"):
        TableBRDF(empty, "e")
