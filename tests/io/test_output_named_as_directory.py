"""An output spelled as a directory (``--json fits/``, the README's batch spelling) with one source is
refused in one line, as an existing directory is: it wrote a JSON file named ``fits``, which then made
the batch form ``--json fits/`` fail ("with several sources this must be a directory")."""

from __future__ import annotations

import os

import pytest

from gonio.cli.main import main
from gonio.errors import ConfigError
from gonio.io.outputs import check_output


@pytest.mark.parametrize("sep", ["/", os.sep])
def test_check_output_refuses_a_name_ending_in_a_separator(tmp_path, sep):
    with pytest.raises(ConfigError, match="names a directory"):
        check_output(str(tmp_path / "fits") + sep, option="--json")
    assert not (tmp_path / "fits").exists()


def test_fit_json_dir_with_one_source_writes_no_file_named_like_the_dir(tmp_path, session, capsys):
    out = tmp_path / "fits"
    assert main(["fit", str(session), "--model", "lambert", "--json", str(out) + "/", "--quiet"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--json" in err[0] and "names a directory" in err[0]
    assert not out.exists()
