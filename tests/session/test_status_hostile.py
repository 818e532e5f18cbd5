"""``gonio status`` of a hand-edited manifest whose lab times are not numbers of seconds: a string was a
ValueError traceback (``Unknown format code 'f' for object of type 'str'``), NaN printed ``nan s`` and two runs of
1e308 s ``inf s``; each is left out (the last run's lab time, or unknown) (found by QA, qa-hostile)."""

from __future__ import annotations

import json
import shutil

import pytest

from gonio.cli.main import main

SMALL = ["--quiet", "--plan", "in_plane", "--theta-i-step", "30", "--theta-o-step", "30", "--theta-max", "60",
         "--sim-resolution", "160x120"]


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    d = tmp_path_factory.mktemp("measured") / "s"
    assert main(["measure", "--sim", *SMALL, "--out", str(d)]) == 0
    return d


@pytest.mark.parametrize("edit", [
    lambda m: (m.pop("runs"), m["last_run"].__setitem__("lab_time_s", "abc")),
    lambda m: m["runs"][0].__setitem__("lab_time_s", float("nan")),
    lambda m: (m["runs"][0].__setitem__("lab_time_s", 1e308), m["runs"].append(dict(m["runs"][0]))),
])
def test_a_lab_time_that_is_not_seconds_reads_as_unknown(measured, tmp_path, capsys, edit):
    d = tmp_path / "s"
    shutil.copytree(measured, d)
    m = json.loads((d / "manifest.json").read_text())
    edit(m)
    (d / "manifest.json").write_text(json.dumps(m))  # NaN as the JSON literal, as a hand edit may leave it
    capsys.readouterr()
    assert main(["status", str(d)]) == 0
    out = capsys.readouterr()
    assert "Traceback" not in out.err and "nan" not in out.out and "inf" not in out.out
    lab = next(line for line in out.out.splitlines() if line.startswith("lab time:"))
    assert lab == "lab time:     unknown" or lab.endswith(" s"), lab  # unknown, or the last run's (finite) time


@pytest.mark.parametrize("value, text", [(0.0, "0:00"), (59.6, "1:00"), (3725.0, "1:02:05"), (-3.0, "0:00"),
                                         (float("inf"), "unknown"), (float("nan"), "unknown"),
                                         ("abc", "unknown"), (None, "unknown")])
def test_a_lab_time_is_formatted_or_said_unknown_never_an_exception(value, text):
    from gonio.session.runner import format_lab_time

    assert format_lab_time(value) == text
