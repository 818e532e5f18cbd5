"""SIGTERM (kill, timeout(1), a service manager) stops a session the way Ctrl-C does: the pose in flight
is finished, the light switched off, the run recorded as interrupted with its resume command. Before, the
default SIGTERM killed the process: no 'interrupted' in the manifest ('none (still running, or killed)'),
no resume line, and on the lab bench the light stayed on until the controller's watchdog (found by QA,
qa-lab)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_sigterm_finishes_the_pose_in_flight_and_records_an_interrupted_run(tmp_path):
    d = tmp_path / "s"
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    # 156 poses: many more than the two measured before the signal (a plan of thousands only costs the child its
    # planning, ~2 CPU s, and proves nothing more)
    proc = subprocess.Popen([sys.executable, "-m", "gonio.cli.main", "measure", "--sim", "--plan", "grid",
                             "--theta-step", "30", "--phi-step", "60", "--out", str(d)], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 600  # a guard against a hung process only: a loaded machine may need minutes
    while proc.poll() is None and time.monotonic() < deadline:
        try:
            if (d / "samples.jsonl").read_bytes().count(b"\n") >= 2:
                break
        except FileNotFoundError:
            pass
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=300)  # the pose in flight is finished first (minutes on a loaded machine)
    err = err.decode()
    assert proc.returncode == 130, err
    assert f"gonio resume {d}" in err and "Traceback" not in err, err
    manifest = json.loads((d / "manifest.json").read_text())
    assert manifest["exit_status"] == "interrupted"
    assert 2 <= manifest["pose_count"] < len(manifest["plan"]["poses"])
