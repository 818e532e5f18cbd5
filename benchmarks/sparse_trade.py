"""The sparse-measurement trade of ``gonio bench`` (:mod:`benchmarks.report`): lab time against the whole table's
cube-root error (:func:`gonio.fit.metrics.cbrt_error`) for a few poses chosen under a prior and reconstructed by its
posterior (n = 5, 10, 20; :mod:`gonio.prior`), beside a dense table.

* full run — the real materials of ``../shared/realdata`` when present: :data:`benchmarks.bench_sparse.QUICK_MATERIALS`
  each held out of the prior it is measured with (leave-one-out), the poses chosen among the default rig's
  reachable candidates, lab times those of the ordered plans on the default rig (:func:`gonio.plan.estimate_plan`),
  the dense table's that of a dense grid plan (10°/30°).
  ``python -m benchmarks sparse`` is the whole study (63 materials, Nielsen 2015, a parametric fit, adaptive
  measuring, the simulated rig with noise); this row is its summary at a fraction of the cost.
* quick run (and without the real data) — synthetic, well under a second: a prior of :data:`N_TRAIN` analytic
  Lambert + Blinn–Phong materials on a small grid (in-sample variances), :data:`N_TEST` others held out (one a
  two-lobe material outside the
  prior's family), candidates an isotropic direction grid without the rig, lab time n × the default capture's time
  per pose (moves not counted). It shows the shape of the trade, not the real materials' numbers.
"""

from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.common import Table

NS = (5, 10, 20)
N_TRAIN, N_TEST = 16, 4
#: The dense plan's size on the default rig (README "Measure in a minute"), for the quick run's lab time.
DENSE_POSES = 931


class _Phong:
    """Lambert + normalized Blinn–Phong lobes, f = kd/π + Σ ksₗ·(eₗ + 2)/(2π)·cos^eₗ θh (Blinn 1977, with the
    energy normalisation of Akenine-Möller et al., *Real-Time Rendering*, 3rd ed., §7.6): a closed form in NumPy,
    so the quick trade needs no compiled kernel."""

    def __init__(self, kd, lobes):
        self.kd = np.asarray(kd, dtype=np.float64)
        self.lobes = [(np.asarray(k, dtype=np.float64), float(e)) for k, e in lobes]

    def eval(self, wi, wo):
        h = wi + wo
        c = np.clip(h[:, 2] / np.maximum(np.linalg.norm(h, axis=1), 1e-300), 0.0, 1.0)[:, None]
        f = np.broadcast_to(self.kd / np.pi, (len(wi), 3)).copy()
        for ks, e in self.lobes:
            f += ks * (e + 2) / (2 * np.pi) * c ** e
        return np.where((wi[:, 2:] > 0) & (wo[:, 2:] > 0), f, 0.0)


