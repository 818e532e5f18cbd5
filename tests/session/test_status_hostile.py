"""``gonio status`` of a hand-edited manifest whose lab times are not numbers of seconds: a string was a
ValueError traceback (``Unknown format code 'f' for object of type 'str'``), NaN printed ``nan s`` and two runs of
1e308 s ``inf s``; each is left out (the last run's lab time, or unknown) (found by QA, qa-hostile)."""

from __future__ import annotations

import json
import shutil

import pytest

from gonio.cli.main import main

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


def test_a_record_of_a_pose_the_plan_does_not_have_is_not_counted_nor_loaded(measured, tmp_path, capsys):
    """A record of pose 500 in a small plan (another session's line pasted in): its samples went into fit and
    export, and status said more poses were done than the plan has (found by QA, qa-hostile)."""
    import warnings

    import numpy as np

    from gonio.samples import SampleSet
    from gonio.session.records import encode_record
    from gonio.session.store import load_session, scan_samples

    d = tmp_path / "s"
    shutil.copytree(measured, d)
    _, before = load_session(d)
    scan = scan_samples(d / "samples.jsonl")
    s, meta = scan.records[max(scan.records)]
    s = SampleSet(**{**s.to_dict(), "pose": np.full(len(s), 500, dtype=np.int64)})  # a good record of pose 500
    with open(d / "samples.jsonl", "ab") as f:
        f.write(encode_record(500, s, meta))
    capsys.readouterr()
    assert main(["status", str(d)]) == 0
    out = capsys.readouterr().out
    n_plan = int(next(line for line in out.splitlines() if line.startswith("plan poses:")).split()[-1])
    assert f"poses done:   {n_plan} ({len(before)} samples)" in out
    assert "NOT IN PLAN: 1 record(s)" in out and "pose 500" in out
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, after = load_session(d)
    assert len(after) == len(before) and 500 not in set(after.pose.tolist())
    assert any("pose 500" in str(w.message) and "left out" in str(w.message) for w in caught)


@pytest.mark.parametrize("value", [1.5, "abc", {"pose": 1}, None])
def test_a_failed_list_that_is_not_a_list_reads_as_none(measured, tmp_path, capsys, value):
    """``last_run.failed`` edited to a number was a TypeError traceback (found by `benchmarks robustness`)."""
    d = tmp_path / "s"
    shutil.copytree(measured, d)
    m = json.loads((d / "manifest.json").read_text())
    m["last_run"]["failed"] = value
    (d / "manifest.json").write_text(json.dumps(m))
    capsys.readouterr()
    assert main(["status", str(d)]) == 0
    assert "Traceback" not in capsys.readouterr().err
