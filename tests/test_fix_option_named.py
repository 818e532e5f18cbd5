"""``gonio fit --fix alpha`` (no value) names --fix, the option the user typed, not --param (an option of
``gonio models``); ``--fix =3`` names the missing name."""

from __future__ import annotations

import pytest

from gonio.cli.main import main


@pytest.mark.parametrize("text", ["alpha", "=3"])
def test_fix_without_name_or_value_names_fix(tmp_path, text, capsys):
    rc = main(["fit", str(tmp_path / "nothing.binary"), "--model", "microfacet", "--fix", text])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--fix" in err[0] and "--param" not in err[0] and "NAME=VALUE" in err[0]
