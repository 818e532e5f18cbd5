"""Simulator speed: simulated lab time per second of wall time of whole `gonio measure --sim` sessions, on the
default plan and on dense plans, for this tree and for a baseline revision of the code, in the same run.

Each session runs in a fresh Python process (imports, the emulators' start-up and the devices' opening
included, as a user sees it) with one BLAS thread; the baseline's process runs the same script on the
files of the baseline revision (``git archive``), so the ratio is measured on the same machine at the same
load. CPU seconds (every thread of the process, user + system) are given besides wall seconds: on a shared
machine they move less with the load than wall time does. Both trees must measure the same samples
(the simulator's seeding, sim/seeding.py): the table says whether they did.

The simulator's own speed-up is the ratio of wall times of the same plan (the speed-up column); × real time
also moves with the session's lab time, which later work on the session's timing (warm-up, darks) changes:
the notes say when the two trees' lab times differ, and give the dense plans' × real time against issue 17's
goal.

``GONIO_BENCH_BASELINE=<rev>`` picks the baseline (default :data:`BASELINE_REV`, the code before the
simulator speed-ups of issue 17); ``GONIO_BENCH_BASELINE=none`` skips it.
"""

from __future__ import annotations

import json
import os
import subprocess
from gonio import childproc  # children die with this process
import sys
import tempfile
from pathlib import Path

from benchmarks.common import Table

#: The revision measured as the baseline: main before the simulator speed-ups (issue 17).
BASELINE_REV = "3cc1a9f"

_ROOT = Path(__file__).resolve().parent.parent

#: Issue 17's goal: simulated lab time per wall second on dense plans.
GOAL_X_REAL_TIME = 200.0

#: (label, generator, parameters in degrees); the first is `gonio measure --sim`'s default plan.
PLANS = [
    ("default (half_diff)", "half_diff", {}),
    ("dense: isotropic 10°/30°", "isotropic", {"theta_step": 10, "phi_step": 30}),
    ("dense: isotropic 10°/15°", "isotropic", {"theta_step": 10, "phi_step": 15}),
]

# Runs in a child process, with only the APIs both trees have: prints one JSON line.
_CHILD = r"""
import json, sys, time, hashlib
from pathlib import Path
import numpy as np
gen, params, out = sys.argv[1], json.loads(sys.argv[2]), Path(sys.argv[3])
from sim.firmware import build_library
build_library()  # a first build of the host firmware is not the simulator's speed
t_import = time.perf_counter()
from gonio.cli.measure import DEFAULT_SIM_RESOLUTION, default_plan_params
from gonio.plan.generators import make_plan
from gonio.session.runner import SessionRunner, open_devices
from gonio.store.directory import SessionStore, load_session
from sim.rig import SimRig, SimRigConfig
kw = default_plan_params(gen)
kw.update({k: np.radians(v) for k, v in params.items()})
plan = make_plan(gen, seed=0, **kw)
w, h = (int(x) for x in DEFAULT_SIM_RESOLUTION.split("x"))
import gonio.pipeline.acquire as acquire
search = [0.0]  # wall seconds in the ChArUco board search (both trees call it through this module)
if hasattr(acquire, "detect_board_pose"):
    _detect = acquire.detect_board_pose
    def _timed(*a, **k):
        t = time.perf_counter()
        try:
            return _detect(*a, **k)
        finally:
            search[0] += time.perf_counter() - t
    acquire.detect_board_pose = _timed
c0, t0 = time.process_time(), time.perf_counter()
with SimRig(config=SimRigConfig.at_resolution(w, h)) as sim:
    devices = open_devices(sim.rig, sim.servo_port, sim.controller_port, sim.camera, sim.clock)
    try:
        store = SessionStore.create(out, {"plan": plan, "mode": "bench"})
        result = SessionRunner(plan, store, devices, sim.calibration, sim.layout, before_pose=sim.begin_pose,
                               stream=None).run()
    finally:
        devices.close()
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
s = load_session(out)[1]
digest = hashlib.sha256(b"".join(np.ascontiguousarray(getattr(s, k)).tobytes()
                                 for k in ("f", "sigma", "wi", "wo", "flags"))).hexdigest()
frames = sum(t.get("frames", 0) for t in getattr(result, "timings", []) or [])
camera = sum(t.get("capture_wall", 0.0) for t in getattr(result, "timings", []) or [])
print(json.dumps({"poses": len(plan), "lab": result.lab_time, "wall": wall, "cpu": cpu, "samples": len(s),
                  "digest": digest, "retries": getattr(result, "retries", 0), "frames": frames,
                  "camera": camera, "search": search[0]}))
"""


