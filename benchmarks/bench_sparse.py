"""Sparse measurement under a data-driven prior: error against the number of poses, leave-one-out.

For each of the 63 real materials of ``../shared/realdata`` (12 MERL + 51 RGL-EPFL, as Sztrajman et al. 2021's
neural fits; :mod:`gonio.prior.build_default`), held out in turn — every prior and basis below is built from the
other 62, nothing is tuned on the held-out material:

* **ours (fixed design)** — :func:`gonio.prior.build.build_prior` of the 62 (leave-one-out calibrated inside, by
  their Gram matrix), n poses chosen by greedy A-optimality (:func:`gonio.prior.design.select_directions`) among
  the default rig's reachable candidates, reconstruction by :class:`gonio.prior.Posterior`;
* **Nielsen 2015** — :mod:`gonio.prior.nielsen` (their cosine-weighted mapping, PCA, condition-number directions,
  ridge regression with η chosen on the 62 alone), same candidates, same budget;
* **select** — a parametric ``gonio.select`` fit (default candidates) of the samples of the *same poses* as ours;
* **dense** — the full table itself (error 0 by definition; lab time of the dense plan), and the prior grid's own
  floor: the held-out material's exact node values, interpolated (what no reconstruction on this grid beats).

Each pose gives :data:`SAMPLES_PER_POSE` samples: its nominal direction pair and neighbours within
:data:`JITTER_DEG` (a target's tiles see the pose at slightly different wi/wo), noiseless values (σ = 0.1 % for
the Bayesian weights). Errors: the cube-root cosine-weighted error of :func:`gonio.fit.metrics.cbrt_error` over
:data:`N_EVAL` random valid MERL cells (same cells for every method), median and 90th percentile over materials.
Also printed: the reconstructions' σ coverage (truth within 2σ, fraction of cells, median over materials) and
how many held-out materials the χ² test calls outside the prior's span.

Hooks: :data:`ROW_HOOKS` — callables ``hook(ctx) -> list[tuple]`` appending rows ``(method, n, median, p90,
note)`` to the table (helper rows: adaptive measuring, the simulated rig with noise); ``ctx`` is a dict with the
held-out loop's data (see :func:`run`). ``--quick``: 6 materials, n ∈ {5, 10, 20}, fewer cells. The plot of the
curves goes to ``$GONIO_SPARSE_PLOT`` (default: ``<tmp>/gonio-sparse.png``).
"""

from __future__ import annotations

import math
import os
import tempfile
import time

import numpy as np

from benchmarks.common import Table

NS = (5, 10, 20)
QUICK_NS = (5, 10, 20)
SELECT_NS = (20,)
N_EVAL = 20_000
SAMPLES_PER_POSE = 5
JITTER_DEG = 2.0
QUICK_MATERIALS = ("chrome", "red-plastic", "green-latex", "nickel", "acrylic_felt_yellow_rgb", "chm_orange_rgb")
#: Extra rows: ``hook(ctx) -> [(method, n, median, p90, note), ...]`` (module docstring).
ROW_HOOKS: list = []


def skipped() -> set[str]:
    """Parts of the study left out of this run: ``$GONIO_SPARSE_SKIP``, comma-separated among ``nielsen``,
    ``select``, ``adaptive``, ``rig`` (e.g. to repeat the adaptive rows alone); ``GONIO_SPARSE_MATERIALS=stratified``
    holds out every third material only (the 21 of :func:`benchmarks.sparse_rig.rig_materials`)."""
    return {x.strip() for x in os.environ.get("GONIO_SPARSE_SKIP", "").split(",") if x.strip()}