def _synthetic(n: int, seed: int):
    """``n`` one-lobe materials (:class:`_Phong`) with random colours and exponents (name, model)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        kd, ks = rng.uniform(0.02, 0.3, 3), rng.uniform(0.05, 0.5, 3)
        out.append((f"synthetic-{seed}-{i}", _Phong(kd, [(ks, float(np.exp(rng.uniform(np.log(5), np.log(300)))))])))
    return out


def _random_pairs(n: int, seed: int):
    """``n`` direction pairs uniform over the upper hemisphere (the evaluation cells)."""
    rng = np.random.default_rng(seed)

    def hemi(k):
        z = rng.uniform(0.02, 1.0, k)
        phi = rng.uniform(0, 2 * np.pi, k)
        r = np.sqrt(1 - z * z)
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)

    return hemi(n), hemi(n)


def _quick_rows(t: Table) -> None:
    from gonio.fit.metrics import cbrt_error
    from gonio.geometry import dirs_from_angles
    from gonio.plan import CaptureSettings
    from gonio.prior import Posterior, PriorGrid, build_prior
    from gonio.prior.design import select_directions

    grid = PriorGrid(14, 10, 8)
    wi_n, wo_n = grid.node_directions()
    train = _synthetic(N_TRAIN, 0)
    prior = build_prior(np.stack([m.eval(wi_n, wo_n) for _, m in train]), [n for n, _ in train], grid,
                        weight=np.full(grid.size, 1.0 / grid.size), calibrate=False)
    two_lobe = _Phong([0.1, 0.08, 0.05], [([0.3, 0.25, 0.2], 400.0), ([0.2, 0.2, 0.2], 8.0)])
    test = _synthetic(N_TEST - 1, 1) + [("two-lobe (outside the family)", two_lobe)]
    g = np.radians(np.arange(0, 81, 10.0))
    ti, to, po = (a.ravel() for a in np.meshgrid(g, g, np.radians(np.arange(0, 181, 20.0)), indexing="ij"))
    cwi, cwo = dirs_from_angles(ti, np.zeros_like(ti), to, po)
    design = select_directions(prior, cwi, cwo, max(NS))
    ewi, ewo = _random_pairs(1000, 7)
    pose_s = CaptureSettings().pose_time()
    for n in NS:
        idx = design.indices[:n]
        errs = []
        for _, m in test:
            f = m.eval(cwi[idx], cwo[idx])
            post = Posterior.start(prior).update(cwi[idx], cwo[idx], f, 1e-3 * np.abs(f) + 1e-6)
            errs.append(cbrt_error(post.predict(ewi, ewo)[0], m.eval(ewi, ewo), ewi[:, 2]))
        t.add("sparse + prior (synthetic)", n, round(n * pose_s, 1), float(np.median(errs)), float(np.max(errs)),
              f"{len(test)} held-out synthetic materials")
    t.add("dense table", DENSE_POSES, round(DENSE_POSES * pose_s, 1), 0.0, 0.0, "measured densely: no reconstruction")
    t.notes.append(f"quick run: synthetic — a prior of {N_TRAIN} analytic Lambert + Blinn–Phong materials on the "
                   f"{grid.grid_id} grid, {len(test)} others held out (one outside the family), {len(cwi)} candidate "
                   f"directions without the rig; lab time = poses × {pose_s:.2f} s per pose (moves not counted). "
                   "The real materials: the full run, or python -m benchmarks sparse")


def _real_rows(t: Table, src) -> None:
    from benchmarks.bench_sparse import (JITTER_DEG, N_EVAL, QUICK_MATERIALS, SAMPLES_PER_POSE, _eval_cells,
                                         _pose_samples)
    from gonio.fit.metrics import cbrt_error
    from gonio.geometry import half_diff_from_dirs
    from gonio.plan import estimate_plan
    from gonio.plan.ordering import MotionModel, optimize_order
    from gonio.plan.plan import Plan
    from gonio.prior import DEFAULT_GRID, Posterior, build_prior
    from gonio.prior.build import cell_weight, fill_nodes
    from gonio.prior.build_default import realdata_materials
    from gonio.prior.design import _directions, candidate_poses, select_directions
    from gonio.rig.kinematics import load_rig

    grid = DEFAULT_GRID
    mod, nets = realdata_materials(src)
    names = sorted(nets)
    held = [m for m in QUICK_MATERIALS if m in nets]
    th, td, pd = grid.node_angles()
    values = fill_nodes(np.stack([mod.evaluate(nets[n], th, td, pd) for n in names]), grid)
    weight = cell_weight(grid)
    eth, etd, epd, ewi, ewo = _eval_cells(N_EVAL // 4)
    h_eval = grid.weights_angles(eth, etd, epd)
    cand = candidate_poses()
    cwi, cwo = _directions(cand.poses)
    rig = load_rig("default")
    motion = MotionModel.from_rig(rig)
    errs, labs = {n: [] for n in NS}, {n: [] for n in NS}
    for name in held:
        mi = names.index(name)
        tr = [i for i in range(len(names)) if i != mi]
        prior = build_prior(values[tr], [names[i] for i in tr], grid, weight=weight)
        design = select_directions(prior, cwi, cwo, max(NS), samples_per_pose=SAMPLES_PER_POSE)
        truth = mod.evaluate(nets[name], eth, etd, epd)
        for n in NS:
            idx = design.indices[:n]
            swi, swo = _pose_samples(cand.poses[idx], SAMPLES_PER_POSE, math.radians(JITTER_DEG), mi)
            a, _, b, c = half_diff_from_dirs(swi, swo)
            f = mod.evaluate(nets[name], a, b, c)
            post = Posterior.start(prior).update(swi, swo, f, 1e-3 * np.abs(f) + 1e-6)
            errs[n].append(cbrt_error(post._predict(h_eval, np.ones(len(eth), bool))[0], truth, ewi[:, 2]))
            plan = Plan(poses=cand.poses[idx], capture=cand.capture, generator="sparse", params={},
                        joints=cand.joints[idx], order="generated")
            if len(plan) > 1:
                plan = plan.reordered(optimize_order(plan.joints, motion, seed=0, time_budget=0.5,
                                                     initial=np.arange(len(plan))), "optimized")
            labs[n].append(estimate_plan(plan, rig).optimized)
    for n in NS:
        t.add("sparse + prior (real materials, leave-one-out)", n, round(float(np.median(labs[n])), 1),
              float(np.median(errs[n])), float(np.max(errs[n])), f"{len(held)} held-out real materials")
    from gonio.plan.generators import make_plan

    dense = make_plan("grid", rig=rig, theta_step=math.radians(10), phi_step=math.radians(30))
    t.add("dense table", len(dense), round(estimate_plan(dense, rig).optimized, 1), 0.0, 0.0,
          "a dense grid (10°/30°, benchmarks labtime's), measured: no reconstruction")
    t.notes.append(f"held out of the prior in turn: {', '.join(held)}; {SAMPLES_PER_POSE} noiseless samples per pose; "
                   "python -m benchmarks sparse has all 63, Nielsen 2015, the parametric fit and the rig with noise")


def trade_tables(quick: bool = False) -> list[Table]:
    """The trade's table (module docstring)."""
    from gonio.prior.build_default import find_realdata

    t0 = time.perf_counter()
    t = Table("Sparse measurement under a prior: lab time vs the whole table's cube-root error (lower is better)",
              ["method", "poses", "lab s", "median cbrt", "max cbrt", "note"])
    src = None if quick else find_realdata()
    if src is None:
        _quick_rows(t)
    else:
        _real_rows(t, src)
    t.default = 2  # twenty poses: the budget
    t.why_default = ("twenty poses under the prior (gonio plan sparse's --n): a whole table in under a minute of lab "
                     "time")
    t.baseline = len(t.rows) - 1  # the dense table
    t.columns = list(t.columns) + ["lab ÷ dense"]
    t.rows = [tuple(r) + (float(r[2]) / float(t.rows[t.baseline][2]),) for r in t.rows]
    t.notes.append(f"run time {time.perf_counter() - t0:.1f} s")
    return [t]
