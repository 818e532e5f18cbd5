"""`gonio bench -o DIR`: completes and writes the report's tables and plots (no timing asserted: speed
targets live in the report itself). The whole report runs at its smoke size (`--smoke`: every trade's own
code at its smallest size, seconds instead of minutes); each trade's quick and full sizes are its own
benchmark's business."""

from __future__ import annotations

import re

import pytest

from benchmarks.common import Table
from benchmarks.report import TRADES as REPORT_TRADES
from benchmarks.report import Trade, write_report
from gonio.cli.main import main

#: The trades with a plot and a marked default: all but the real materials, which need $GONIO_REALDATA
#: (unset here: tests never depend on the real materials' folder) and then say so in a note.
TRADES = [tr.name for tr in REPORT_TRADES if tr.name != "realdata"]


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    # a smoke run that looks for the real materials' folder fails: tests/conftest.py's _never_reads_realdata
    code = main(["bench", "--smoke", "-o", str(out)])
    return code, out


def _sections(text: str) -> dict[str, str]:
    """Each trade's part of the report, by trade name (a section ends with the line of its seconds)."""
    parts = {}
    for tr in REPORT_TRADES:
        start = text.index(f"## {tr.title}\n")
        end = text.index(f"\n_{tr.name}: ", start)
        parts[tr.name] = text[start:text.index("\n", end + 1)]
    return parts


def test_report_completes_with_every_table(report):
    code, out = report
    assert code == 0
    text = (out / "REPORT.md").read_text(encoding="utf-8")
    assert "smoke run" in text and "`gonio bench --smoke`" in text and "**Smoke run:**" in text
    assert "| cores |" in text and "| numpy |" in text
    for heading in ("lab time vs BRDF error", "lab time vs noise", "evaluations/s vs error",
                    "MERL lookup", "fit time vs parameter error", "declared vs calibrated geometry",
                    "light and dark strategies"):
        assert heading in text
    sections = _sections(text)
    assert "This trade failed" not in text
    # every trade says how long it took, in its section and in the run's summary line
    for name, part in sections.items():
        assert re.search(rf"\n_{name}: \d+\.\d s_$", part), name
        assert re.search(rf"\b{name} \d+ s\b", text.split("\n| machine", 1)[0]), name
    # every trade produced at least one table with a marked default and its reason
    for name in TRADES:
        assert "**default**" in sections[name] and "\nDefault: " in sections[name], name
    assert "GONIO_REALDATA" in sections["realdata"]
    # the plan table's rows are all sessions: an adaptive session row, no planner-callback rows
    assert "| adaptive | budget" in text and "planner callback" not in text
    assert "Pareto front" in text


def test_report_writes_a_png_per_trade(report):
    _, out = report
    text = (out / "REPORT.md").read_text(encoding="utf-8")
    try:
        import matplotlib  # noqa: F401
    except ImportError:  # without the plots extra the report must say so instead
        assert "**No plots:**" in text
        return
    for name in TRADES:
        png = out / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert f"({name}.png)" in (out / "REPORT.md").read_text(encoding="utf-8")


