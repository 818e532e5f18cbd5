"""Config and CLI input (issue: hardening): mutated rig, camera, target and material files give one-line
ConfigErrors, never a traceback; device files and FIFOs are refused, not read; out-of-range CLI values
are one line; the kinematic guard refuses non-finite angles on its own."""

from __future__ import annotations

import math
import os
import random
import tomllib
from importlib import resources

import numpy as np
import pytest

from gonio.cli.main import main
from gonio.errors import ConfigError, GonioError, UnreachablePose
from gonio.pipeline.target import load_target
from gonio.rig.calibration import load_camera_calibration
from gonio.rig.kinematics import load_rig
from gonio.session.material import load_material

CAMERA = ("width = 320\nheight = 240\nfocal_px = 380.0\ndist = [0.0, 0.0, 0.0, 0.0, 0.0]\n[noise]\n"
          "dn_per_electron = 0.2\nread_noise_e = 3.0\nfull_well_e = 20000\n[camera]\nlinear = true\n"
          "bit_depth = 12\nblack_level = 64\n")
TARGET = ('[charuco]\nsquares = [9, 7]\nsquare_length = 0.03\nmarker_length = 0.022\ndictionary = "DICT_5X5_100"\n'
          "sample = [-0.025, -0.025, 0.025, 0.025]\nwhite = [-0.105, -0.02, -0.065, 0.02]\nwhite_albedo = 0.99\n"
          "[mount]\ntilt_x_deg = 1.0\n")
MATERIAL = 'model = "microfacet"\nlabel = "x"\n[params]\nkd = [0.3, 0.1, 0.1]\nks = 0.8\nalpha = 0.2\nf0 = 0.04\n'
#: Values the audit found tracebacks with, and their relatives.
VALUES = ['"up"', '"fast"', "5", "inf", "-inf", "nan", "2147483648.0", "1e308", "-1", "0", "1e-300", "true", "[]",
          "[1, 2]", "[9, 7000]", "{}", "{a = 1}", '"x"', "[[1,2],[3]]", "-0.0", "1e30", "99999999999999999999"]


def _shipped(name: str) -> str:
    return (resources.files("gonio.rig") / "rigs" / name).read_text()


def mutate(text: str, rng: random.Random) -> str:
    lines = text.splitlines()
    idx = [i for i, line in enumerate(lines) if "=" in line and not line.strip().startswith("#")]
    for _ in range(rng.randint(1, 3)):
        i = rng.choice(idx)
        key = lines[i].split("=", 1)[0]
        r = rng.random()
        if r < 0.8:
            lines[i] = f"{key}= {rng.choice(VALUES)}"
        elif r < 0.9:
            lines[i] = ""
        else:  # a value where a table was, and a table where a value was
            lines[i] = f"{key}= {rng.choice(VALUES)}\n[{key.strip()}]\nx = 1"
    return "\n".join(lines) + "\n"


def fuzz_configs(n_per_kind: int, seed: int, tmp_dir) -> tuple[int, list[str]]:
    """Mutated files per loader: ``(files tried, tracebacks as 'kind: Type: message')``."""
    rng = random.Random(seed)
    tried, bad = 0, []
    kinds = (("rig", _shipped("default.toml"), load_rig), ("turntable", _shipped("turntable.toml"), load_rig),
             ("camera", CAMERA, load_camera_calibration), ("target", TARGET, load_target),
             ("material", MATERIAL, load_material))
    for kind, base, loader in kinds:
        path = os.path.join(tmp_dir, f"{kind}.toml")
        for _ in range(n_per_kind):
            text = mutate(base, rng)
            try:
                tomllib.loads(text)
            except tomllib.TOMLDecodeError:
                continue  # not TOML: the parser's one-line error is tested elsewhere
            with open(path, "w") as fh:
                fh.write(text)
            tried += 1
            try:
                loader(path)
            except GonioError as exc:
                assert "\n" not in str(exc)
            except Exception as exc:  # noqa: BLE001 - what the test counts
                bad.append(f"{kind}: {type(exc).__name__}: {exc}")
    return tried, bad


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
