"""Rows of ``benchmarks sparse`` (:mod:`benchmarks.bench_sparse`, through its ``ROW_HOOKS``) for adaptive measuring
and for the whole chain on the simulated rig, leave-one-out like the rest of that table.

* :func:`adaptive_rows` — **(b) adaptive** (``gonio measure --plan sparse --adaptive``): for each held-out material
  the :class:`gonio.prior.adaptive.PosteriorPlanner` itself (4 fixed-design poses, then one pose at a time, the
  one that most reduces the posterior's expected error), on the same candidates, samples per pose, jitter and
  noiseless values as the fixed design's rows; the error after n poses, and how many poses reach the fixed
  design's median error at n = 20 (issue 27's target: ≤ 14).
* :func:`rig_rows` — **through the simulated rig with noise**: a few held-out materials written as MERL tables and
  measured by ``gonio measure --sim --material T.binary`` with ``--plan sparse --n 20`` (fixed) and ``--plan
  sparse --adaptive --max-poses 20``, the prior built without them; lab time of the session (target ≤ 2 min on
  the default rig), the reconstruction's cube-root error, and the σ's honesty: the fraction of valid cells whose
  truth lies within 2σ of the reconstruction (target ≥ 80 %).
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time

import numpy as np

#: Materials measured through the simulated rig (full run; quick: the first), of different kinds: a plastic, a
#: metal, a paint.
RIG_MATERIALS = ("red-plastic", "nickel", "green-latex")
#: Poses of the sessions on the simulated rig (issue 27: twenty, ≤ 2 minutes of lab time).
RIG_POSES = 20
LAB_TARGET_S = 120.0
COVERAGE_TARGET = 0.80
#: Poses of the fixed design whose median error the adaptive rows must reach, and the issue's budget for it.
FIXED_N, ADAPTIVE_TARGET_N = 20, 14
N_INITIAL = 4


def _loo_prior(ctx, mi: int):
    from gonio.prior import build_prior
    from gonio.prior.build import cell_weight

    names, values, grid = ctx["names"], ctx["values"], ctx["grid"]
    tr = np.array([i for i in range(len(names)) if i != mi])
    return build_prior(values[tr], [names[i] for i in tr], grid, weight=cell_weight(grid))


_CTX: dict = {}


def _adaptive_one(mi: int) -> dict:
    """The adaptive planner's errors after 4…n_max poses with material ``mi`` held out."""
    from benchmarks.bench_sparse import JITTER_DEG, SAMPLES_PER_POSE, _pose_samples
    from gonio.fit.metrics import cbrt_error
    from gonio.geometry import half_diff_from_dirs
    from gonio.plan.ordering import MotionModel
    from gonio.prior.adaptive import PosteriorPlanner, SparseAdaptiveSettings
    from gonio.rig.kinematics import load_rig
    from gonio.samples import SampleSet

    ctx = _CTX
    mod, net = ctx["module"], ctx["nets"][ctx["names"][mi]]
    eth, etd, epd, ewi, ewo = ctx["eval"]
    cand, n_max = ctx["candidates"], FIXED_N
    truth = mod.evaluate(net, eth, etd, epd)
    h_eval = ctx["grid"].weights_angles(eth, etd, epd)
    prior = _loo_prior(ctx, mi)
    planner = PosteriorPlanner(cand, prior, motion=MotionModel.from_rig(load_rig("default")),
                               settings=SparseAdaptiveSettings(n_initial=N_INITIAL, max_poses=n_max))

    def measure(idx, k0):
        wi, wo = _pose_samples(cand.poses[idx], SAMPLES_PER_POSE, math.radians(JITTER_DEG), mi * 1000 + k0)
        th, _, td, pd = half_diff_from_dirs(wi, wo)
        f = mod.evaluate(net, th, td, pd)
        return SampleSet(wi, wo, f, 1e-3 * np.abs(f) + 1e-6, pose=np.repeat(idx, SAMPLES_PER_POSE))

    rounds = [planner.first_round()]
    samples = [measure(rounds[0].candidates, 0)]
    errs, everywhere, wall = {}, np.ones(len(eth), dtype=bool), time.process_time()
    while True:
        n = sum(len(r.candidates) for r in rounds)
        fp, _ = planner.posterior(samples, len(rounds))._predict(h_eval, everywhere)
        errs[n] = cbrt_error(fp, truth, ewi[:, 2])
        d = planner.decide(rounds, samples)
        if d.next is None:
            break
        rounds.append(d.next)
        samples.append(measure(d.next.candidates, n))
    out = {"errs": errs, "cpu_per_pose": (time.process_time() - wall) / max(n - N_INITIAL, 1)}
    _log([{"kind": "adaptive-noiseless", "material": ctx["names"][mi], "errs": {str(k): v for k, v in errs.items()}}])
    return out


