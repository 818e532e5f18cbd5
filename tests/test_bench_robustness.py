"""A small run of every section of benchmarks/bench_robustness.py (the full-scale run is
`python -m benchmarks robustness`): the goals hold at small scale too."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from benchmarks import bench_robustness as br


def test_wire_fuzz_python_and_c():
    for row in (br.python_wire_fuzz(1500), br.c_wire_fuzz(20_000)):
        assert (row["crashes"], row["corrupt_accepted"], row["lost_resync"]) == (0, 0, 0), row


def test_dynamixel_status_fuzz():
    row = br.dxl_status_fuzz(3000)
    assert row["crashes"] == 0 and row["wrong_values"] == 0 and row["accepted"] > 0


def test_config_and_session_file_fuzz(tmp_path):
    assert br.config_fuzz(20)["tracebacks"] == 0
    s = tmp_path / "s"
    assert br._gonio("measure", "--sim", *br.SESSION_ARGS, "--out", str(s)).wait() == 0
    assert br.record_fuzz(s, 300)["tracebacks"] == 0


def test_kill_resume_is_bit_identical():
    row = br.kill_resume(1, seed=11)
    assert (row["unresumable"], row["poses_lost"], row["records_duplicated"], row["poses_not_bit_identical"]) == \
        (0, 0, 0, 0), row


def test_fault_scenarios_complete_or_stop_in_one_line():
    for row in br.fault_scenarios(quick=True):
        assert row["one_line"] and row["lost"] == 0, row
        assert row["status"] == ("error" if "E-stop" in row["scenario"] else "completed"), row
