"""The session API (gonio.session.api, issue 31): the README's script measures on the simulated rig, is
interrupted from its callback, resumes, fits and exports — without gonio.cli; the same script against the emulated
hardware path (servo bus and rig controller on pseudo-terminals, driven through dynamixel-sdk and pyserial, with a
camera object of the caller's); the rig's context manager leaves the light off and the torque released."""

from __future__ import annotations

import math
import re
import runpy
import sys
from pathlib import Path

import pytest

import gonio
from gonio.errors import ConfigError
from gonio.session.store import load_session

ROOT = Path(__file__).resolve().parents[2]


def _script() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Run the instrument from Python", 1)[1].split("\n## ", 1)[0]
    block = re.findall(r"```python\n(.*?)```", section, flags=re.S)[0]
    assert len(block.strip().splitlines()) <= 15, "the README promises a 15-line script"
    assert "gonio.cli" not in block
    return block


def _run(source: str, cwd: Path, namespace: dict | None = None) -> dict:
    import os

    old = os.getcwd()
    os.chdir(cwd)
    try:
        ns = dict(namespace or {})
        exec(compile(source, "README script", "exec"), ns)  # noqa: S102 - the README's own script
        return ns
    finally:
        os.chdir(old)


def _check_outcome(cwd: Path, ns: dict, capsys) -> None:
    out = capsys.readouterr().out
    assert "interrupted" in out  # the callback stopped the first run
    manifest, samples = load_session(cwd / "demo-session")
    assert manifest["exit_status"] == "completed" and len(manifest["resumes"]) >= 1
    assert sorted(set(samples.pose.tolist())) == list(range(len(manifest["plan"]["poses"])))
    assert ns["run"].ok and ns["fit"].params["alpha"] == pytest.approx(0.25, abs=0.03)
    assert "<bsdf" in (cwd / "demo.xml").read_text()


def test_the_readme_script_measures_resumes_fits_and_exports_on_the_simulated_rig(tmp_path, capsys):
    ns = _run(_script(), tmp_path)
    _check_outcome(tmp_path, ns, capsys)


def test_the_same_script_on_the_emulated_hardware_path(tmp_path, capsys):
    """Real ports (pty) for the servos and the controller, opened by the host's own drivers; the camera a simulated
    one handed in as an object (a mixed rig); resume onto the rig the script holds open."""
    from gonio.plugins import plugin

    simrig = plugin("sim.rig")
    cfg = simrig.SimRigConfig(controller="python")
    with simrig.SimRig("default", simrig.DEFAULT_MATERIAL, config=cfg) as sim:
        opened = (f'gonio.open_rig("default", hardware=gonio.HardwareOptions(servo_port={sim.servo_port!r}, '
                  f'controller_port={sim.controller_port!r}), camera=SIM.camera, calibration=SIM.calibration, '
                  'clock=SIM.clock)')
        source = _script().replace("gonio.open_rig(sim=True)", opened)
        assert opened in source
        ns = _run(source, tmp_path, {"SIM": sim})
        _check_outcome(tmp_path, ns, capsys)
        manifest, _ = load_session(tmp_path / "demo-session")
        assert manifest["mode"] == "hardware" and manifest["hardware"]["servo_port"] == sim.servo_port
        # leaving the with block: light off, torque released (the servos on the emulated bus say so)
        assert not sim.controller.light_on
        assert all(s.peek("torque_enable") == 0 for s in sim.servo_bus.servos.values())


def test_the_notebook_example_in_docs_runs(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["measure_from_python.py", str(tmp_path / "nb")])
    runpy.run_path(str(ROOT / "docs" / "examples" / "measure_from_python.py"), run_name="__main__")
    out = capsys.readouterr().out
    assert "interrupted: 6/38 poses" in out and "completed: 38/38 poses" in out
    assert (tmp_path / "nb.xml").is_file()


def test_a_callback_that_fails_is_said_and_the_session_goes_on(tmp_path, capsys):
    calls = []

    def bad(event):
        calls.append(event.index)
        raise RuntimeError("plot window closed")

    from gonio.plan.generators import make_plan

    plan = make_plan("in_plane", theta_i_step=math.radians(30), theta_o_step=math.radians(30),
                     theta_max=math.radians(60))  # 12 poses (the generator's defaults: 56): each callback fails
    with gonio.open_rig(sim=gonio.SimOptions(seed=2)) as rig:
        run = gonio.measure(rig, plan, tmp_path / "s", on_pose=bad, progress=None)
    assert run.ok and len(calls) == run.poses_total == len(plan) > 1
    err = capsys.readouterr().err
    assert "on_pose callback failed (RuntimeError: plot window closed); the pose is stored" in err


def test_options_are_validated_in_one_line():
    with pytest.raises(ConfigError, match="--sim-resolution") as e:
        gonio.SimOptions(resolution="10x10")
    assert "\n" not in str(e.value)
    with pytest.raises(ConfigError, match="--sim-controller"):
        gonio.SimOptions(controller="arduino")
    with pytest.raises(ConfigError, match="--warmup-wait"):
        gonio.TimingOptions(warmup_wait=-1).as_dict()
    with pytest.raises(ConfigError, match="--seed"):
        gonio.SimOptions(seed=-1)


def test_resume_onto_another_rig_is_refused(tmp_path):
    with gonio.open_rig(sim=True) as rig:
        run = gonio.measure(rig, "in_plane", tmp_path / "s", on_pose=lambda e: e.done < 2, progress=None)
    assert run.status == "interrupted"
    with gonio.open_rig("turntable", sim=True) as other:
        with pytest.raises(ConfigError, match="not the rig this session was measured with"):
            gonio.resume(tmp_path / "s", rig=other)
