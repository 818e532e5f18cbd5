"""sim.compile_lock: one process at a time compiles a simulator kernel; the others wait for numba's cache (a caller
that needs the kernel) or keep making the same frames with NumPy meanwhile (sim.compiled.pick); a lock left by a
killed process stops nobody."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

pytest.importorskip("numba")

from sim import compile_lock  # noqa: E402

#: a small kernel with a disk cache, beside which its lock lives (a module of the test's own: never a copy of a sim
#: source, whose cache would be written under the real file's name)
KERNEL = """
import numba
from sim.compile_lock import serialized

@serialized
@numba.njit(cache=True)
def total(x):
    s = 0.0
    for v in x:
        s += v * v
    return s
"""

#: a process that waits for ``go`` and then calls the kernel: its result and whether it compiled or read the cache
CALLER = """
import json, os, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from {mod} import total
while not os.path.exists(sys.argv[2]):
    time.sleep(0.002)
r = total(np.arange(1000.0))
print(json.dumps(dict(r=r, misses=sum(total.stats.cache_misses.values()), hits=sum(total.stats.cache_hits.values()))))
"""

#: a process that takes a lock file as a compiler would, says so, and sleeps (until it is killed)
HOLDER = """
import fcntl, sys, time
files = [open(p, "a") for p in sys.argv[1:]]
for f in files:
    fcntl.flock(f, fcntl.LOCK_EX)
print("held", flush=True)
time.sleep(120)
"""


def _env():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    return {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}


def _module(tmp_path, name):
    (tmp_path / f"{name}.py").write_text(KERNEL)
    return name


def _holder(paths):
    p = subprocess.Popen([sys.executable, "-c", HOLDER, *paths], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


def test_two_processes_compile_a_kernel_once_and_get_the_same_result(tmp_path):
    """Two processes call a kernel that no cache holds at the same moment: one compiles it (holding its lock), the
    other waits for the lock and reads the first one's machine code from the cache; the same result; no deadlock."""
    mod = _module(tmp_path, f"k{os.getpid()}a")
    go = tmp_path / "go"
    procs = [subprocess.Popen([sys.executable, "-c", CALLER.format(mod=mod), str(tmp_path), str(go)],
                              stdout=subprocess.PIPE, text=True, env=_env()) for _ in range(2)]
    time.sleep(0.5)
    go.touch()
    out = [json.loads(p.communicate(timeout=120)[0]) for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert out[0]["r"] == out[1]["r"] == float(np.sum(np.arange(1000.0) ** 2))
    assert sorted((o["misses"], o["hits"]) for o in out) == [(0, 1), (1, 0)], out  # one compiled, one read it


def test_a_lock_left_by_a_killed_process_stops_nobody(tmp_path):
    """A process holding a kernel's lock (as while compiling it) makes it busy to the others; killed, it leaves no
    lock: the kernel is not busy and compiles."""
    sys.path.insert(0, str(tmp_path))
    try:
        mod = __import__(_module(tmp_path, f"k{os.getpid()}b"))
    finally:
        sys.path.remove(str(tmp_path))
    path = compile_lock.lock_path(mod.total)
    assert os.path.dirname(path) == mod.total.stats.cache_path
    assert not compile_lock.busy([mod.total])
    holder = _holder([path])
    try:
        assert compile_lock.busy([mod.total])
    finally:
        holder.kill()
        holder.wait()
    assert not compile_lock.busy([mod.total])
    assert mod.total(np.arange(4.0)) == 14.0


def test_an_unlockable_cache_compiles_as_numba_does(tmp_path, monkeypatch):
    """A lock file that cannot be opened (an unwritable cache directory) leaves the kernel as numba makes it."""
    sys.path.insert(0, str(tmp_path))
    try:
        mod = __import__(_module(tmp_path, f"k{os.getpid()}c"))
    finally:
        sys.path.remove(str(tmp_path))
    monkeypatch.setattr(compile_lock, "lock_path", lambda k: str(tmp_path / "missing-dir-file" / "x" / "lock"))
    (tmp_path / "missing-dir-file").write_text("")  # a file where the directory would be: makedirs fails
    assert not compile_lock.busy([mod.total])
    assert mod.total(np.arange(3.0)) == 5.0


def test_frames_take_numpy_while_another_process_compiles_and_are_the_same(tmp_path, monkeypatch):
    """sim.compiled.pick: while another process holds the locks of the sensor chain's and the board's kernels (is
    compiling them), a process about to take the compiled paths for the first time makes its frames with NumPy; once
    they are released (the compiler killed), the compiled paths. The same frames either way."""
    from gonio.brdf import make
    from gonio.pipeline.target import CameraCalibration, CameraPose, TargetLayout
    from sim import camera, compiled, sensor_noise

    def frames():
        sensor = camera.SensorModel()
        calib = CameraCalibration.pinhole(64, 48, 80.0, noise=sensor.noise_model())
        cam = camera.SimCamera(calib, sensor, camera.SimScene(TargetLayout(), make("lambert", albedo=[0.6, 0.4, 0.3])),
                               seed=7)
        cam.set_pose(CameraPose.look_at([0.05, 0.02, 0.6]))
        cam.set_light([0.1, 0.2, 0.5])
        return [cam.capture(t).pixels.tobytes() for t in (0.001, 0.01)]

    funcs = (sensor_noise.expose_compiled, camera.board_points_compiled, camera.shade_board_compiled)
    kernels = [k for f in funcs for k in f.kernels()]
    # locks of the test's own (the real ones are the other tests' and processes' to take)
    monkeypatch.setattr(compile_lock, "lock_path", lambda k: str(tmp_path / f"{k.py_func.__name__}.lock"))
    monkeypatch.setattr(compiled, "use_compiled", lambda: True)
    monkeypatch.setattr(compiled, "_STARTED", set())
    took = []
    pick = compiled.pick

    def recorded(c, r):
        f = pick(c, r)
        took.append(f is c)
        return f

    monkeypatch.setattr(compiled, "pick", recorded)

    holder = _holder([compile_lock.lock_path(k) for k in kernels])
    try:
        meanwhile = frames()
        assert took and not any(took), "the NumPy paths while the kernels are being compiled elsewhere"
    finally:
        holder.kill()
        holder.wait()
    took.clear()
    after = frames()
    assert took and all(took), "the compiled paths once nobody compiles them"
    assert meanwhile == after
