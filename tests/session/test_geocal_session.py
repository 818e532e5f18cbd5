"""The geometric calibration session (issue 15) runs through the session runner on the simulated rig:
observations stored per pose, an interrupted session resumed to the same observations, the estimate refused
in one line when the poses cannot determine the rig, and the hardware path naming what it needs."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from gonio.errors import ConfigError
from gonio.rig.kinematics import load_rig, read_rig_text
from gonio.session.geocal_session import calibration_lab_time, calibration_session_plan


@pytest.fixture(scope="module")
def rig():
    return load_rig("default")


def _small_plan(rig):
    """Two ChArUco poses and two highlight poses of the quick calibration plan."""
    from dataclasses import replace

    plan = calibration_session_plan(rig, quick=True)
    kinds = plan.params["kinds"]
    idx = [0, 5] + [kinds.index("highlight") + k for k in (4, 7)]
    return replace(plan, poses=plan.poses[idx], joints=plan.joints[idx],
                   params={**plan.params, "kinds": [kinds[i] for i in idx]})


@pytest.fixture(scope="module")
def session(rig, tmp_path_factory):
    """A 4-pose calibration session on as-built rig 3 (too few poses for an estimate: refused in one line)."""
    from gonio.cli.calibrate import _new_session

    d = tmp_path_factory.mktemp("geocal")
    text, src = read_rig_text("default")
    args = argparse.Namespace(out=str(d / "cal.toml"), session=None, sim=True, sim_as_built="3", seed=0, quiet=True)
    with pytest.raises(ConfigError) as info:
        _new_session(args, rig, text, src, _small_plan(rig))
    return d, info.value


def _records(d):
    from gonio.session.store import scan_samples

    return {k: meta for k, (_, meta) in scan_samples(d / "cal.toml.session" / "samples.jsonl").records.items()}


def test_the_calibration_plan_is_reachable_and_fits_in_ten_minutes(rig):
    plan = calibration_session_plan(rig)
    kinds = plan.params["kinds"]
    assert kinds.count("camera") >= 20 and kinds.count("highlight") >= 150
    assert calibration_lab_time(plan, rig) < 600
    wi, wo = rig.directions(plan.joints)
    assert np.all(rig.check_directions(wi, wo) == 0)
    assert np.all((plan.joints >= rig.lower) & (plan.joints <= rig.upper))


def test_every_pose_is_stored_with_what_the_camera_saw(session, rig):
    d, err = session
    assert "need at least 8" in str(err) and "\n" not in str(err)
    recs = _records(d)
    assert sorted(recs) == [0, 1, 2, 3]
    for k, meta in recs.items():
        assert meta["board"] is not None and np.shape(meta["board"]["cov"]) == (6, 6)
        target = np.array([meta["target_joints_rad"][n] for n in rig.names])
        measured = np.array([meta["joints_rad"][n] for n in rig.names])
        assert np.all(np.abs(np.degrees(measured - target)) < 0.5)
    assert [recs[k]["kind"] for k in range(4)] == ["camera", "camera", "highlight", "highlight"]
    hl = [recs[k]["highlight"] for k in (2, 3)]
    assert all(h is not None and np.all(np.isfinite(h["xy"])) for h in hl), [recs[k]["reason"] for k in (2, 3)]
    manifest = json.loads((d / "cal.toml.session" / "manifest.json").read_text())
    assert manifest["exit_status"] == "completed" and manifest["sim"]["tile"] == {}
    assert not (d / "cal.toml").exists()  # no estimate, no file


def test_an_interrupted_calibration_session_resumes_to_the_same_observations(session, tmp_path):
    import shutil

    from gonio.cli.main import main

    d, _ = session
    src = d / "cal.toml.session"
    dst = tmp_path / "cal.toml.session"
    shutil.copytree(src, dst)
    lines = (dst / "samples.jsonl").read_bytes().splitlines(keepends=True)
    (dst / "samples.jsonl").write_bytes(b"".join(lines[:2]))  # as if the rig stopped after two poses
    m = json.loads((dst / "manifest.json").read_text())
    m["exit_status"], m["geocal"]["out"] = "interrupted", str(tmp_path / "cal.toml")
    (dst / "manifest.json").write_text(json.dumps(m))
    assert main(["resume", str(dst), "--quiet"]) != 0  # measures poses 2, 3; the estimate is refused (4 poses)
    before, after = _records(d), {k: v for k, v in _records(tmp_path).items()}
    assert sorted(after) == [0, 1, 2, 3]
    for k in (2, 3):  # the same pose, frames and detections (the arms' last micro-steps differ with the history)
        assert np.allclose(after[k]["highlight"]["xy"], before[k]["highlight"]["xy"], atol=3e-5)  # 0.01 px
        assert np.allclose(after[k]["board"]["position_m"], before[k]["board"]["position_m"], atol=2e-4)


def test_the_hardware_path_names_what_it_needs(capsys, tmp_path):
    from gonio.cli.main import main

    assert main(["calibrate", "rig", "--out", str(tmp_path / "c.toml")]) != 0
    err = capsys.readouterr().err
    assert "--rig RIG.toml" in err and err.count("\n") == 1
    text, _ = read_rig_text("default")
    (tmp_path / "rig.toml").write_text(text)
    assert main(["calibrate", "rig", "--rig", str(tmp_path / "rig.toml"), "--camera", "0",
                 "--out", str(tmp_path / "c.toml")]) != 0
    err = capsys.readouterr().err
    assert "--servo-port" in err and "--controller-port" in err and "--calibration" in err and err.count("\n") == 1
    assert main(["calibrate", "rig", "--rig", str(tmp_path / "rig.toml"), "--estimate"]) == 0
    assert "estimated lab time" in capsys.readouterr().out
    assert not any(p.name.endswith(".session") for p in tmp_path.iterdir())
