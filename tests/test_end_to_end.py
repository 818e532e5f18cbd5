"""A user's whole workflow through the `gonio` command, on one simulated session:
measure -> status -> export (csv, npz, merl) -> plot -> fit.

Each step is checked against the session store (and, for the MERL table, against the known simulated
material). The measurement and the refused commands run as separate processes, as a user runs them (the
exit codes, stdout and stderr as a shell sees them); the other steps run ``gonio``'s ``main`` in this process
(the same code after the interpreter's start-up, which costs more CPU than most of these steps: ~1-2 s each
for the imports of numpy, scipy, numba and matplotlib).
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from gonio.brdf import make
from gonio.io.merl import FILE_SIZE, read_merl
from gonio.session.store import load_session

PLAN = ["--plan", "in_plane", "--theta-i-step", "20", "--theta-o-step", "15", "--theta-max", "60"]


def gonio(*args: str, ok: bool = True) -> subprocess.CompletedProcess:
    """``gonio ARGS`` in a new process."""
    out = subprocess.run([sys.executable, "-m", "gonio.cli.main", *args], capture_output=True, text=True, timeout=300)
    if ok:
        assert out.returncode == 0, f"gonio {' '.join(args)} failed:\n{out.stderr}"
    return out


@pytest.fixture
def run(capsys):
    """``run(*ARGS)``: ``gonio ARGS`` in this process (:func:`gonio.cli.main.main`), which must exit 0; its stdout."""
    from gonio.cli.main import main

    def run(*args: str) -> str:
        capsys.readouterr()
        code = main(list(args))
        out, err = capsys.readouterr()
        assert code == 0, f"gonio {' '.join(args)} failed ({code}):\n{err}"
        return out

    return run


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    d = tmp_path_factory.mktemp("e2e") / "session"
    out = gonio("measure", "--sim", "--quiet", "--sim-resolution", "240x180", *PLAN, "--out", str(d))
    assert "lab time" in out.stdout and "wall time" in out.stdout
    return d


def test_status_reports_a_completed_session(session, run):
    manifest, samples = load_session(session)
    out = run("status", str(session))
    assert "completed" in out and f"{len(manifest['plan']['poses'])}" in out
    assert len(samples) > 0


def test_csv_export_has_the_documented_columns_and_every_sample(session, tmp_path, run):
    path = tmp_path / "s.csv"
    run("export", str(session), "--format", "csv", "-o", str(path))
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    head = rows[0]
    assert head[:10] == ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b",
                         "sigma_r", "sigma_g", "sigma_b"]
    _, samples = load_session(session)
    assert len(rows) - 1 == len(samples)
    f = np.array([[float(x) for x in r[4:7]] for r in rows[1:]])
    np.testing.assert_array_equal(np.sort(f.ravel()), np.sort(samples.f.ravel()))


def test_npz_export_is_self_describing_without_pickle(session, tmp_path, run):
    path = tmp_path / "s.npz"
    run("export", str(session), "--format", "npz", "-o", str(path))
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["metadata"][()] if z["metadata"].ndim == 0 else z["metadata"][0]))
        keys = set(z.files)
    assert any(k.startswith("samples") for k in keys) and any(k.startswith("table") for k in keys)
    text = json.dumps(meta).lower()
    assert "1/sr" in text and "cos" in text and "microfacet" in text


def test_merl_export_matches_the_simulated_material_where_measured(session, tmp_path, run):
    path = tmp_path / "s.binary"
    run("export", str(session), "--format", "merl", "-o", str(path))
    assert path.stat().st_size == FILE_SIZE
    table = read_merl(path)
    manifest, samples = load_session(session)
    truth = make(manifest["material"]["model"], **manifest["material"]["params"])
    good = samples.good()
    got = table.lookup(good.wi, good.wo, method="nearest")
    want = truth.eval(good.wi, good.wo)
    rel = np.abs(got - want) / want
    # Nearest cell around each sample. Measured here: median 0.2 %, p95 1.1 %; the same session
    # against alpha = 0.30 instead of 0.25 gives a median of 2.3 %, which these bounds reject.
    assert np.median(rel) < 0.01 and np.percentile(rel, 95) < 0.05, (np.median(rel), np.percentile(rel, 95))


@pytest.mark.parametrize("kind", ["polar", "inplane", "coverage"])
def test_plots_render(session, tmp_path, kind, run):
    png = tmp_path / f"{kind}.png"
    run("plot", str(session), "--kind", kind, "-o", str(png))
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000


def test_fit_writes_json_and_residual_plot_uses_it(session, tmp_path, run):
    fit_json = tmp_path / "fit.json"
    run("fit", str(session), "--model", "microfacet", "--json", str(fit_json))
    result = json.loads(fit_json.read_text())
    assert result["model"] == "microfacet" and {"params", "uncertainty", "loss", "error"} <= set(result)
    assert 0.0 < result["params"]["alpha"] < 1.0
    png = tmp_path / "residual.png"
    run("plot", str(session), "--kind", "residual", "--model", str(fit_json), "-o", str(png))
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_bad_inputs_are_one_line_errors(session, tmp_path):
    out = gonio("export", str(tmp_path / "nothing"), "--format", "csv", "-o", str(tmp_path / "x.csv"), ok=False)
    assert out.returncode != 0 and out.stderr.strip().count("\n") == 0 and "nothing" in out.stderr
    assert "Traceback" not in out.stderr
    out = gonio("measure", "--sim", "--quiet", "--out", str(session), ok=False)
    assert out.returncode != 0 and "Traceback" not in out.stderr and str(session.name) in out.stderr
