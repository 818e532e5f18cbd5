"""Config and CLI input (issue: hardening): mutated rig, camera, target and material files give one-line
ConfigErrors, never a traceback; device files and FIFOs are refused, not read; out-of-range CLI values
are one line; the kinematic guard refuses non-finite angles on its own."""

from __future__ import annotations

import math
import os
import tomllib

import numpy as np
import pytest

from benchmarks.robust_inputs import _shipped, fuzz_configs
from gonio.cli.main import main
from gonio.errors import ConfigError, UnreachablePose
from gonio.rig.kinematics import load_rig

def test_mutated_config_files_never_traceback(tmp_path):
    tried, bad = fuzz_configs(60, seed=7, tmp_dir=tmp_path)
    assert tried > 200 and bad == []


@pytest.mark.parametrize("edit, message", [
    (lambda d: {**d, "layout": ["arms"]}, "layout"),
    (lambda d: {**d, "joints": 5}, "joints"),
    (lambda d: {**d, "bus": {"baud": "fast"}}, "bus.baud"),
    (lambda d: {**d, "geometry": 3}, "geometry"),
    (lambda d: {**d, "joints": [{**j, "servo_id": 2.5} for j in d["joints"]]}, "servo_id"),
    (lambda d: {**d, "joints": [{**j, "direction": "up"} for j in d["joints"]]}, "direction"),
    (lambda d: {**d, "joints": [{**j, "name": 5} for j in d["joints"]]}, "name"),
])
def test_rig_structure_errors_are_one_line(edit, message):
    data = edit(tomllib.loads(_shipped("default.toml")))
    with pytest.raises(ConfigError, match=message) as exc:
        load_rig(text=_to_toml(data), source="rig.toml")
    assert "\n" not in str(exc.value)


def _to_toml(d: dict) -> str:
    """A minimal TOML writer for these tests (tables, arrays of tables, scalars, arrays)."""
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v + '"'
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + "}"
        return repr(v)
    top = [f"{k} = {val(v)}" for k, v in d.items()
           if not isinstance(v, dict) and not (isinstance(v, list) and v and all(isinstance(x, dict) for x in v))]
    out = top[:]
    for k, v in d.items():
        if isinstance(v, dict):
            out += [f"[{k}]"] + [f"{a} = {val(b)}" for a, b in v.items()]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                out += [f"[[{k}]]"] + [f"{a} = {val(b)}" for a, b in item.items()]
    return "\n".join(out) + "\n"


def test_device_files_and_fifos_are_refused_not_read(tmp_path, capsys):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for path in ("/dev/zero", str(fifo)):
        assert main(["measure", "--sim", "--rig", path, "--out", str(tmp_path / "s")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"gonio measure: error: --rig = '{path}': is not a regular file"]
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("argv", [["measure", "--sim", "--seed", "-1"], ["plan", "in_plane", "--seed", "-1"],
                                  ["fit", "x.binary", "--seed", str(2 ** 32)]])
def test_seed_out_of_range_is_one_line(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--seed" in err[0]


@pytest.mark.parametrize("angles", [(0, 0, 0, -math.inf), (math.nan, 0, 0, 0), (0, math.inf, 0.3, 1.0),
                                    (0.3, 0, 0.4, math.nan)])
def test_the_kinematic_guard_refuses_non_finite_angles_itself(angles):
    rig = load_rig()
    with pytest.raises(UnreachablePose):
        rig.solve(*angles)
    joints, code = rig.solve_many(*[np.array([a]) for a in angles])
    assert code[0] != 0 and np.all(np.isnan(joints))


@pytest.mark.parametrize("charuco, message", [
    ("squares = [9, 7000]", "charuco.squares = (9, 7000): at most 100 squares a side"),
    ("squares = [40, 40]", "needs 800 markers but DICT_5X5_100 has 100"),
    ("marker_length = 1e-300", "charuco.marker_length = 1e-300: must be at least"),
    ('dictionary = "DICT_NOPE"', "charuco.dictionary = 'DICT_NOPE': not a cv2.aruco dictionary"),
])
def test_a_target_opencv_cannot_draw_is_refused_before_a_session_exists(tmp_path, capsys, charuco, message):
    base = {"squares": "squares = [9, 7]", "square_length": "square_length = 0.03",
            "marker_length": "marker_length = 0.022", "dictionary": 'dictionary = "DICT_5X5_100"'}
    base[charuco.split(" ")[0]] = charuco
    target = tmp_path / "target.toml"
    target.write_text("[charuco]\n" + "\n".join(base.values()) + "\n")
    out = tmp_path / "s"
    assert main(["measure", "--sim", "--plan", "in_plane", "--theta-i", "30", "--theta-o-step", "20", "--quiet",
                 "--target", str(target), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(target) in err[0] and message in err[0], err
    assert not out.exists()  # nothing left behind that could never be resumed
