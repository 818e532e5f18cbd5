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
    from gonio.store.directory import SessionStore
    from sim.rig import SimRig, SimRigConfig

    w, h = resolution
    t0 = time.perf_counter()
    with SimRig(material=material, config=SimRigConfig.at_resolution(w, h)) as sim:
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

    from gonio.cli.measure import DEFAULT_SIM_RESOLUTION
    from gonio.plan.plan import CaptureSettings

    plan = _default_plan(quick)
    res = tuple(int(x) for x in DEFAULT_SIM_RESOLUTION.split("x"))
    configs = [
        ("1 exposure × 1 frame (baseline)", replace(plan, capture=CaptureSettings(exposures=(0.004,), frames=1,
                                                                                  auto_exposure=False)), res),
        ("default: automatic exposure", plan, res),
        ("default plan, 640×480 camera", plan, (640, 480)),
    ]
    if quick:
        configs = configs[:2]
    t = Table(f"session: default `gonio measure --sim` ({len(plan)} poses, plan {plan.generator})",
              ["configuration", "wall s (total)", "× baseline", "lab s", "lab/wall", "wall ms/pose", "samples"],
              baseline=0, default=1,
              why_default="automatic exposure keeps glossy peaks and the white reference in range (see the exposure "
                          "table); at 320×240 the whole default session stays within a few seconds of wall time.")
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
    return [exposure_table(quick), t, b, adaptive_table(quick)]


def _flag_stats(samples, brdf):
    """flagged %, saturated %, low-signal %, usable samples, median σ/f and median relative error of the
    unflagged samples against the true BRDF."""
    from gonio import samples as S

    ok = samples.flags == 0
    f_true = brdf.eval(samples.wi[ok], samples.wo[ok])
    rel = np.abs(samples.f[ok] - f_true) / np.maximum(np.abs(f_true), 1e-12)
    sf = samples.sigma[ok] / np.maximum(np.abs(samples.f[ok]), 1e-12)
    pct = 100.0 / max(len(samples), 1)
    return (pct * np.count_nonzero(~ok), pct * np.count_nonzero(samples.flags & S.SATURATED),
            pct * np.count_nonzero(samples.flags & S.LOW_SIGNAL), int(ok.sum()),
            float(np.median(sf)) if sf.size else float("nan"), float(np.median(rel)) if rel.size else float("nan"))


def exposure_table(quick: bool = False) -> Table:
    """Automatic exposure (the default) against the old fixed bracket: flagged samples, lab time and the
    cost model's estimate / lower bound of the same plan, on the simulator's default material and on a
    glossy two-lobe material (narrow lobe: the case the fixed bracket saturates)."""
    from dataclasses import replace

    from benchmarks.bench_tradeoffs import MATERIAL as TWO_LOBES
    from gonio.brdf import make
    from gonio.cli.measure import DEFAULT_SIM_RESOLUTION
    from gonio.plan import estimate_plan
    from gonio.store.directory import load_session
    from sim.rig import DEFAULT_MATERIAL

    plan = _default_plan(quick)  # its capture is the default: automatic exposure
    res = tuple(int(x) for x in DEFAULT_SIM_RESOLUTION.split("x"))
    fixed = replace(plan, capture=replace(plan.capture, auto_exposure=False))  # the expected bracket, fixed
    materials = [("sim default (microfacet GGX α 0.25)", DEFAULT_MATERIAL), ("lambert+2ggx, narrow lobe α 0.1", TWO_LOBES)]
    if quick:
        materials = materials[1:]
    t = Table(f"exposure control: automatic (default) vs the fixed bracket, `gonio measure --sim` plan ({len(plan)} "
              f"poses {plan.generator})",
              ["material", "exposure", "flagged %", "saturated %", "low signal %", "usable samples", "median σ/f",
               "median rel err", "lab s", "lab vs fixed", "lab s (poses)", "frames/pose", "estimate s",
               "lower bound s"], baseline=0, default=1,
              why_default="automatic exposure: no sample lost to saturation on a glossy lobe for about the same lab "
                          "time; the fixed bracket flags the peak's samples.")
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, material) in enumerate(materials):
            brdf = make(material["model"], **material["params"])
            lab_fixed = None
            for j, (how, p) in enumerate((("fixed 4/16/64 ms × 2", fixed),
                                          ("auto (default; expected 4/16/64 ms × 2)", plan))):
                result, _ = _session(p, res, Path(tmp) / f"e{i}{j}", material=material)
                samples = load_session(Path(tmp) / f"e{i}{j}")[1]
                est = estimate_plan(p)
                lab_fixed = lab_fixed or result.lab_time
                poses_lab = sum(x["move_lab"] + x["dark_lab"] + x["capture_lab"] for x in result.timings)
                frames = float(np.mean([x["frames"] for x in result.timings]))
                t.add(label, how, *_flag_stats(samples, brdf), result.lab_time, result.lab_time / lab_fixed,
                      poses_lab, frames, est.optimized, est.lower_bound)
    t.notes.append("Rows of a material: the fixed bracket first (its baseline). flagged: any flag (saturated in every "
                   "exposure, low signal, no board, ...); errors over unflagged samples against the true BRDF at "
                   "their directions. lab s: the whole session (darks of every exposure used, warm-up, poses); "
                   "estimate / lower bound: gonio.plan.estimate_plan (the runner's cost model, gonio.plan.labtime; "
                   "auto: the expected bracket 4/16/64 ms × 2). frames/pose includes the metering frame.")
    return t


