"""What a lab user meets with inputs that hold nothing or less than they should: a header-only CSV, a
session stopped before its first pose, a samples.jsonl shorter than its manifest says, a file where a
session directory is expected. Each is one line naming the file, a non-zero exit (or a warning where the
data are still usable), and nothing written."""

from __future__ import annotations

import shutil
import warnings

import pytest

from gonio.cli.main import main




@pytest.fixture
def empty_csv(session, tmp_path):
    full = tmp_path / "full.csv"
    assert main(["export", str(session), "--format", "csv", "-o", str(full)]) == 0
    empty = tmp_path / "empty.csv"
    empty.write_text(full.read_text().splitlines(keepends=True)[0])  # the header only
    return empty


@pytest.fixture
def truncated(session, tmp_path):
    """A completed session whose samples.jsonl lost its last records (the manifest still counts them)."""
    d = tmp_path / "truncated"
    shutil.copytree(session, d)
    lines = (d / "samples.jsonl").read_bytes().splitlines(keepends=True)
    (d / "samples.jsonl").write_bytes(b"".join(lines[:1]))
    return d, len(lines) - 1


@pytest.mark.parametrize("argv", [
    ["fit", "{src}", "--model", "lambert"],
    ["report", "{src}", "-o", "{tmp}/r.html"],
    ["export", "{src}", "--format", "merl", "-o", "{tmp}/t.binary"],
    ["plot", "{src}", "--kind", "coverage", "-o", "{tmp}/c.png"],
])
def test_an_empty_csv_is_one_line_naming_it_and_nothing_is_written(empty_csv, tmp_path, capsys, argv):
    pytest.importorskip("matplotlib") if argv[0] == "plot" else None
    out = tmp_path / "out"
    out.mkdir()
    code = main([a.format(src=empty_csv, tmp=out) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and str(empty_csv) in err[0] and "warning" not in err[0], err
    assert not list(out.iterdir())


def test_a_truncated_session_says_what_is_missing(truncated, capsys):
    import gonio

    d, lost = truncated
    assert main(["status", str(d)]) == 0
    out = capsys.readouterr().out
    assert f"MISSING: {lost} pose(s)" in out
    with pytest.warns(UserWarning, match=f"{lost} pose\\(s\\) the manifest counted"):
        gonio.load(d)


def test_a_complete_session_loads_without_a_warning_and_status_on_a_file_names_it(session, empty_csv, capsys):
    import gonio

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gonio.load(session)
    assert "MISSING" not in (main(["status", str(session)]), capsys.readouterr().out)[1]
    for command in ("status", "repair"):
        assert main([command, str(empty_csv)]) != 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "is a file, not a session directory" in err[0], err


def test_a_data_file_given_as_a_fit_result_says_what_it_is(tmp_path):
    from gonio.cli.plot import load_model
    from gonio.errors import ConfigError
    from gonio.io.merl import MerlTable, write_merl

    import numpy as np

    table = tmp_path / "t.binary"
    write_merl(table, MerlTable(np.full((90, 90, 180, 3), np.nan)))
    with pytest.raises(ConfigError, match=r"t.binary: not a fit result \(gonio fit --json FIT.json\): it looks like a "
                                          r"MERL BRDF binary"):
        load_model(table)