def adaptive_rows(ctx) -> list[tuple]:
    """(b) adaptive rows of the table (module docstring)."""
    global _CTX
    _CTX = ctx
    held, ns = ctx["held"], ctx["ns"]
    if FIXED_N not in ns or ("ours", FIXED_N) not in ctx["errors"]:
        return []
    from benchmarks.bench_sparse import map_held

    results = map_held(_adaptive_one, held)
    fixed20 = float(np.median(ctx["errors"][("ours", FIXED_N)]))
    med = {n: float(np.median([r["errs"][n] for r in results])) for n in range(N_INITIAL, FIXED_N + 1)}
    p90 = {n: float(np.percentile([r["errs"][n] for r in results], 90)) for n in med}
    reach = next((n for n in sorted(med) if med[n] <= fixed20), None)
    # per material: the poses the adaptive planner needs to reach that material's own fixed-design error at 20
    own = [next((n for n in sorted(r["errs"]) if r["errs"][n] <= f), None)
           for r, f in zip(results, ctx["errors"][("ours", FIXED_N)])]
    own_med = float(np.median([math.inf if n is None else n for n in own]))
    cpu = float(np.median([r["cpu_per_pose"] for r in results]))
    rows = []
    for n in sorted(set(ns) | {ADAPTIVE_TARGET_N}):
        if n in med:
            note = ""
            if n == ADAPTIVE_TARGET_N:
                ok = reach is not None and reach <= ADAPTIVE_TARGET_N
                note = (f"fixed design's n = {FIXED_N} median {fixed20:.4g} reached at n = {reach if reach else '> 20'} "
                        f"(target ≤ {ADAPTIVE_TARGET_N}: {'met' if ok else 'NOT met'}); per material, poses to reach its "
                        f"own fixed n = {FIXED_N} error: median {own_med:g}; {cpu:.2f} CPU s per decision")
            rows.append(("(b) adaptive: expected cube-root error reduction under the posterior, 1 pose per round", n,
                         med[n], p90[n], note))
    return rows


def _merl_file(mod, net, path) -> None:
    f, missing = mod.table(net)
    mod.write_merl(path, f, missing)


def _session(args, out) -> dict:
    """Run ``gonio measure`` in this process (quiet); the manifest and the lab seconds of its runs."""
    import contextlib
    import io

    from gonio.cli.main import main
    from gonio.store.directory import load_session

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        code = main(["measure", "--sim", "--quiet", *args, "--out", str(out)])
    if code != 0:
        raise RuntimeError(f"gonio measure {' '.join(args)}: exit {code}: {err.getvalue()[-300:]}")
    manifest, _ = load_session(out)
    lab = sum(float(r.get("lab_time_s") or 0.0) for r in manifest.get("runs", []))
    return {"manifest": manifest, "lab_s": lab}


def rig_materials(names, quick: bool) -> list[str]:
    """The held-out materials measured through the simulated rig: ``$GONIO_SPARSE_RIG`` = ``all`` (the 63),
    ``stratified`` (every third of the sorted names: the families — felts, metals, paints, papers, satins, … —
    are contiguous in that order, so each is sampled; 21 of 63), or comma-separated names; default
    :data:`RIG_MATERIALS` (quick: its first)."""
    how = os.environ.get("GONIO_SPARSE_RIG", "").strip()
    if how == "all":
        return list(names)
    if how == "stratified":  # in an order that spreads the families, so that a run cut short is still spread
        every = sorted(names)[::3]
        step = next(k for k in (8, 7, 5, 3, 2, 1) if math.gcd(k, len(every)) == 1)
        return [every[(step * i) % len(every)] for i in range(len(every))]
    if how:
        return [m for m in how.split(",") if m in names]
    return [m for m in (RIG_MATERIALS[:1] if quick else RIG_MATERIALS) if m in names]


