"""`gonio measure` / `gonio resume` through the CLI entry point (in-process; the simulated rig)."""

from __future__ import annotations

import json

import pytest

from gonio.cli.main import main
from gonio.session.store import load_session

SMALL = ["--sim", "--quiet", "--sim-resolution", "240x180", "--plan", "in_plane", "--theta-i-step", "30",
         "--theta-o-step", "30", "--theta-max", "60"]


def test_measure_sim_runs_a_session_and_reports_samples_lab_and_wall_time(tmp_path, capsys, monkeypatch):
    from sim import compiled

    expected = []  # the simulator is told the session's size before its first frame (sim.compiled.expect)
    monkeypatch.setattr(compiled, "expect", lambda values, poses: expected.append((values, poses)))
    d = tmp_path / "s"
    assert main(["measure", *SMALL, "--out", str(d)]) == 0
    out = capsys.readouterr().out
    assert "samples" in out and "lab time" in out and "wall time" in out
    manifest, samples = load_session(d)
    assert manifest["exit_status"] == "completed" and manifest["mode"] == "sim"
    assert manifest["material"]["model"] == "microfacet" and manifest["sim"]["width"] == 240
    assert len(samples) > 0 and set(samples.pose.tolist()) == set(range(len(manifest["plan"]["poses"])))
    assert expected == [(240 * 180 * 3, len(manifest["plan"]["poses"]))]
    # resuming a completed session measures nothing and changes no sample
    before = (d / "samples.jsonl").read_bytes()
    assert main(["resume", str(d), "--quiet"]) == 0
    assert (d / "samples.jsonl").read_bytes() == before


def test_material_file_is_used_and_recorded(tmp_path):
    m = tmp_path / "white.toml"
    m.write_text('label = "matte"\nmodel = "lambert"\n[params]\nalbedo = [0.5, 0.5, 0.5]\n')
    d = tmp_path / "s"
    assert main(["measure", *SMALL, "--material", str(m), "--out", str(d)]) == 0
    manifest, samples = load_session(d)
    assert manifest["material"] == {"model": "lambert", "params": {"albedo": [0.5, 0.5, 0.5]}, "label": "matte"}
    good = samples.good()
    assert abs(float(good.f.mean()) * 3.141592653589793 - 0.5) < 0.01


@pytest.mark.parametrize("extra, named", [
    (["--plan", "spiral"], "spiral"),
    (["--theta-i-step", "5"], "--theta-i-step"),  # not a parameter of the default plan (half_diff)
    (["--plan", "grid", "--theta-max", "0", "--theta-step", "10"], "no reachable pose"),
    (["--sim-resolution", "big"], "big"),
])
def test_bad_input_is_one_line_error_and_nothing_written(tmp_path, capsys, extra, named):
    d = tmp_path / "s"
    args = ["measure", "--sim", "--quiet", "--out", str(d), *extra]
    assert main(args) != 0
    err = capsys.readouterr().err.strip()
    assert named in err and err.count("\n") == 0
    assert not d.exists()


def test_bad_material_and_unknown_model_name_the_file(tmp_path, capsys):
    m = tmp_path / "m.toml"
    m.write_text('model = "glitter"\n')
    assert main(["measure", "--sim", "--material", str(m), "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert str(m) in err and "glitter" in err
    m.write_text('model = "lambert"\n')  # missing its required parameter
    assert main(["measure", "--sim", "--material", str(m), "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert str(m) in err and "albedo" in err
    assert not (tmp_path / "s").exists()


def test_a_directory_holding_another_session_is_refused_and_left_alone(tmp_path, capsys):
    d = tmp_path / "s"
    d.mkdir()
    (d / "manifest.json").write_text(json.dumps({"format": 1, "note": "someone else's"}))
    assert main(["measure", *SMALL, "--out", str(d)]) == 2
    assert "holds another session" in capsys.readouterr().err
    assert json.loads((d / "manifest.json").read_text())["note"] == "someone else's"
    assert not (d / "samples.jsonl").exists()


def test_hardware_mode_names_the_missing_option(tmp_path, capsys):
    assert main(["measure", "--rig", "default", "--out", str(tmp_path / "s")]) == 2
    assert "--servo-port" in capsys.readouterr().err


def test_resume_of_a_directory_without_a_session_is_an_error(tmp_path, capsys):
    assert main(["resume", str(tmp_path)]) == 2
    assert "not a gonio session" in capsys.readouterr().err
