"""A child process never outlives its parent (gonio.childproc): the parent is killed with SIGKILL — no
``finally``, no ``atexit`` — and its child must be gone within a few seconds. Checked for a plain child, the
simavr bridge (which kept running at a full core before) and a batch's worker processes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for its reaper is not running)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def _kill_parent_and_watch(script: str, tmp_path, n_children: int = 1) -> list[int]:
    """Run ``script`` in a parent process; it (or they) print the children's pids, one per line. Kill the
    parent with SIGKILL; return the pids still running 5 s later."""
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{tmp_path}"}
    parent = subprocess.Popen([sys.executable, "-c", textwrap.dedent(script)], stdout=subprocess.PIPE, text=True,
                              env=env, cwd=tmp_path)
    pids = []
    try:
        for _ in range(n_children):
            line = parent.stdout.readline().strip()
            if not line:
                break
            pids.append(int(line))
        assert len(pids) == n_children and all(_alive(p) for p in pids), pids
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        parent.stdout.close()
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.05)
    left = [p for p in pids if _alive(p)]
    for p in left:  # do not leave them running if the test fails
        os.kill(p, signal.SIGKILL)
    return left


def test_a_child_dies_with_its_parent(tmp_path):
    assert _kill_parent_and_watch("""
        from gonio import childproc
        p = childproc.popen(["sleep", "120"])
        print(p.pid, flush=True)
        import time; time.sleep(120)
    """, tmp_path) == []


def test_a_child_of_plain_popen_would_outlive_it(tmp_path):
    """The control: without gonio.childproc the same child survives its parent (so the test above can fail)."""
    left = _kill_parent_and_watch("""
        import subprocess
        p = subprocess.Popen(["sleep", "120"])
        print(p.pid, flush=True)
        import time; time.sleep(120)
    """, tmp_path)
    assert len(left) == 1


def test_the_simavr_bridge_dies_with_its_parent(tmp_path):
    from sim.simavr import DEBIAN_PACKAGES
    from tests.debian import require

    require("the firmware's AVR build in simavr", *DEBIAN_PACKAGES)
    assert _kill_parent_and_watch("""
        from sim.simavr import SimavrController
        s = SimavrController().start()
        print(s.proc.pid, flush=True)
        import time; time.sleep(120)
    """, tmp_path) == []


def test_batch_workers_die_with_their_parent(tmp_path):
    (tmp_path / "slowjob.py").write_text(textwrap.dedent("""
        import os, time
        def job(source, options):
            with open(f"pid-{source}.tmp", "w") as f:
                f.write(str(os.getpid()))
            os.rename(f"pid-{source}.tmp", f"pid-{source}")
            time.sleep(120)
            return {"status": "ok"}
    """))
    assert _kill_parent_and_watch("""
        import os, threading, time
        from gonio.batch import run_batch
        import slowjob
        threading.Thread(target=run_batch, args=(slowjob.job, ["a", "b"], {}), kwargs={"jobs": 2}, daemon=True).start()
        while not (os.path.exists("pid-a") and os.path.exists("pid-b")):
            time.sleep(0.05)
        print(open("pid-a").read(), flush=True)
        print(open("pid-b").read(), flush=True)
        time.sleep(120)
    """, tmp_path, n_children=2) == []
