"""A session whose manifest plan was edited after poses were measured is not resumed: the records' own angles
(``meta.pose_rad``) disagree with the plan, and a resume would measure the missing poses at other angles than
planned, never measure the planned angles, and end "completed" (found by QA, qa-hostile)."""

from __future__ import annotations

import json
import shutil

from gonio.cli.main import main


def without_last_record(measured, tmp_path):
    d = tmp_path / "s"
    shutil.copytree(measured, d)
    lines = (d / "samples.jsonl").read_bytes().splitlines(keepends=True)
    last = json.loads(lines[-1][9:])["pose"]
    (d / "samples.jsonl").write_bytes(b"".join(lines[:-1]))
    return d, last


def test_a_reordered_plan_is_refused_in_one_line_and_nothing_is_measured(measured, tmp_path, capsys):
    d, last = without_last_record(measured, tmp_path)
    m = json.loads((d / "manifest.json").read_text())
    first = next(k for k in range(m["plan"]["n_poses"]) if k != last)
    for key in ("poses", "joints"):
        m["plan"][key][first], m["plan"][key][last] = m["plan"][key][last], m["plan"][key][first]
    (d / "manifest.json").write_text(json.dumps(m))
    before = (d / "samples.jsonl").read_bytes(), (d / "manifest.json").read_bytes()
    capsys.readouterr()
    code = main(["resume", str(d)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 4 and len(err) == 1 and "Traceback" not in err[0], err
    assert f"plan.poses[{first}]" in err[0] and "not the one this session measured" in err[0]
    assert ((d / "samples.jsonl").read_bytes(), (d / "manifest.json").read_bytes()) == before  # not marked resumed


def test_an_unchanged_plan_resumes(measured, tmp_path, capsys):
    d, last = without_last_record(measured, tmp_path)
    assert main(["resume", str(d)]) == 0
    assert json.loads((d / "samples.jsonl").read_bytes().splitlines()[-1][9:])["pose"] == last
