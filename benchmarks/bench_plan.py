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
        opt = optimize_order(q, model, initial=raster)
        t_opt = time.perf_counter() - t0
        t0 = time.perf_counter()
        mst = mst_move_time(q, model)
        t_mst = time.perf_counter() - t0
        rows = [
            ("raster, one axis at a time", fixed + path_move_time(q, raster, model, sequential=True), 0.0),
            ("raster, joints together", fixed + path_move_time(q, raster, model), 0.0),
            ("nearest neighbour", fixed + path_move_time(q, nn, model), t_nn),
            ("optimized (NN + 2-opt/Or-opt)", fixed + path_move_time(q, opt, model), t_opt),
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
    tables.append(_scaling_table(model, quick))
    tables.append(_adaptive_table(rig, model, quick))
    return tables


def _scaling_table(model, quick: bool) -> Table:
    """Planning growth: k-d tree nearest-neighbour tour and Borůvka MST vs the dense O(N²) references
    (the previous implementation, kept as ``_..._dense``), on uniformly spread joint vectors."""
    from gonio.plan import ordering as o

    sizes = [300, 3000] if quick else [1000, 10000]
    rng = np.random.default_rng(0)
    t = Table("planning growth: k-d tree vs dense (random poses over ±1.5 rad per joint)",
              ["step", "poses", "dense (s)", "k-d tree (s)", "speed-up", "tree time vs 10x fewer poses",
               "same result"], baseline=None)
    prev: dict = {}
    for n in sizes:
        q = rng.uniform(-1.5, 1.5, (n, 4))
        for label, fast, dense in (
                ("nearest-neighbour tour", lambda: o.nearest_neighbour_order(q, model),
                 lambda: o._nearest_neighbour_order_dense(q, model)),
                ("MST lower bound", lambda: o.mst_move_time(q, model), lambda: o._mst_move_time_dense(q, model))):
            t0 = time.perf_counter()
            a = fast()
            t1 = time.perf_counter()
            b = dense()
            t2 = time.perf_counter()
            same = bool(np.array_equal(a, b)) if isinstance(a, np.ndarray) else abs(a - b) <= 1e-12 * abs(b)
            growth = (t1 - t0) / prev[label] if label in prev else float("nan")
            prev[label] = t1 - t0
            t.add(label, n, t2 - t1, t1 - t0, (t2 - t1) / (t1 - t0), growth, same)
    t.notes.append("goal: <= 15x the time for 10x the poses (n log n). The 2-opt/Or-opt local search of "
                   "optimize_order is not covered here: it still grows faster than n log n on large random "
                   "sets (long 2-opt reversals), known open work.")
    return t


def _adaptive_table(rig, model, quick: bool) -> Table:
    """Error versus lab time: adaptive plans vs uniform (farthest-point) plans of the same lab time."""
    from gonio.brdf import make
    from gonio.geometry import dirs_from_angles
    from gonio.plan import make_plan
    from gonio.plan.adaptive import _farthest_points, _features, adaptive_plan, fit_model, relative_rms
    from gonio.plan.ordering import optimize_order, path_move_time
    from gonio.samples import SampleSet

    cand = make_plan("isotropic", rig=rig, order="raster", theta_step=math.radians(10),
                     phi_step=math.radians(30), theta_max=math.radians(70))
    truth = make("lambert+2ggx", **{"diffuse.albedo": [0.25, 0.2, 0.15], "lobe1.ks": 0.3, "lobe1.alpha": 0.3,
                                     "lobe2.ks": 0.5, "lobe2.alpha": 0.05})
    fit = fit_model("lambert+2ggx", n_starts=4)
    wi_all, wo_all = dirs_from_angles(*cand.poses.T)
    f_all = truth.eval(wi_all, wo_all)
    rng = np.random.default_rng(0)

    def measure(poses):
        wi, wo = dirs_from_angles(*poses.T)
        f = truth.eval(wi, wo)
        sig = 0.01 * f + 1e-4
        return SampleSet(wi, wo, f + rng.normal(size=f.shape) * sig, sig)

    pose_time = cand.capture.pose_time()
    fps = _farthest_points(_features(cand.poses), len(cand), np.random.default_rng(1))

    def uniform(budget):
        n = max(1, int(budget / pose_time))
        while n > 1:
            sel = fps[:n]
            o = optimize_order(cand.joints[sel], model)
            lab = path_move_time(cand.joints[sel], o, model) + n * pose_time
            if lab <= budget:
                break
            n = int(n * budget / lab) if lab > 1.05 * budget else n - 1
        m = fit(measure(cand.poses[fps[:n]]))
        return n, lab, relative_rms(m.eval(wi_all, wo_all), f_all)

    t = Table(f"error vs lab time: adaptive vs uniform plans ({len(cand)} isotropic candidates; truth "
              "lambert+2ggx with a narrow lobe, fitted lambert+2ggx, 1 % noise)",
              ["plan", "lab budget (s)", "poses", "lab time (s)", "rel. RMS error (all candidates)", "error vs uniform"],
              baseline=0)
    for budget in ([120.0, 240.0] if quick else [60.0, 120.0, 240.0, 480.0]):
        n_u, lab_u, err_u = uniform(budget)
        res = adaptive_plan(cand, measure, fit, motion=model, target_error=0.0, lab_budget=budget,
                            n_initial=max(8, int(budget / pose_time / 3)), batch=12)
        err_a = relative_rms(res.model.eval(wi_all, wo_all), f_all)
        t.add("uniform (farthest point)", budget, n_u, lab_u, err_u, 1.0)
        t.add("adaptive", budget, len(res.plan), res.lab_time, err_a, err_a / err_u)
    t.notes.append("each budget's uniform row is the baseline of the adaptive row below it (last column); "
                   "adaptive starts with a farthest-point round of a third of the budget, then adds 12 poses a "
                   "round by model disagreement + residual; with very small budgets the coarse round leaves "
                   "little to adapt and uniform can win. One noise seed per row: fits of the two-lobe model "
                   "have local minima, so single rows are noisy (compare the trend across budgets).")
    return t