def test_output_path_that_is_a_file_is_a_one_line_error(tmp_path, capsys):
    f = tmp_path / "not-a-dir"
    f.write_text("x")
    assert main(["bench", "--quick", "-o", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gonio bench: error: -o: out = ") and "not a directory" in err


def _tiny(quick):
    t = Table("tiny", ["x", "y"], baseline=0, default=0, why_default="because")
    t.add(1.0, 2.0)
    return [t]


def _broken(quick):
    raise RuntimeError("boom")


def test_report_without_matplotlib_and_with_a_failing_trade(tmp_path, monkeypatch, capsys):
    import sys

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if the plots extra were not installed
    trades = [Trade("tiny", "Tiny trade", _tiny, lambda ax, t: True), Trade("broken", "Broken", _broken, None)]
    path, failed = write_report(tmp_path, quick=True, trades=trades, stream=sys.stderr)
    text = path.read_text(encoding="utf-8")
    assert failed == ["broken"]
    assert "(quick run)" in text and "`gonio bench --quick`" in text and "Smoke run" not in text
    assert "**No plots:**" in text and "| matplotlib | not installed" in text
    assert "### tiny" in text and "Default: because" in text
    assert "RuntimeError: boom" in text and "**Failed trades:** broken" in text
    assert not list(tmp_path.glob("*.png"))
    err = capsys.readouterr().err
    assert "matplotlib is not installed" in err and "broken failed" in err


def _row(kind, label, lab, err, default=False):
    from benchmarks.bench_tradeoffs import PlanRow

    return PlanRow(kind, label, 10, lab, 1.0, 100, 0.01, err, 1.0, default)


def test_pareto_front_and_knee():
    from benchmarks.bench_tradeoffs import knee, pareto_front

    lab = [100, 110, 120, 130, 200, 150, 400]
    err = [1.0, 0.1, 0.05, 0.045, 0.03, 0.2, 0.02]  # row 5 is dominated (by rows 1-3)
    assert pareto_front(lab, err).tolist() == [0, 1, 2, 3, 4, 6]
    assert knee(lab, err) == 2  # the big drop is over by 120 s; later rows buy little for their time
    assert knee([100], [0.5]) == 0
    assert pareto_front([1, 2, float("nan")], [2, 1, 0.1]).tolist() == [0, 1]


def test_why_default_is_computed_from_the_rows():
    from benchmarks.bench_tradeoffs import why_default

    rows = [_row("in_plane", "sparse", 100, 1.0), _row("in_plane", "d (gonio measure default)", 120, 0.2, True),
            _row("half_diff", "6 θh", 115, 0.05), _row("grid", "dense", 400, 0.04)]
    text = why_default(rows)
    assert "in_plane d (10 poses)" in text and "**not** on the Pareto front" in text
    assert "half_diff 6 θh (10 poses) beats it in both (0.96× the default's lab time for 0.25× its error)" in text
    assert "knee" in text and "half_diff 6 θh" in text.split("knee")[1]
    rows[2] = _row("half_diff", "6 θh", 130, 0.19)
    text = why_default(rows)
    assert "It is on the lab time / error Pareto front" in text and "It is the knee" in text


def test_knee_of_a_two_row_front_is_the_more_accurate_row():
    from benchmarks.bench_tradeoffs import knee

    assert knee([235.0, 246.0, 300.0], [5.7, 0.02, 0.1]) == 1


def test_bench_robustness_writes_the_robustness_tables(tmp_path, monkeypatch, capsys):
    """`gonio bench --robustness` runs benchmarks.bench_robustness (its sections have their own tests,
    tests/test_bench_robustness.py; here a stand-in table keeps this test cheap) and writes ROBUSTNESS.md."""
    from benchmarks import bench_robustness

    asked = []

    def fake_run(quick=False):
        asked.append(quick)
        t = Table("Frames fuzzed per decoder", ["decoder", "frames", "crashes"])
        t.add("python", 1000, 0)
        return [t]

    monkeypatch.setattr(bench_robustness, "run", fake_run)
    assert main(["bench", "--robustness", "-o", str(tmp_path / "r")]) == 0
    text = (tmp_path / "r" / "ROBUSTNESS.md").read_text()
    assert asked == [False] and "full scale" in text and "Frames fuzzed per decoder" in text and "| python" in text
    assert "ROBUSTNESS.md" in capsys.readouterr().out


def test_sizes_order_and_the_smoke_size_runs_the_quick_code_where_a_trade_has_no_smaller_one():
    from benchmarks.bench_tradeoffs import _brackets, _uniform_plans, fitted_model
    from benchmarks.common import Size, round_time, size, timed_calls

    assert [size(False), size(True), size(Size.SMOKE)] == [Size.FULL, Size.QUICK, Size.SMOKE]
    assert round_time(False) > round_time(True) > round_time(Size.SMOKE) == 0.0  # smoke: one timed call a round
    assert timed_calls(False) > timed_calls(True) > timed_calls(Size.SMOKE) == 1
    assert not Size.FULL and Size.QUICK and Size.SMOKE  # `if quick:` takes the quick branch at the smoke size
    assert len(_uniform_plans(Size.SMOKE)) < len(_uniform_plans(True)) < len(_uniform_plans(False))
    assert len(_brackets(Size.SMOKE)) < len(_brackets(True)) < len(_brackets(False))
    assert fitted_model(True) == fitted_model(False) == "lambert+2ggx" != fitted_model(Size.SMOKE)


def test_no_test_can_look_for_the_real_materials():
    """The suite's guard (tests/conftest.py): the realdata lookup every benchmark goes through fails inside a test,
    whatever the machine holds, and $GONIO_REALDATA is unset."""
    import os

    import benchmarks.bench_realdata

    with pytest.raises(AssertionError, match="realdata"):
        benchmarks.bench_realdata.find_realdata()
    assert "GONIO_REALDATA" not in os.environ