def _eval_cells(n: int, seed: int = 0):
    """``(θh, θd, φd, wi, wo)`` of ``n`` random MERL cell centres above the horizon."""
    from gonio.geometry import dirs_from_half_diff
    from gonio.io.merl import cell_centres

    rng = np.random.default_rng(seed)
    th, td, pd = cell_centres()
    i, j, k = rng.integers(0, 90, 3 * n), rng.integers(0, 90, 3 * n), rng.integers(0, 180, 3 * n)
    TH, TD, PD = th[i], td[j], pd[k]
    wi, wo = dirs_from_half_diff(TH, np.zeros_like(TH), TD, PD)
    ok = np.flatnonzero((wi[:, 2] > 0) & (wo[:, 2] > 0))[:n]
    return TH[ok], TD[ok], PD[ok], wi[ok], wo[ok]


def _pose_samples(poses: np.ndarray, k: int, jitter: float, seed: int):
    """Direction pairs (len(poses)·k, 3) of each pose's k samples: the nominal pair and k−1 jittered ones."""
    from gonio.geometry import dirs_from_angles

    rng = np.random.default_rng(seed)
    p = np.repeat(poses, k, axis=0)
    d = rng.uniform(-jitter, jitter, p.shape)
    d[::k] = 0.0
    q = p + d
    q[:, [0, 2]] = np.clip(q[:, [0, 2]], 0.0, math.radians(85))
    return dirs_from_angles(q[:, 0], q[:, 1], q[:, 2], q[:, 3])


_CTX: dict = {}


def _one_material(mi: int) -> dict:
    """Everything measured with material ``mi`` held out (module docstring); data from :data:`_CTX`."""
    from gonio.fit.metrics import cbrt_error
    from gonio.geometry import half_diff_from_dirs
    from gonio.prior import Posterior, build_prior
    from gonio.prior import nielsen as nl
    from gonio.prior.design import select_directions
    from gonio.samples import SampleSet

    c = _CTX
    names, values, grid, ns, mod = c["names"], c["values"], c["grid"], c["ns"], c["mod"]
    eth, etd, epd, ewi, ewo = c["eval"]
    h_eval, cand, cwi, cwo, h_cand = c["h_eval"], c["cand"], c["cwi"], c["cwo"], c["h_cand"]
    net = c["nets"][names[mi]]
    tr = np.array([i for i in range(len(names)) if i != mi])
    truth = mod.evaluate(net, eth, etd, epd)
    prior = build_prior(values[tr], [names[i] for i in tr], grid, weight=c["weight"])
    design = select_directions(prior, cwi, cwo, c["n_max"], samples_per_pose=SAMPLES_PER_POSE)
    skip = skipped()
    if "nielsen" not in skip:
        nmod = nl.build_nielsen(values[tr], grid)
        n_order = nl.select_condition(nmod, h_cand, c["n_max"])
        etas = nl.choose_eta(values[tr], grid, h_cand, n_order, ns)
    else:
        etas = {}
    out = {"floor": cbrt_error(nl.interpolate(values[mi].T, h_eval), truth, ewi[:, 2]), "ours": {}, "nielsen": {},
           "select": {}, "cover": {}, "outside": {}, "expected": {}, "select_s": [], "etas": etas}
    everywhere = np.ones(len(eth), dtype=bool)
    for n in ns:
        # ours: the A-optimal poses, each with its samples
        swi, swo = _pose_samples(cand.poses[design.indices[:n]], SAMPLES_PER_POSE, math.radians(JITTER_DEG), mi)
        th, _, td, pd = half_diff_from_dirs(swi, swo)
        f = mod.evaluate(net, th, td, pd)
        post = Posterior.start(prior).update(swi, swo, f, 1e-3 * np.abs(f) + 1e-6)
        fp, sp = post._predict(h_eval, everywhere)
        out["ours"][n] = cbrt_error(fp, truth, ewi[:, 2])
        out["cover"][n] = float(np.mean(np.abs(fp - truth) <= 2 * sp))
        out["outside"][n] = bool(post.quality().out_of_span)
        out["expected"][n] = float(design.errors[n])
        if n in SELECT_NS and "select" not in skip:
            from gonio.fit.select import select

            c0 = time.process_time()
            sel = select(SampleSet(swi, swo, f, np.full_like(f, np.nan)))
            out["select_s"].append(time.process_time() - c0)
            out["select"][n] = cbrt_error(sel.model.eval(ewi, ewo), truth, ewi[:, 2])
        if "nielsen" in skip:
            continue
        # Nielsen 2015: their directions, the same budget and sample pattern
        nwi, nwo = _pose_samples(cand.poses[n_order[:n]], SAMPLES_PER_POSE, math.radians(JITTER_DEG), mi)
        th, _, td, pd = half_diff_from_dirs(nwi, nwo)
        coef = nl.reconstruct_coefficients(nmod, grid.weights(nwi, nwo), mod.evaluate(net, th, td, pd), *etas[n])
        out["nielsen"][n] = cbrt_error(nl.interpolate(nl.predict_nodes(nmod, coef), h_eval), truth, ewi[:, 2])
    from benchmarks.sparse_rig import _log

    _log([{"kind": "fixed-noiseless", "material": names[mi],
           **{key: {str(k): v for k, v in out[key].items()} for key in ("ours", "cover", "nielsen", "select")},
           "select_s": out["select_s"]}])
    return out


