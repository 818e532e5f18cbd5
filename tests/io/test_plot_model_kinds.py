"""``gonio plot --model FIT.json`` with a kind that does not draw a model (polar, coverage) says so in one
line: it was silently ignored, so the plot could pass for a comparison with the model."""

from __future__ import annotations

import json

import pytest

from gonio.cli.main import main


@pytest.mark.parametrize("kind", ["polar", "coverage"])
def test_model_with_a_kind_that_cannot_draw_it_is_named(tmp_path, session, kind, capsys):
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps({"model": "lambert", "params": {"albedo": [0.3, 0.2, 0.1]}}))
    out = tmp_path / f"{kind}.png"
    assert main(["plot", str(session), "--kind", kind, "--model", str(fit), "-o", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--model" in err[0] and "not drawn" in err[0] and kind in err[0] and out.exists()
