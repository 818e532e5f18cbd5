"""Measure, watch, resume, fit and export from Python — a notebook in script form (each ``# %%`` is a cell).

Runs on the simulated rig as it stands (``python docs/examples/measure_from_python.py [DIR]``; the test suite runs
it: tests/session/test_session_api.py). On a rig, replace the ``open_rig`` call by the rig's files and ports::

    gonio.open_rig("my-rig.toml", hardware=gonio.HardwareOptions(servo_port="/dev/ttyUSB0",
                   controller_port="/dev/ttyACM0", camera="0", calibration="camera.toml"))
"""

# %% Open the rig and measure, watching every pose as it is stored
import sys
from pathlib import Path

import numpy as np

import gonio

out = Path(sys.argv[1] if len(sys.argv) > 1 else "example-session")
lab, values = [], []
stop_after = 6  # poses: the first run stops there, as Ctrl-C would


def watch(event):
    """Called after each stored pose: keep what a live plot would show; returning False stops the session."""
    lab.append(event.lab_time)
    values.append(float(np.median(event.samples.f[:, 1])))  # green BRDF of the pose's tiles, 1/sr
    return stop_after is None or event.done < stop_after


with gonio.open_rig(sim=gonio.SimOptions(seed=3)) as rig:
    run = gonio.measure(rig, "half_diff", out, on_pose=watch, progress=None)
print(f"{run.status}: {run.poses_done}/{run.poses_total} poses, {len(lab)} events, lab time {lab[-1]:.0f} s")

# %% Resume: the simulated rig is rebuilt from the manifest, only the poses left are measured
stop_after = None
run = gonio.resume(out, on_pose=watch, progress=None)
print(f"{run.status}: {run.poses_done}/{run.poses_total} poses, {run.samples_total} samples, "
      f"green BRDF {min(values):.3f}..{max(values):.3f} 1/sr over {len(values)} poses")
assert run.ok and run.poses_done == run.poses_total

# %% Fit, look, export
fit = gonio.fit(run.load(), "microfacet")
print(fit)
gonio.to_mitsuba(fit, out.with_suffix(".xml"), approx=True)
print(f"wrote {out.with_suffix('.xml')}")
