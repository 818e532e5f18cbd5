"""A small run of each section of benchmarks/bench_robustness.py that this module owns (the full-scale
run is `python -m benchmarks robustness`): the goals hold at small scale too. The hooked sections have
their own tests (tests/session/test_robust_session.py; the wire module's own)."""

from __future__ import annotations

from benchmarks import bench_robustness as br


def test_dynamixel_status_fuzz():
    row = br.dxl_status_fuzz(3000)
    assert row["crashes"] == 0 and row["wrong_values"] == 0 and row["accepted"] > 0


def test_config_fuzz_has_no_traceback():
    assert br.config_fuzz(20)["tracebacks"] == 0


def test_fault_scenarios_complete_or_stop_in_one_line_with_the_resume_hint():
    picked = [s for s in br.SCENARIOS if s[0].startswith(("short", "servo overload", "E-stop"))]
    rows = br.fault_scenarios(quick=True, scenarios=picked)
    assert len(rows) == 3
    for row in rows:
        assert row["one_line"] and row["lost"] == 0 and row["goals_after"] == 0, row
        if row["scenario"].startswith("short"):
            assert row["status"] == "completed" and row["poses_stored"] == 4, row
        else:
            assert row["status"] == "safety stop" and row["resume_hint"], row  # servo alarm, E-stop: exit 7
    # an alarm after pose 1 was reached: pose 1 is captured where it stands, no move to pose 2
    assert "overload" in rows[1]["ended"] and rows[1]["poses_stored"] == 2
    # an E-stop during pose 1: nothing of pose 1 is kept (its frames may be of a dark sample)
    assert "E-stop" in rows[2]["ended"] and rows[2]["poses_stored"] == 1


def test_hooked_sections_say_not_available_when_their_module_is_absent():
    (t,) = br._hook_tables("robust_does_not_exist", "Some section", quick=True)
    assert "not available" in t.to_markdown()