def _default_plan(quick: bool):
    """`gonio measure --sim`'s default plan (quick: a 12-pose in-plane sweep)."""
    from gonio.cli.measure import DEFAULT_PLAN, default_plan_params
    from gonio.plan.generators import make_plan

    if quick:
        return make_plan("in_plane", seed=0, theta_i_step=np.radians(30), theta_o_step=np.radians(30),
                         theta_max=np.radians(60))
    return make_plan(DEFAULT_PLAN, seed=0, **default_plan_params(DEFAULT_PLAN))


def _adaptive_session(candidates, settings, fit, resolution, out: Path, material=None):
    """An adaptive session (gonio.session.adaptive) on a fresh simulated rig: ``(result, wall s, samples)``."""
    from gonio.session.adaptive import AdaptiveSession, new_adaptive_manifest
    from gonio.session.runner import open_devices
    from gonio.store.directory import SessionStore, load_session
    from sim.rig import SimRig, SimRigConfig

    w, h = resolution
    t0 = time.perf_counter()
    with SimRig(material=material, config=SimRigConfig.at_resolution(w, h)) as sim:
        store = SessionStore.create(out, {**new_adaptive_manifest(candidates, settings, fit, sim.rig), "mode": "bench"})
        devices = open_devices(sim.rig, sim.servo_port, sim.controller_port, sim.camera, sim.clock)
        try:
            result = AdaptiveSession(store, devices, sim.calibration, sim.layout, before_pose=sim.begin_pose,
                                     stream=None).run()
        finally:
            devices.close()
    return result, time.perf_counter() - t0, load_session(out)[1]


def adaptive_table(quick: bool = False) -> Table:
    """An adaptive session against a uniform plan of about the same lab time: lab time and BRDF error of
    the fitted model against the simulated material on a fixed dense set of directions."""
    from dataclasses import replace

    from benchmarks.bench_tradeoffs import MATERIAL as TWO_LOBES, THETA_MAX_DEG, eval_directions
    from gonio.brdf import make
    from gonio.cli.measure import DEFAULT_SIM_RESOLUTION
    from gonio.plan.adaptive import AdaptiveSettings, _farthest_points, _features, relative_rms
    from gonio.plan.generators import make_plan
    from gonio.plan.ordering import MotionModel, optimize_order
    from gonio.rig.kinematics import load_rig
    from gonio.session.adaptive import FitSpec
    from gonio.session.runner import RunnerSettings
    from gonio.store.directory import load_session
    from sim.rig import DEFAULT_MATERIAL

    rig = load_rig()
    res = tuple(int(x) for x in DEFAULT_SIM_RESOLUTION.split("x"))
    cand = make_plan("isotropic", rig=rig, order="raster", theta_step=np.radians(10), phi_step=np.radians(30),
                     theta_max=np.radians(THETA_MAX_DEG))
    wi, wo = eval_directions()
    cases = [("sim default (microfacet)", DEFAULT_MATERIAL, "microfacet", 120.0)]
    if not quick:
        cases.append(("two GGX lobes, fitted microfacet", TWO_LOBES, "microfacet", 240.0))
    t = Table(f"adaptive session vs a uniform plan of about the same lab time ({len(cand)} isotropic candidates "
              f"10°/30°, θ ≤ {THETA_MAX_DEG:g}°, simulated sessions)",
              ["material", "plan", "poses", "rounds", "lab s (all)", "lab s (poses)", "wall s",
               "BRDF rel RMS err", "err vs uniform"], baseline=0)
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, material, model, budget) in enumerate(cases):
            truth = make(material["model"], **material["params"])
            f_true = truth.eval(wi, wo)
            spec = FitSpec(model, n_starts=3)
            settings = AdaptiveSettings(n_initial=16, batch=8, target_error=0.0, lab_budget=budget, seed=0,
                                        round_overhead=RunnerSettings().timing.warmup_step)
            ar, a_wall, a_s = _adaptive_session(cand, settings, spec, res, Path(tmp) / f"a{i}", material)
            n = sum(r["n_poses"] for r in ar.rounds)
            # uniform: the same number of candidates spread by farthest-point sampling, ordered for lab time
            sel = _farthest_points(_features(cand.poses), n, np.random.default_rng(0))
            sel = sel[optimize_order(cand.joints[sel], MotionModel.from_rig(rig))]
            uplan = replace(cand, poses=cand.poses[sel], joints=cand.joints[sel], generator="uniform", order="optimized")
            ur, u_wall = _session(uplan, res, Path(tmp) / f"u{i}", material=material)
            u_s = load_session(Path(tmp) / f"u{i}")[1]
            errs = []
            for s in (u_s, a_s):
                errs.append(relative_rms(spec.callable()(s).eval(wi, wo), f_true))
            pose_lab = [sum(x["move_lab"] + x["dark_lab"] + x["capture_lab"] for x in r.timings) for r in (ur, ar)]
            t.add(label, "uniform (farthest point, same poses count)", len(uplan), 1, ur.lab_time, pose_lab[0], u_wall,
                  errs[0], 1.0)
            t.add(label, f"adaptive (budget {budget:g} s, fit {model})", n, len(ar.rounds), ar.lab_time, pose_lab[1],
                  a_wall, errs[1], errs[1] / errs[0])
    t.notes.append("BRDF error: the model fitted to all of a session's samples (gonio.fit, n_starts=3) against the "
                   "simulated material, relative RMS over 20,000 fixed random direction pairs (θ ≤ "
                   f"{THETA_MAX_DEG:g}°). Adaptive: coarse round 16, 8 poses a round, target error 0 so it runs to the "
                   "budget (the planner's account: moves + settle + capture + 15 s light check a round). 'lab s (all)' "
                   "includes the session start (darks, warm-up) and the adaptive session's per-round light check; "
                   "'lab s (poses)' only moves, settle, darks and capture. Rows of a material: uniform first, its "
                   "baseline. Wall time of the adaptive session includes its fits.")
    return t
