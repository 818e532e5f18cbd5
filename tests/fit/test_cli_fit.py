"""``gonio fit`` on a MERL file written from an analytic model, and its errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.brdf import make
from gonio.cli.main import main
from gonio.io.merl import MerlTable, cell_directions, write_merl


@pytest.fixture(scope="module")
def merl_ggx(tmp_path_factory):
    wi, wo, above = cell_directions()
    model = make("microfacet", kd=[0.2, 0.3, 0.1], ks=[0.5, 0.4, 0.6], alpha=0.12)
    values = np.full(above.shape + (3,), np.nan)
    values[above] = model.eval(wi[above], wo[above])
    return write_merl(tmp_path_factory.mktemp("merl") / "ggx.binary", MerlTable(values))


def test_fit_merl_recovers_parameters_and_writes_json(merl_ggx, tmp_path, capsys):
    out = tmp_path / "fit.json"
    assert main(["fit", str(merl_ggx), "--model", "microfacet", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert set(report) >= {"model", "params", "uncertainty", "loss", "error", "candidates"}
    assert report["model"] == "microfacet" and report["loss"] == "robust"
    assert report["params"]["alpha"] == pytest.approx(0.12, rel=0.02)
    np.testing.assert_allclose(report["params"]["kd"], [0.2, 0.3, 0.1], rtol=0.01)
    assert "alpha" in capsys.readouterr().out


def test_fit_errors_are_one_line(tmp_path, capsys):
    assert main(["fit", str(tmp_path / "missing.binary")]) == 4
    bad = tmp_path / "bad.binary"
    bad.write_bytes(b"\x00" * 16)  # wrong header dims
    assert main(["fit", str(bad)]) == 4
    err = capsys.readouterr().err
    assert "bad.binary" in err and "Traceback" not in err
    assert main(["fit", str(bad), "--loss", "huber"]) == 4  # the file is read first
    assert main(["fit", str(bad), "--max-theta", "200"]) == 2  # options are checked before the file is read
    assert "--max-theta: max_theta = 200.0: must be in (0, 90] degrees" in capsys.readouterr().err
    assert main(["fit", str(bad), "--equivalence", "0.05"]) == 2  # a --select option without --select
    assert "--equivalence: equivalence = 0.05: applies to --select only" in capsys.readouterr().err
    assert main(["fit", str(bad), "--metal"]) == 2
    assert "--metal: metal = True: applies to --select only" in capsys.readouterr().err
