"""`gonio status` sums the lab time of every run of a session; a resume with nothing to do is not counted."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.cli.status import session_status
from gonio.plan.plan import CaptureSettings, Plan
from gonio.samples import SampleSet
from gonio.session.store import SessionStore

SMALL = ["--sim", "--quiet", "--sim-resolution", "240x180", "--plan", "in_plane", "--theta-i-step", "30",
         "--theta-o-step", "30", "--theta-max", "60"]


def _plan(n):
    poses = np.radians(np.tile([30.0, 0.0, 30.0, 180.0], (n, 1)))
    return Plan(poses=poses, capture=CaptureSettings(), generator="custom")


def _one_sample():
    return SampleSet.from_angles(np.radians([30.0]), np.zeros(1), np.radians([30.0]), np.full(1, np.pi),
                                 f=np.full((1, 3), 0.3), sigma=np.full((1, 3), 0.01))


def test_lab_time_is_the_sum_over_the_first_run_and_each_resume(tmp_path, capsys):
    d = tmp_path / "s"
    store = SessionStore.create(d, {"plan": _plan(3), "mode": "test"})
    store.append(0, _one_sample())
    store.finish("interrupted", last_run={"status": "interrupted", "poses": 1, "samples": 1, "lab_time_s": 100.0})
    store = SessionStore.open(d)
    store.append(1, _one_sample())
    store.finish("interrupted", last_run={"status": "interrupted", "poses": 1, "samples": 1, "lab_time_s": 40.0})
    store = SessionStore.open(d)
    store.append(2, _one_sample())
    store.finish("completed", last_run={"status": "completed", "poses": 1, "samples": 1, "lab_time_s": 25.5})
    s = session_status(d)
    assert s["lab_time"] == pytest.approx(165.5) and s["lab_time_runs"] == 3 and s["resumes"] == 2
    assert main(["status", str(d)]) == 0
    assert "lab time:     165.5 s over 3 runs" in capsys.readouterr().out


def test_resume_of_a_finished_session_says_so_and_is_not_counted(tmp_path, capsys):
    d = tmp_path / "s"
    assert main(["measure", *SMALL, "--out", str(d)]) == 0
    first = session_status(d)
    assert first["lab_time_runs"] == 1 and first["lab_time"] > 0
    capsys.readouterr()
    assert main(["resume", str(d), "--quiet"]) == 0
    assert "nothing to resume" in capsys.readouterr().out
    after = session_status(d)
    assert after["resumes"] == 0 and after["exit_status"] == "completed"
    assert after["lab_time"] == pytest.approx(first["lab_time"]) and after["lab_time_runs"] == 1