def _stats(errs):
    e = np.asarray(errs, dtype=np.float64)
    return float(np.median(e)), float(np.percentile(e, 90))


def map_held(fn, held):
    """``[fn(m) for m in held]`` over ``GONIO_BENCH_WORKERS`` forked processes (default 2; 1: in this process) —
    the held-out materials are independent, and the forked workers share the module context."""
    workers = max(1, min(int(os.environ.get("GONIO_BENCH_WORKERS", "2")), len(held)))
    if workers == 1:
        return [fn(mi) for mi in held]
    import multiprocessing as mp

    with mp.get_context("fork").Pool(workers) as pool:
        return pool.map(fn, held, chunksize=1)


def run(quick: bool = False) -> list[Table]:
    from gonio.prior.build_default import find_realdata

    t = Table("Sparse measurement under a prior: cube-root error of the whole table vs poses (leave-one-out over "
              "the real materials; lower is better)", ["method", "poses", "median cbrt", "p90 cbrt", "vs Nielsen",
                                                        "note"])
    src = find_realdata()
    if src is None:
        t.notes.append("../shared/realdata not found (set GONIO_REALDATA): no real materials measured in this run")
        return [t]
    return _run(src, quick, t)


def _run(src, quick: bool, t: Table) -> list[Table]:
    from gonio.prior import DEFAULT_GRID
    from gonio.prior.build import cell_weight, fill_nodes
    from gonio.prior.build_default import node_values_realdata, realdata_materials
    from gonio.prior.design import _directions, candidate_poses

    t0 = time.perf_counter()
    grid = DEFAULT_GRID
    mod, nets = realdata_materials(src)
    c0 = time.process_time()
    names, values = node_values_realdata(mod, nets, grid)
    eval_cpu = time.process_time() - c0
    values = fill_nodes(values, grid)
    weight = cell_weight(grid)
    t_prior = _prior_table(values, names, grid, eval_cpu, quick)
    ns = QUICK_NS if quick else NS
    held = [names.index(n) for n in QUICK_MATERIALS] if quick else list(range(len(names)))
    if os.environ.get("GONIO_SPARSE_MATERIALS") in ("stratified", "rest"):  # every third of the sorted names (the
        every = sorted(names)[::3]  # families are contiguous in that order): 21 of 63; "rest": the other 42
        held = [names.index(n) for n in (every if os.environ["GONIO_SPARSE_MATERIALS"] == "stratified"
                                         else [m for m in names if m not in every])]
    n_max = max(ns)
    eth, etd, epd, ewi, ewo = _eval_cells(N_EVAL // 4 if quick else N_EVAL)
    h_eval = grid.weights_angles(eth, etd, epd)
    cand = candidate_poses()
    cwi, cwo = _directions(cand.poses)
    h_cand = grid.weights(cwi, cwo)
    global _CTX
    _CTX = {"grid": grid, "names": names, "values": values, "weight": weight, "ns": ns, "n_max": n_max, "nets": nets, "mod": mod,
            "eval": (eth, etd, epd, ewi, ewo), "h_eval": h_eval, "cand": cand, "cwi": cwi, "cwo": cwo, "h_cand": h_cand}
    results = map_held(_one_material, held)
    skip = skipped()
    errs = {key: [] for key in [("ours", n) for n in ns] + [("nielsen", n) for n in ns if "nielsen" not in skip] +
            [("select", n) for n in SELECT_NS if n in ns and "select" not in skip] + [("grid floor", 0)]}
    cover, outside, expected = {n: [] for n in ns}, {n: 0 for n in ns}, {n: [] for n in ns}
    select_s, etas_used = [], {}
    for mi, r in zip(held, results):
        errs[("grid floor", 0)].append(r["floor"])
        for n in ns:
            errs[("ours", n)].append(r["ours"][n])
            if ("nielsen", n) in errs:
                errs[("nielsen", n)].append(r["nielsen"][n])
            cover[n].append(r["cover"][n])
            outside[n] += r["outside"][n]
            expected[n].append(r["expected"][n])
            if ("select", n) in errs:
                errs[("select", n)].append(r["select"][n])
        select_s += r["select_s"]
        etas_used[mi] = r["etas"]
    nielsen_med = {n: _stats(errs[("nielsen", n)])[0] if ("nielsen", n) in errs else math.nan for n in ns}
    for n in ns:
        m, p = _stats(errs[("ours", n)])
        t.add("ours: prior + A-optimal poses", n, m, p, m / nielsen_med[n],
              f"σ coverage (truth within 2σ) {np.median(cover[n]):.2f}; {outside[n]} of {len(held)} said outside the "
              f"span; expected log-RMS {np.median(expected[n]):.3g}")
    for n in ns if "nielsen" not in skip else ():
        m, p = _stats(errs[("nielsen", n)])
        ks = [etas_used[mi][n][1] for mi in etas_used]
        t.add("Nielsen et al. 2015 (same data, candidates)", n, m, p, 1.0,
              f"k = {int(np.median(ks))} components (median), η and k chosen on the training materials per fold")
    for n in SELECT_NS:
        if ("select", n) in errs:
            m, p = _stats(errs[("select", n)])
            t.add("parametric gonio.select, same poses", n, m, p, m / nielsen_med[n],
                  f"{np.median(select_s):.1f} CPU s per fit (median)")
    m, p = _stats(errs[("grid floor", 0)])
    t.add("dense: the full table (reference)", "dense", 0.0, 0.0, 0.0, "measured densely: no reconstruction")
    t.add("prior grid floor (exact node values)", "-", m, p, m / nielsen_med[ns[-1]],
          f"the {grid.grid_id} grid's interpolation alone")
    ctx = {"names": names, "held": held, "ns": ns, "errors": errs, "grid": grid, "values": values, "nets": nets,
           "module": mod, "eval": (eth, etd, epd, ewi, ewo), "candidates": cand, "quick": quick}
    for hook in ROW_HOOKS:
        if getattr(hook, "part", None) in skip:
            t.notes.append(f"{hook.part} rows left out of this run (GONIO_SPARSE_SKIP)")
            continue
        for row in hook(ctx):
            method, n, med, p90, note = row
            t.add(method, n, med, p90, med / nielsen_med.get(n, math.nan) if isinstance(n, int) else math.nan, note)
    t.notes += [
        f"{len(held)} held-out materials of {src} (each excluded from every prior, basis and η it is measured with); "
        f"{SAMPLES_PER_POSE} noiseless samples per pose (nominal + within {JITTER_DEG:g}°); cbrt over {len(eth)} random "
        "valid MERL cells (Ngan et al. 2005 on cube roots, gonio.fit.metrics)",
        f"candidates: {len(cand)} reachable poses of the default rig ({cand.n_dropped} unreachable never planned)",
        f"run time {time.perf_counter() - t0:.0f} s",
    ]
    _plot(errs, ns, os.environ.get("GONIO_SPARSE_PLOT") or os.path.join(tempfile.gettempdir(), "gonio-sparse.png"), t)
    return [t, t_prior]


def _prior_table(values, names, grid, eval_cpu: float, quick: bool) -> Table:
    """The shipped prior's size, build and load times, and what float16 storage costs."""
    from gonio.prior import Posterior, build_prior, load_prior, save_prior
    from gonio.prior.design import _directions, candidate_poses, select_directions
    from gonio.prior.nielsen import interpolate

    t = Table("The default prior: size, build and load time (targets: ≤ 5 MB, ≤ 180 s on one core, ≤ 1 s)",
              ["quantity", "value", "target", "ok"])
    c0 = time.process_time()
    prior = build_prior(values, names, grid)
    build = time.process_time() - c0 + eval_cpu
    path = os.path.join(tempfile.mkdtemp(prefix="gonio-prior-"), "prior.npz")
    save_prior(prior, path)
    size = os.path.getsize(path) / 1e6
    loads = []
    for _ in range(5):
        w0 = time.perf_counter()
        back = load_prior(path)
        loads.append(time.perf_counter() - w0)
    load = float(np.median(loads))
    cand = candidate_poses()
    cwi, cwo = _directions(cand.poses)
    idx = select_directions(prior, cwi, cwo, 20).indices
    wi, wo = cwi[idx], cwo[idx]
    h = grid.weights(wi, wo)
    diffs = []
    for m in (range(0, len(values), 10) if quick else range(len(values))):
        f = interpolate(values[m].T, h)  # the material at the 20 directions
        a = Posterior.start(prior).update(wi, wo, f, 1e-3 * f + 1e-6)
        b = Posterior.start(back).update(wi, wo, f, 1e-3 * f + 1e-6)
        mean_a, _ = a.node_mapped()
        mean_b, _ = b.node_mapped()
        diffs.append(float(np.max(np.abs(mean_a - mean_b))))
    t.add("file size (MB)", round(size, 2), "≤ 5", "yes" if size <= 5 else "no")
    t.add("build from the 63 materials, CPU s (node values + PCA + leave-one-out)", round(build, 1), "≤ 180",
          "yes" if build <= 180 else "no")
    t.add("load, s (median of 5)", round(load, 3), "≤ 1", "yes" if load <= 1 else "no")
    t.add("float16 storage: largest change of a reconstruction, log domain (20 poses, max over nodes, median "
          "over materials)", float(np.median(diffs)), "≪ the error (~0.1)", "yes" if np.median(diffs) < 0.01 else "no")
    t.notes.append(f"{prior.n_components} components, grid {grid.grid_id}; float16 basis scaled per column")
    return t


def _plot(errs, ns, path, t: Table) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        t.notes.append("matplotlib not installed: no plot")
        return
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for key, label, colour in (("ours", "ours (prior + A-optimal)", "C0"), ("nielsen", "Nielsen et al. 2015", "C1"),
                               ("select", "parametric select", "C2")):
        xs = [n for n in ns if (key, n) in errs and errs[(key, n)]]
        if not xs:
            continue
        med = [np.median(errs[(key, n)]) for n in xs]
        p90 = [np.percentile(errs[(key, n)], 90) for n in xs]
        ax.plot(xs, med, "o-", color=colour, label=f"{label}, median")
        ax.plot(xs, p90, "o--", color=colour, alpha=0.5, label=f"{label}, p90")
    floor = np.median(errs[("grid floor", 0)])
    ax.axhline(floor, color="grey", lw=0.8, ls=":", label="prior grid floor (median)")
    ax.set_xlabel("poses")
    ax.set_ylabel("cube-root error of the whole table")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    ax.set_title("Sparse measurement, leave-one-out over the real materials", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    t.notes.append(f"plot: {path}")


# Rows of helper modules: adaptive measuring and the simulated rig with noise (benchmarks/sparse_rig.py).
from benchmarks.sparse_rig import HOOKS as _SPARSE_RIG_HOOKS  # noqa: E402

ROW_HOOKS.extend(_SPARSE_RIG_HOOKS)
