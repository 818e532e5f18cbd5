"""``gonio report --model FIT.json --fit MODELS``: the on-the-fly fits are not made when a saved fit is
given (as --help says); the command now says so in one line instead of ignoring --fit silently."""

from __future__ import annotations

from gonio.cli.main import main


def test_fit_beside_model_is_named_as_not_fitted(inputs, fit_json, tmp_path, capsys):
    session, _ = inputs
    out = tmp_path / "r.html"
    assert main(["report", str(session), "--model", str(fit_json), "--fit", "lambert", "-o", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--fit" in err[0] and "--model" in err[0] and out.exists()


def test_model_alone_says_nothing(inputs, fit_json, tmp_path, capsys):
    session, _ = inputs
    assert main(["report", str(session), "--model", str(fit_json), "-o", str(tmp_path / "r.html")]) == 0
    assert capsys.readouterr().err.strip() == ""