#: Designs measured through the rig: ``$GONIO_SPARSE_RIG_KINDS`` (comma-separated, default both).
RIG_KINDS = ("fixed", "adaptive")


def _rig_one(mi: int) -> list[dict]:
    """Material ``mi`` held out: its table written as a MERL file, a prior of the others, and a fixed and an
    adaptive session of :data:`RIG_POSES` poses on the simulated rig with its noise, each reconstructed and
    compared with the truth (module docstring)."""
    from gonio.fit.metrics import cbrt_error
    from gonio.prior import load_prior, save_prior
    from gonio.prior.reconstruct import reconstruct

    ctx = _CTX
    names, mod = ctx["names"], ctx["module"]
    eth, etd, epd, ewi, ewo = ctx["eval"]
    h_eval = ctx["grid"].weights_angles(eth, etd, epd)
    everywhere = np.ones(len(eth), dtype=bool)
    name = names[mi]
    net = ctx["nets"][name]
    truth = mod.evaluate(net, eth, etd, epd)
    work = tempfile.mkdtemp(prefix=f"gonio-sparse-rig-{mi}-")
    prior_path = os.path.join(work, f"{name}-loo.npz")
    save_prior(_loo_prior(ctx, mi), prior_path)
    table = os.path.join(work, f"{name}.binary")
    _merl_file(mod, net, table)
    common = ["--material", table, "--plan", "sparse", "--prior", prior_path, "--seed", str(mi)]
    kinds = [k for k in os.environ.get("GONIO_SPARSE_RIG_KINDS", ",".join(RIG_KINDS)).split(",") if k in RIG_KINDS]
    out = []
    for kind in kinds:
        extra = ["--n", str(RIG_POSES)] if kind == "fixed" else ["--adaptive", "--max-poses", str(RIG_POSES)]
        d = os.path.join(work, f"{name}-{kind}")
        w0 = time.perf_counter()
        try:
            run = _session(common + extra, d)
            post, _, s = reconstruct(d, load_prior(prior_path))
        except Exception as exc:  # one failed session is counted and named, not the end of the run
            out.append({"kind": kind, "material": name, "error": f"{type(exc).__name__}: …{str(exc)[-240:]}"})
            continue
        fp, sp = post._predict(h_eval, everywhere)
        out.append({"kind": kind, "material": name, "lab_s": run["lab_s"], "wall_s": time.perf_counter() - w0,
                    "cbrt": cbrt_error(fp, truth, ewi[:, 2]), "cover": float(np.mean(np.abs(fp - truth) <= 2 * sp)),
                    "samples": len(s), "poses": len(run["manifest"]["plan"]["poses"])})
    shutil.rmtree(work, ignore_errors=True)
    _log(out)
    return out


def _log(rows: list[dict]) -> None:
    """Append a held-out material's results to ``$GONIO_SPARSE_LOG`` (JSON lines) as soon as it is done: a long
    run cut short keeps what it measured."""
    path = os.environ.get("GONIO_SPARSE_LOG")
    if path:
        import json

        with open(path, "a") as fh:
            fh.write("".join(json.dumps(r) + "\n" for r in rows))


def rig_rows(ctx) -> list[tuple]:
    """Rows of the fixed and adaptive designs measured through the simulated rig (module docstring), over the
    materials of :func:`rig_materials`, in :func:`benchmarks.bench_sparse.map_held`'s process pool."""
    from benchmarks.bench_sparse import map_held

    global _CTX
    _CTX = ctx
    names = ctx["names"]
    mats = rig_materials(names, ctx["quick"])
    if not mats:
        return []
    results = [x for r in map_held(_rig_one, [names.index(m) for m in mats]) for x in r]
    path = os.environ.get("GONIO_SPARSE_RIG_JSON")
    if path:
        import json

        with open(path, "w") as fh:
            json.dump(results, fh, indent=1)
    return rows_of(results)


