"""`gonio plan` and `gonio status` from the command line."""

import json

import numpy as np

from gonio.cli.main import main
from gonio.plan import Plan
from gonio.samples import SampleSet
from gonio.session.store import SAMPLES, SessionStore


def test_plan_estimate_and_out(tmp_path, capsys):
    out = tmp_path / "p.json"
    assert main(["plan", "in_plane", "--theta-i-step", "20", "--theta-o-step", "10", "--estimate",
                 "--exposures", "0.01,0.02", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "dropped" in text and "collision" in text and "lower bound" in text and "raster" in text
    plan = Plan.from_dict(json.loads(out.read_text()))
    assert plan.generator == "in_plane" and plan.capture.exposures == (0.01, 0.02)
    assert np.isclose(plan.params["theta_i_step"], np.radians(20))
    n = int(text.split(":")[1].split("poses")[0].strip().split()[-1])
    assert n == len(plan)


def test_plan_bad_input_is_one_line(capsys, tmp_path):
    assert main(["plan", "spiral"]) == 2
    assert main(["plan", "grid", "--theta-step", "-5"]) == 2
    assert main(["plan", "grid", "--n-theta-h", "4"]) == 2
    assert main(["plan", "in_plane", "--frames", "0"]) == 2
    assert main(["plan", "in_plane", "--out", str(tmp_path / "no" / "dir" / "p.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5
    assert "spiral" in err[0] and "grid.theta_step" in err[1] and "--n-theta-h" in err[2]
    assert "frames" in err[3] and "p.json" in err[4]


def test_status_reports_progress_and_torn_record(tmp_path, capsys):
    d = tmp_path / "s"
    plan = Plan(np.zeros((5, 4)), generator="custom")
    store = SessionStore.create(d, {"material": "m", "plan": plan})
    s = SampleSet(np.zeros((2, 3)), np.zeros((2, 3)), np.ones((2, 3)), np.ones((2, 3)))
    for k in range(3):
        store.append(k, s, {"lab_time_s": 10.0 * (k + 1)})
    store.close()
    with open(d / SAMPLES, "ab") as fh:
        fh.write(b"0123abcd {\"pose\": 3")  # a record torn by a crash
    assert main(["status", str(d)]) == 0
    out = capsys.readouterr().out
    assert "plan poses:   5" in out and "poses done:   3 (6 samples)" in out and "remaining:    2" in out
    assert "30.0 s" in out and "torn last record" in out and "none (still running" in out
    store = SessionStore.open(d)
    store.finish("completed")
    assert main(["status", str(d)]) == 0
    out = capsys.readouterr().out
    assert "exit status:  completed" in out and "torn" not in out


def test_status_of_a_non_session_is_an_error(tmp_path, capsys):
    assert main(["status", str(tmp_path)]) == 4
    assert "manifest.json" in capsys.readouterr().err
