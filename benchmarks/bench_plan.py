"""Lab time of a plan's order: optimized (nearest neighbour + 2-opt/Or-opt) vs the raster order moving
one axis at a time (baseline) vs the MST lower bound, for the default plans on the default rig."""

from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.common import Table


def run(quick: bool = False) -> list[Table]:
    from gonio.plan import GENERATORS, make_plan
    from gonio.plan.ordering import (
        MotionModel, mst_move_time, nearest_neighbour_order, optimize_order, path_move_time, raster_order,
    )
    from gonio.rig.kinematics import load_rig

    rig = load_rig()
    model = MotionModel.from_rig(rig)
    coarse = {"grid": {"theta_step": math.radians(25), "phi_step": math.radians(60)},
              "isotropic": {"theta_step": math.radians(20), "phi_step": math.radians(30)},
              "in_plane": {}, "half_diff": {"n_theta_h": 8}}
    tables = []
    for name in GENERATORS:
        params = coarse[name] if quick else {}
        plan = make_plan(name, rig=rig, order="raster", **params)
        poses, q = plan.poses, plan.joints
        fixed = len(plan) * plan.capture.pose_time()
        raster = raster_order(poses)
        t0 = time.perf_counter()
        nn = nearest_neighbour_order(q, model)
        t_nn = time.perf_counter() - t0
        t0 = time.perf_counter()
        opt = optimize_order(q, model, time_budget=2.0, initial=raster)
        t_opt = time.perf_counter() - t0
        t0 = time.perf_counter()
        mst = mst_move_time(q, model)
        t_mst = time.perf_counter() - t0
        rows = [
            ("raster, one axis at a time", fixed + path_move_time(q, raster, model, sequential=True), 0.0),
            ("raster, joints together", fixed + path_move_time(q, raster, model), 0.0),
            ("nearest neighbour", fixed + path_move_time(q, nn, model), t_nn),
            ("optimized (NN + 2-opt/Or-opt, 2 s budget)", fixed + path_move_time(q, opt, model), t_opt),
            ("lower bound: N*pose time + MST", fixed + mst, t_mst),
        ]
        base = rows[0][1]
        t = Table(f"plan {name} ({len(plan)} poses, {plan.n_dropped} dropped; "
                  f"{plan.capture.pose_time():.3f} s settle+capture per pose)",
                  ["order", "lab time (s)", "moves (s)", "vs raster", "vs bound", "moves vs MST", "compute (s)"],
                  baseline=0, default=3,
                  why_default="what `gonio plan` and `gonio measure` use; within a few % of the bound")
        for label, lab, secs in rows:
            t.add(label, lab, lab - fixed, lab / base, lab / rows[-1][1], (lab - fixed) / mst, secs)
        t.notes.append("moves: slowest joint's trapezoidal profile (joints concurrent) except the baseline row, "
                       "which sums the joints' times; the MST bound holds for every order (a visiting order "
                       "is a spanning path).")
        tables.append(t)
    return tables