def rows_of(results: list[dict]) -> list[tuple]:
    """The table's rows of the sessions ``results`` (one dict per session, as :func:`_rig_one` returns and
    ``$GONIO_SPARSE_LOG`` keeps them)."""
    rows = []
    for kind, label in (("fixed", "through the simulated rig, noisy: fixed design"),
                        ("adaptive", "through the simulated rig, noisy: (b) adaptive")):
        r = [x for x in results if x["kind"] == kind and "error" not in x]
        failed = [x["material"] for x in results if x["kind"] == kind and "error" in x]
        if not r:
            continue
        cb = np.array([x["cbrt"] for x in r])
        lab = np.array([x["lab_s"] for x in r])
        cover = np.array([x["cover"] for x in r])
        ok = int(np.sum(cover >= COVERAGE_TARGET))
        worst = sorted(r, key=lambda x: x["cover"])[:3]
        rows.append((label, RIG_POSES, float(np.median(cb)), float(np.percentile(cb, 90)),
                     f"{len(r)} held-out materials{f' ({len(failed)} sessions failed: {failed})' if failed else ''}; "
                     f"lab time median {np.median(lab):.0f} s, max {lab.max():.0f} s (target ≤ {LAB_TARGET_S:.0f} s: "
                     f"{'met' if lab.max() <= LAB_TARGET_S else 'NOT met'}); truth within 2σ: median "
                     f"{100 * np.median(cover):.0f} % of cells, ≥ {100 * COVERAGE_TARGET:.0f} % for {ok} of {len(r)} "
                     f"materials (lowest: " + ", ".join(f"{x['material']} {100 * x['cover']:.0f} %" for x in worst)
                     + f"); samples per session median {np.median([x['samples'] for x in r]):.0f}"))
    return rows


adaptive_rows.part, rig_rows.part = "adaptive", "rig"
HOOKS = [adaptive_rows, rig_rows]


def main(argv=None) -> int:
    """``python -m benchmarks.sparse_rig [--quick]``: only the through-the-rig rows of ``benchmarks sparse`` (the
    materials of :func:`rig_materials`: ``GONIO_SPARSE_RIG=all`` for the 63), printed as a table."""
    import argparse

    from benchmarks.bench_sparse import N_EVAL, _eval_cells
    from benchmarks.common import Table
    from gonio.prior import DEFAULT_GRID
    from gonio.prior.build import fill_nodes
    from gonio.prior.build_default import find_realdata, node_values_realdata, realdata_materials

    ap = argparse.ArgumentParser(prog="python -m benchmarks.sparse_rig")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--from-log", nargs="+", metavar="LOG", help="only tabulate the sessions of these "
                    "$GONIO_SPARSE_LOG files (runs cut short or split over materials); nothing is measured")
    a = ap.parse_args(argv)
    if a.from_log:
        return _from_log(a.from_log)
    src = find_realdata()
    if src is None:
        print("../shared/realdata not found (set GONIO_REALDATA)")
        return 1
    t0 = time.perf_counter()
    mod, nets = realdata_materials(src)
    names, values = node_values_realdata(mod, nets, DEFAULT_GRID)
    ctx = {"names": names, "values": fill_nodes(values, DEFAULT_GRID), "grid": DEFAULT_GRID, "nets": nets,
           "module": mod, "eval": _eval_cells(N_EVAL // 4 if a.quick else N_EVAL), "quick": a.quick}
    t = Table("Sparse measurement through the simulated rig with noise, leave-one-out",
              ["method", "poses", "median cbrt", "p90 cbrt", "note"])
    for row in rig_rows(ctx):
        t.add(*row)
    t.notes.append(f"run time {time.perf_counter() - t0:.0f} s; materials: {os.environ.get('GONIO_SPARSE_RIG') or 'default'}")
    print(t.to_markdown())
    return 0


def _from_log(paths: list[str]) -> int:
    """Print the rows of the sessions logged in ``paths`` (the last entry of a material and design wins)."""
    import json

    from benchmarks.common import Table

    kept: dict = {}
    for path in paths:
        with open(path) as fh:
            for line in fh:
                r = json.loads(line)
                if r.get("kind") in RIG_KINDS:
                    kept[(r["kind"], r["material"])] = r
    t = Table("Sparse measurement through the simulated rig with noise, leave-one-out (from logs)",
              ["method", "poses", "median cbrt", "p90 cbrt", "note"])
    for row in rows_of(list(kept.values())):
        t.add(*row)
    t.notes.append(f"{len({m for _, m in kept})} materials from {', '.join(paths)}")
    print(t.to_markdown())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
