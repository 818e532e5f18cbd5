"""A MERL output must be named as one (``.binary``, or ``.merl``, the names gonio reads a MERL table
under), as CSV and NPZ outputs must: ``gonio export S --format merl -o x.npz`` wrote a MERL binary that
gonio itself then refused to read ("not a gonio NPZ export: it looks like a MERL BRDF binary")."""

from __future__ import annotations

import pytest

from gonio.cli.main import main


@pytest.mark.parametrize("command", [["export", "--format", "merl"], ["tabulate"]])
@pytest.mark.parametrize("name", ["x.npz", "x.csv", "x.out"])
def test_merl_output_with_another_suffix_is_refused(tmp_path, session, command, name, capsys):
    out = tmp_path / name
    argv = [command[0], str(session), *command[1:], "-o", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "must end in .binary" in err[0]
    assert not out.exists() and not (tmp_path / (name + ".json")).exists()


def test_merl_suffix_is_accepted(tmp_path, session):
    assert main(["export", str(session), "--format", "merl", "-o", str(tmp_path / "x.merl")]) == 0
    assert (tmp_path / "x.merl").exists() and (tmp_path / "x.merl.json").exists()
