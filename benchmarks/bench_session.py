"""Session: wall time versus simulated lab time of the default `gonio measure --sim` session, and where
the wall time of a pose goes (move, settle + darks, capture, pipeline), with a baseline row measured in
the same run (the same plan captured with a one-exposure bracket)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import Table


def _session(plan, resolution, out: Path, material=None):
    """Run ``plan`` on a fresh simulated rig (camera ``resolution`` = (w, h), ``material``: BRDF or
    material dict, default the simulator's) into a new store at ``out``: ``(RunResult, wall seconds)``."""
    from gonio.session.runner import SessionRunner, open_devices
    from gonio.session.store import SessionStore
    from sim.rig import SimRig, SimRigConfig

    w, h = resolution
    t0 = time.perf_counter()
    with SimRig(material=material, config=SimRigConfig(width=w, height=h, focal_px=380.0 * w / 320.0)) as sim:
        devices = open_devices(sim.rig, sim.servo_port, sim.controller_port, sim.camera, sim.clock)
        try:
            store = SessionStore.create(out, {"plan": plan, "mode": "bench"})
            runner = SessionRunner(plan, store, devices, sim.calibration, sim.layout, before_pose=sim.begin_pose,
                                   stream=None)
            result = runner.run()
        finally:
            devices.close()
    return result, time.perf_counter() - t0


def run(quick: bool = False) -> list[Table]:
    from dataclasses import replace

    from gonio.cli.measure import DEFAULT_PLAN, DEFAULT_PLAN_PARAMS, DEFAULT_SIM_RESOLUTION
    from gonio.plan.generators import make_plan
    from gonio.plan.plan import CaptureSettings

    params = {k: np.radians(v) for k, v in DEFAULT_PLAN_PARAMS.items()}
    if quick:
        params = {"theta_i_step": np.radians(30), "theta_o_step": np.radians(30), "theta_max": np.radians(60)}
    plan = make_plan(DEFAULT_PLAN, seed=0, **params)
    res = tuple(int(x) for x in DEFAULT_SIM_RESOLUTION.split("x"))
    configs = [
        ("1 exposure × 1 frame (baseline)", replace(plan, capture=CaptureSettings(exposures=(0.004,), frames=1)), res),
        ("default: 3 exposures × 2 frames", plan, res),
        ("default plan, 640×480 camera", plan, (640, 480)),
    ]
    if quick:
        configs = configs[:2]
    t = Table(f"session: default `gonio measure --sim` ({len(plan)} poses, plan {DEFAULT_PLAN})",
              ["configuration", "wall s (total)", "× baseline", "lab s", "lab/wall", "wall ms/pose", "samples"],
              baseline=0, default=1,
              why_default="the plan's 3-exposure bracket covers glossy peaks and the white reference without "
                          "saturation; at 320×240 the whole default session stays within a few seconds of wall time.")
    b = Table("session: wall and lab time per pose, by stage (mean over poses)",
              ["configuration", "move wall ms", "move lab s", "settle+dark wall ms", "settle+dark lab s",
               "capture wall ms", "capture lab s", "pipeline wall ms", "frames/pose"], baseline=0, default=1)
    base_wall = None
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, p, r) in enumerate(configs):
            result, wall = _session(p, r, Path(tmp) / f"s{i}")
            if base_wall is None:
                base_wall = wall
            n = max(result.measured, 1)
            t.add(label, wall, wall / base_wall, result.lab_time, result.lab_time / wall, 1e3 * wall / n,
                  result.samples)
            tm = {k: float(np.mean([x[k] for x in result.timings])) for k in result.timings[0]}
            b.add(label, 1e3 * tm["move_wall"], tm["move_lab"], 1e3 * tm["dark_wall"], tm["dark_lab"],
                  1e3 * tm["capture_wall"], tm["capture_lab"], 1e3 * tm["pipeline_wall"], tm["frames"])
    t.notes.append("wall includes starting the emulators, opening the devices (servo scan + configure, controller "
                   "handshake), dark frames and the light's warm-up (lab time only).")
    b.notes.append("move lab includes the settle time (controller.wait after the move). settle+dark: dark-frame "
                   "refresh plus the light's re-warm-up when darks are due (every 900 s of lab time); the first "
                   "darks are taken together with the initial warm-up, so a session this short shows 0 here.")
    return [t, b]