def _tree(rev: str, into: Path) -> Path | None:
    """The files of revision ``rev`` of this repository extracted into ``into`` (None without git or the rev)."""
    try:
        into.mkdir(parents=True, exist_ok=True)
        archive = childproc.run(["git", "-C", str(_ROOT), "archive", "--format=tar", rev], capture_output=True,
                                 check=True).stdout
        childproc.run(["tar", "-x", "-C", str(into)], input=archive, check=True, capture_output=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return into


def _run(tree: Path, gen: str, params: dict, out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    r = childproc.run([sys.executable, "-c", _CHILD, gen, json.dumps(params), str(out)], cwd=str(tree), env=env,
                       capture_output=True, text=True)
    if r.returncode:
        raise RuntimeError(f"session in {tree} failed: {(r.stderr or r.stdout).strip().splitlines()[-1:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def run(quick: bool = False) -> list[Table]:
    rev = os.environ.get("GONIO_BENCH_BASELINE", BASELINE_REV)
    plans = PLANS[:2] if quick else PLANS
    t = Table("simulator speed: simulated lab time / wall time of whole `gonio measure --sim` sessions, this tree vs "
              f"baseline {rev}",
              ["plan", "poses", "code", "lab s", "wall s", "CPU s", "lab/wall (× real time)", "wall ms/pose",
               "camera frames/pose", "frames s", "board search s",
               "speed-up vs baseline (wall/pose)", "CPU vs baseline", "× real time vs baseline", "pose retries",
               "same samples as baseline"],
              baseline=0 if rev != "none" else None)
    with tempfile.TemporaryDirectory() as tmp:
        base = None if rev == "none" else _tree(rev, Path(tmp) / "baseline")
        if rev != "none" and base is None:
            t.notes.append(f"baseline {rev}: not measured (no git checkout or unknown revision)")
        dense, lab_changed = [], []
        for i, (label, gen, params) in enumerate(plans):
            ref = _run(base, gen, params, Path(tmp) / f"b{i}") if base is not None else None
            now = _run(_ROOT, gen, params, Path(tmp) / f"n{i}")
            if label.startswith("dense"):
                both = now.get("camera", 0.0) + now.get("search", 0.0)
                dense.append((label, now["lab"] / now["wall"], ref["lab"] / ref["wall"] if ref else None,
                              now["lab"] / both if both > 0 else None, 2 * now["lab"] / now["cpu"]))
            for code, r in ((f"baseline {rev}", ref), ("this tree", now)):
                if r is None:
                    continue
                speed = r["lab"] / r["wall"]
                t.add(label, r["poses"], code, r["lab"], r["wall"], r["cpu"], speed, 1e3 * r["wall"] / r["poses"],
                      r.get("frames", 0) / r["poses"] if r.get("frames") else float("nan"),
                      r.get("camera") or float("nan"), r.get("search") or float("nan"),
                      ref["wall"] / r["wall"] if ref else float("nan"),
                      r["cpu"] / ref["cpu"] if ref else float("nan"),
                      speed / (ref["lab"] / ref["wall"]) if ref else float("nan"), r["retries"],
                      "—" if r is ref or ref is None else ("yes" if r["digest"] == ref["digest"] else "NO"))
                if ref is not None and r is now and abs(now["lab"] - ref["lab"]) > 1e-6 * ref["lab"]:
                    lab_changed.append(f"{label}: {ref['lab']:.0f} → {now['lab']:.0f} s")
    if lab_changed:
        t.notes.append("the sessions' lab time differs from the baseline's (" + "; ".join(lab_changed) + "): the "
                       "session's own timing changed (light warm-up, dark frames), not the simulator, so × real time "
                       "moves with it; the simulator's own speed-up is the wall time of the same plan's poses "
                       "(speed-up column), and the samples differ with the timing (the light's drift)")
    for label, speed, ref_speed, floor, two in dense:
        t.notes.append(f"{label}: this tree {speed:.0f}× real time"
                       + (f", baseline {ref_speed:.0f}× ({speed / ref_speed:.2f}×)" if ref_speed else "")
                       + f"; issue 17's goal ≥ {GOAL_X_REAL_TIME:.0f}×: {'met' if speed >= GOAL_X_REAL_TIME else 'not met'}"
                       + (f"; the simulated camera's frames and the board searches alone allow {floor:.0f}× on one "
                          "core" if floor else "")
                       + f"; this tree's whole CPU time split perfectly over two cores would give {two:.0f}×")
    t.notes.append("wall and CPU: from the emulators' start to the end of the session (opening the devices, darks, "
                   "warm-up, every pose, the store's writes), not the interpreter's start-up; CPU counts every "
                   "thread of the process (host code and emulators). Camera frames per pose: the poses' frames (metering, "
                   "re-metering and bracket; not the dark sets), each one capture and one photodiode reading. Frames s: wall time in "
                   "the camera's capture for those frames (the simulator renders and adds the sensor's noise); board "
                   "search s: in the host's ChArUco search (OpenCV). Neither can be skipped (each frame is a different "
                   "exposure or pose; the board is searched once per camera position), so lab time over their sum "
                   "bounds × real time however cheap the rest becomes. Same samples: SHA-256 of the samples' "
                   "f, σ, wi, wo and flags. A pose retried after a transient real-time timeout (a loaded machine) "
                   "changes the lab time and the samples of both trees alike.")
    return [t]
