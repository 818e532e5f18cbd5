"""`gonio measure --plan sparse --adaptive` (issue 27 item 4): after each pose the next is the one that most reduces
the expected error under the posterior, on the simulated rig with a synthetic prior; it stops at the target or the
pose budget, says the expected error as it goes, and an interrupted session resumes and keeps adapting."""

from __future__ import annotations

import json

import numpy as np
import pytest

import gonio
from gonio.cli.main import main
from gonio.prior import save_prior
from gonio.prior.adaptive import SparseAdaptiveSettings, new_sparse_adaptive_manifest
from gonio.session.store import load_session
from tests.prior.conftest import GRID, node_values_of, synthetic_materials

SIM = ["--sim", "--sim-resolution", "240x180", "--seed", "2"]


@pytest.fixture(scope="module")
def prior_file(tmp_path_factory):
    """A prior of 8 synthetic Lambert + GGX materials (the simulated default material is one of that family)."""
    from gonio.prior import build_prior

    mats = synthetic_materials(8)
    prior = build_prior(node_values_of(mats), [n for n, _ in mats], GRID, calibrate=False)
    path = tmp_path_factory.mktemp("prior") / "synthetic.npz"
    save_prior(prior, path)
    return path


@pytest.fixture(scope="module")
def budget_run(prior_file, tmp_path_factory):
    d = tmp_path_factory.mktemp("adaptive") / "s"
    code = main(["measure", *SIM, "--plan", "sparse", "--adaptive", "--prior", str(prior_file), "--coarse", "3",
                 "--max-poses", "6", "--out", str(d)])
    assert code == 0
    return d


def test_stops_at_the_pose_budget_and_the_expected_error_falls(budget_run, capsys):
    manifest, samples = load_session(budget_run)
    ad = manifest["adaptive"]
    assert ad["planner"] == "prior" and ad["stop"] == "budget" and manifest["exit_status"] == "completed"
    assert len(manifest["plan"]["poses"]) == 6 and sorted(set(samples.pose.tolist())) == list(range(6))
    assert [r["n_poses"] for r in ad["rounds"]] == [3, 1, 1, 1]
    errors = [r["error"] for r in ad["rounds"]]
    assert all(b <= a + 1e-12 for a, b in zip(errors, errors[1:])) and errors[-1] < errors[0]
    # the planner never picks a pose twice, and every pose is one of the reachable candidates
    idx = [i for r in ad["rounds"] for i in r["candidate_index"]]
    assert len(set(idx)) == len(idx) and max(idx) < len(ad["candidates"]["poses"])
    assert ad["model"]["model"] == "prior posterior" and ad["model"]["params"]["expected_error"] == \
        pytest.approx(errors[-1])


def test_stops_at_the_target_expected_error(budget_run, prior_file, tmp_path, capsys):
    errors = [r["error"] for r in load_session(budget_run)[0]["adaptive"]["rounds"]]
    target = errors[1] * (1 + 1e-9)  # reached after the second round of the same seed's session
    d = tmp_path / "t"
    assert main(["measure", *SIM, "--plan", "sparse", "--adaptive", "--prior", str(prior_file), "--coarse", "3",
                 "--max-poses", "6", "--target-error", repr(target), "--out", str(d)]) == 0
    err = capsys.readouterr().err
    assert "expected error" in err and "stop (target)" in err  # progress says the current expected error
    ad = load_session(d)[0]["adaptive"]
    assert ad["stop"] == "target" and ad["rounds"][-1]["error"] <= target
    assert sum(r["n_poses"] for r in ad["rounds"]) < 6


def test_an_interrupted_session_resumes_and_keeps_adapting(prior_file, tmp_path, capsys):
    d = tmp_path / "i"
    with gonio.open_rig(sim=gonio.SimOptions(resolution="240x180", seed=2)) as rig:
        entry = new_sparse_adaptive_manifest(rig.rig, prior_arg=prior_file,
                                             settings=SparseAdaptiveSettings(n_initial=3, max_poses=6))
        run = gonio.measure(rig, entry["plan"], d, adaptive=entry["adaptive"], progress=None,
                            on_pose=lambda e: e.done < 4)  # stop after the first pose of round 1
    assert run.status == "interrupted"
    before = load_session(d)[0]["adaptive"]
    assert before["stop"] is None and len(before["rounds"]) == 2
    assert main(["resume", str(d), "--quiet"]) == 0
    manifest, samples = load_session(d)
    ad = manifest["adaptive"]
    assert ad["stop"] == "budget" and len(manifest["plan"]["poses"]) == 6
    assert ad["rounds"][:2][0]["candidate_index"] == before["rounds"][0]["candidate_index"]
    assert sorted(set(samples.pose.tolist())) == list(range(6))


def test_a_changed_prior_is_refused_at_resume_and_options_of_other_plans_are_refused(budget_run, prior_file,
                                                                                     tmp_path, capsys):
    m = json.loads((budget_run / "manifest.json").read_text())
    m["adaptive"]["prior"]["sha256"] = "0" * 64
    m["adaptive"]["stop"] = None
    (tmp_path / "c").mkdir()
    for f in budget_run.iterdir():
        (tmp_path / "c" / f.name).write_bytes(f.read_bytes())
    (tmp_path / "c" / "manifest.json").write_text(json.dumps(m))
    assert main(["resume", str(tmp_path / "c"), "--quiet"]) != 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "changed since the session started" in err
    p = ["--prior", str(prior_file)]
    for args, named in ((["--plan", "sparse", "--adaptive", *p, "--n", "5"], "--n"),
                        (["--plan", "half_diff", "--max-poses", "5"], "--max-poses"),
                        (["--plan", "half_diff", "--adaptive"], "--adaptive"),
                        (["--plan", "sparse", "--adaptive", *p, "--max-poses", "0"], "--max-poses"),
                        (["--plan", "sparse", "--adaptive", *p, "--select", "lambert"], "--select")):
        out = tmp_path / "x"
        assert main(["measure", *SIM, *args, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and named in err and not out.exists()
    assert main(["plan", "sparse", "--adaptive", "--prior", str(prior_file)]) == 2
    assert "chosen while measuring" in capsys.readouterr().err
