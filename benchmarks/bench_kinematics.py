"""Rig layouts: inverse-kinematics cost (vectorized solve of many poses) and the lab time of the same
plans on the "arms" rig (default) and the "turntable" rig (sample turntable + light elevation only)."""

from __future__ import annotations

import math

import numpy as np

from benchmarks.common import Table, time_call


def run(quick: bool = False) -> list[Table]:
    from gonio.plan import estimate_plan, make_plan
    from gonio.rig.kinematics import load_rig

    rigs = {"arms": load_rig("default"), "turntable": load_rig("turntable")}
    n = 2_000 if quick else 20_000
    rng = np.random.default_rng(0)
    ti, to = rng.uniform(0, math.radians(80), (2, n))
    pi_, po = rng.uniform(0, 2 * math.pi, (2, n))

    solve = Table(f"inverse kinematics: solve_many of {n} random poses (from the zero pose)",
                  ["rig", "isotropic", "time (ms)", "us / pose", "vs arms", "reachable"], baseline=0, default=0,
                  why_default="the default rig file's layout; the turntable couples its joints (16 candidate "
                              "joint vectors per pose, searched together, instead of two independent arms)")
    base = None
    for iso in (False, True):
        for name, rig in rigs.items():
            secs = time_call(lambda: rig.solve_many(ti, pi_, to, po, isotropic=iso), min_time=0.1 if quick else 0.3)
            _, code = rig.solve_many(ti, pi_, to, po, isotropic=iso)
            base = secs if base is None else base
            solve.add(name, str(iso), secs * 1e3, secs / n * 1e6, secs / base, float(np.mean(code == 0)))

    plans = Table("lab time of the same plans, optimized order, on each rig layout",
                  ["plan", "rig", "poses", "dropped", "lab time (s)", "moves (s)", "vs arms"], baseline=0, default=0,
                  why_default="the default rig")
    specs = {"grid": {"theta_step": math.radians(30 if quick else 20), "phi_step": math.radians(90 if quick else 45)},
             "isotropic": {"theta_step": math.radians(20 if quick else 10), "phi_step": math.radians(30 if quick else 15)}}
    for pname, params in specs.items():
        ref = None
        for name, rig in rigs.items():
            plan = make_plan(pname, rig=rig, **params)
            est = estimate_plan(plan, rig)
            fixed = len(plan) * plan.capture.pose_time()
            ref = est.optimized if ref is None else ref
            plans.add(pname, name, len(plan), plan.n_dropped, est.optimized, est.optimized - fixed,
                      est.optimized / ref)
    plans.notes.append("isotropic plans have φi = 0: on the turntable rig the turntable stays still and the camera "
                       "azimuth sweeps φo; grid plans turn the turntable for each φi.")
    return [solve, plans]
