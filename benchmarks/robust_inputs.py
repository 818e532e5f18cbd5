"""Mutation fuzzing of the configuration loaders (rig, camera, target, material TOML): shared by
benchmarks/bench_robustness.py (full scale) and tests/test_config_fuzz.py (a small run in the suite)."""

from __future__ import annotations

import os
import random
import tomllib
from importlib import resources

from gonio.errors import GonioError
from gonio.pipeline.target import load_target
from gonio.rig.calibration import load_camera_calibration
from gonio.rig.kinematics import load_rig
from gonio.io.material_toml import load_material

CAMERA = ("width = 320\nheight = 240\nfocal_px = 380.0\ndist = [0.0, 0.0, 0.0, 0.0, 0.0]\n[noise]\n"
          "dn_per_electron = 0.2\nread_noise_e = 3.0\nfull_well_e = 20000\n[camera]\nlinear = true\n"
          "bit_depth = 12\nblack_level = 64\n")
TARGET = ('[charuco]\nsquares = [9, 7]\nsquare_length = 0.03\nmarker_length = 0.022\ndictionary = "DICT_5X5_100"\n'
          "sample = [-0.025, -0.025, 0.025, 0.025]\nwhite = [-0.105, -0.02, -0.065, 0.02]\nwhite_albedo = 0.99\n"
          "[mount]\ntilt_x_deg = 1.0\n")
MATERIAL = 'model = "microfacet"\nlabel = "x"\n[params]\nkd = [0.3, 0.1, 0.1]\nks = 0.8\nalpha = 0.2\nf0 = 0.04\n'
#: Values the audit found tracebacks with, and their relatives.
VALUES = ['"up"', '"fast"', "5", "inf", "-inf", "nan", "2147483648.0", "1e308", "-1", "0", "1e-300", "true", "[]",
          "[1, 2]", "[9, 7000]", "[40, 40]", "[3, 100000]", "{}", "{a = 1}", '"x"', "[[1,2],[3]]", "-0.0", "1e30", "99999999999999999999"]


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
    for kind, base, loader in loaders():
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



def _target_in_use(path):
    """Load a target file, then use it as a session does: build and draw the OpenCV board (the audit's
    cv2.error / SystemError came from here, after the loader had accepted the file)."""
    layout = load_target(path)
    layout.charuco.board().generateImage((64, 48), marginSize=0, borderBits=1)
    return layout


def loaders():
    """``(kind, base text, loader)`` of every configuration file a user writes."""
    return (("rig", _shipped("default.toml"), load_rig), ("turntable", _shipped("turntable.toml"), load_rig),
            ("camera", CAMERA, load_camera_calibration), ("target", TARGET, _target_in_use),
            ("material", MATERIAL, load_material))
