"""`gonio plan NAME --out PLAN.json` writes a plan that `gonio measure --plan-file PLAN.json` runs, pose for
pose; the file is versioned and validated on read (one line per fault, before anything moves)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.session.store import load_session

PLAN = ["in_plane", "--theta-i-step", "30", "--theta-o-step", "30", "--theta-max", "60"]
SIM = ["--sim", "--quiet", "--sim-resolution", "240x180"]


@pytest.fixture(scope="module")
def plan_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("plan") / "plan.json"
    assert main(["plan", *PLAN, "--out", str(path)]) == 0
    return path


def test_measure_runs_the_saved_plan_pose_for_pose(plan_file, tmp_path, capsys):
    saved = json.loads(plan_file.read_text())
    assert saved["format"] == 1 and saved["units"] == "rad" and saved["n_poses"] == len(saved["poses"])
    d = tmp_path / "s"
    assert main(["measure", *SIM, "--plan-file", str(plan_file), "--out", str(d)]) == 0
    assert f"plan {plan_file}: in_plane, {saved['n_poses']} poses" in capsys.readouterr().out
    manifest, samples = load_session(d)
    assert manifest["exit_status"] == "completed"
    np.testing.assert_array_equal(np.array(manifest["plan"]["poses"]), np.array(saved["poses"]))
    assert set(samples.pose.tolist()) == set(range(saved["n_poses"]))
    # a session (its directory or manifest) is a plan file too: the same poses measured on the next sample
    from gonio.io.plan_file import read_plan_file
    from gonio.rig.kinematics import load_rig

    assert main(["measure", *SIM, "--plan-file", str(d), "--out", str(tmp_path / "again")]) == 0
    assert f"plan {d}: in_plane, {saved['n_poses']} poses" in capsys.readouterr().out
    np.testing.assert_array_equal(read_plan_file(d / "manifest.json", load_rig(None)).poses, np.array(saved["poses"]))


def test_plan_out_that_exists_is_refused_before_the_plan_is_computed(plan_file, capsys):
    before = plan_file.read_bytes()
    assert main(["plan", *PLAN, "--out", str(plan_file)]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "exists (use --force" in err
    assert plan_file.read_bytes() == before


def _bad(tmp_path, plan_file, edit) -> str:
    data = json.loads(plan_file.read_text())
    edit(data)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(data) if not isinstance(data, str) else data)
    return str(p)


@pytest.mark.parametrize("edit, says", [
    (lambda d: d.update(format=2), "format = 2: expected 1; written by a newer gonio?"),
    (lambda d: (d.clear(), d.update(model="lambert", params={})), "expected 1; it is not a plan (no 'poses'"),
    (lambda d: d["poses"].__setitem__(0, [30.0, 0.0, 45.0, 180.0]), "in a file whose angles are radians: were "
                                                                     "degrees written?"),
    (lambda d: d.update(units="deg"), "units = 'deg': expected 'rad'"),
    (lambda d: d.update(n_poses=d["n_poses"] + 1), "n_poses ="),
    (lambda d: d.pop("poses"), "missing field 'poses'"),
    (lambda d: d["poses"].__setitem__(0, [0.3, 0.0, 3.0, 0.0]), "is unreachable on rig"),
    (lambda d: d["poses"].__setitem__(0, [0.3, 0.0]), "bad.json"),
])
def test_a_bad_plan_file_is_one_line_and_nothing_moves(plan_file, tmp_path, capsys, edit, says):
    bad = _bad(tmp_path, plan_file, edit)
    out = tmp_path / "never"
    assert main(["measure", *SIM, "--plan-file", bad, "--out", str(out)]) != 0
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1 and "bad.json" in err
    assert not out.exists()


def test_plan_file_that_is_not_json_and_conflicting_options(plan_file, tmp_path, capsys):
    p = tmp_path / "plan.json"
    p.write_text("version https://git-lfs.github.com/spec/v1\noid sha256:0\n")
    assert main(["measure", *SIM, "--plan-file", str(p), "--out", str(tmp_path / "s")]) != 0
    assert "Git LFS pointer" in capsys.readouterr().err
    assert main(["measure", *SIM, "--plan-file", str(plan_file), "--plan", "grid", "--out", str(tmp_path / "s")]) == 2
    assert "give it without --plan" in capsys.readouterr().err
