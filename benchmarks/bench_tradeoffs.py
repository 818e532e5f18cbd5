"""Speed-versus-accuracy trades no other benchmark covers: plan density and kind (lab time vs BRDF error,
simulated sessions end to end), exposure bracket and frames averaged (lab time vs noise), and MERL
lookup interpolation (speed vs error). ``gonio bench`` (:mod:`benchmarks.report`) runs these together
with :mod:`benchmarks.bench_brdf` (Schlick vs pow, float32 vs float64) and :mod:`benchmarks.bench_fit`
(fit time vs data subsampling).

Every error is measured against the known simulated material: the sessions render :data:`MATERIAL`
(a diffuse base, a broad and a narrow GGX lobe), so sparse plans can miss the narrow lobe.
"""

from __future__ import annotations

import math
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.common import Table, time_call

#: The simulated sample of the plan and capture trades: Lambert + a broad and a narrow GGX lobe.
MATERIAL = {"model": "lambert+2ggx",
            "params": {"diffuse.albedo": [0.25, 0.2, 0.15], "lobe1.ks": 0.3, "lobe1.alpha": 0.3,
                       "lobe2.ks": 0.3, "lobe2.alpha": 0.1}}
#: Camera resolution of the simulated sessions (the `gonio measure --sim` default).
RESOLUTION = (320, 240)
#: Largest zenith angle of the plans and of the directions the BRDF error is averaged over.
THETA_MAX_DEG = 70.0
_D = math.radians


def truth():
    """The simulated material as a BRDF model."""
    from gonio.brdf import make

    return make(MATERIAL["model"], **MATERIAL["params"])


def eval_directions(n: int = 20_000, theta_max_deg: float = THETA_MAX_DEG, seed: int = 0):
    """``(wi, wo)``: ``n`` random direction pairs, uniform in solid angle up to ``theta_max_deg``."""
    from gonio.geometry import from_spherical

    rng = np.random.default_rng(seed)
    c = math.cos(_D(theta_max_deg))
    wi = from_spherical(np.arccos(rng.uniform(c, 1, n)), rng.uniform(0, 2 * np.pi, n))
    wo = from_spherical(np.arccos(rng.uniform(c, 1, n)), rng.uniform(0, 2 * np.pi, n))
    return wi, wo


def simulate(plan, out: Path):
    """Run ``plan`` on the simulated rig rendering :data:`MATERIAL`: ``(RunResult, wall s, SampleSet)``."""
    from benchmarks.bench_session import _session
    from gonio.session.store import load_session

    result, wall = _session(plan, RESOLUTION, out, material=MATERIAL)
    return result, wall, load_session(out)[1]


def overhead_lab(result) -> float:
    """Lab seconds of a session not spent on its poses (device checks, darks, the light's warm-up)."""
    return result.lab_time - sum(t["move_lab"] + t["dark_lab"] + t["capture_lab"] for t in result.timings)


def fit_error(samples, wi, wo, f_true) -> tuple[float, float]:
    """Fit :data:`MATERIAL`'s model to ``samples``: ``(relative RMS error over (wi, wo), fit seconds)``."""
    from gonio.brdf import make
    from gonio.fit import fit
    from gonio.plan.adaptive import relative_rms

    t0 = time.perf_counter()
    res = fit(samples, MATERIAL["model"], n_starts=4)
    secs = time.perf_counter() - t0
    return relative_rms(make(res.model, **res.params).eval(wi, wo), f_true), secs


def _plans(quick: bool) -> list[tuple[str, str, dict]]:
    from gonio.cli.measure import DEFAULT_PLAN_PARAMS

    deflt = {k: _D(v) for k, v in DEFAULT_PLAN_PARAMS.items()}
    t = _D(THETA_MAX_DEG)
    rows = [("in_plane", "30°/30°, θ ≤ 60°", {"theta_i_step": _D(30), "theta_o_step": _D(30), "theta_max": _D(60)}),
            ("in_plane", "20°/10° (gonio measure default)", deflt),
            ("half_diff", "4 θh, 20°/60°", {"n_theta_h": 4, "theta_d_step": _D(20), "phi_d_step": _D(60), "theta_max": t}),
            ("in_plane", "10°/5°", {"theta_i_step": _D(10), "theta_o_step": _D(5), "theta_max": t}),
            ("half_diff", "6 θh, 15°/45°", {"n_theta_h": 6, "theta_d_step": _D(15), "phi_d_step": _D(45), "theta_max": t}),
            ("half_diff", "10 θh, 10°/30°", {"n_theta_h": 10, "theta_d_step": _D(10), "phi_d_step": _D(30), "theta_max": t}),
            ("grid", "30°/90°", {"theta_step": _D(30), "phi_step": _D(90), "theta_max": t}),
            ("grid", "20°/60°", {"theta_step": _D(20), "phi_step": _D(60), "theta_max": t}),
            ("isotropic", "20°/45°", {"theta_step": _D(20), "phi_step": _D(45), "theta_max": t}),
            ("isotropic", "10°/30°", {"theta_step": _D(10), "phi_step": _D(30), "theta_max": t})]
    return rows[:3] if quick else rows


def plan_table(quick: bool = False) -> Table:
    """Lab time vs BRDF error of uniform plans (simulated sessions end to end) and adaptive plans."""
    from gonio.plan.generators import make_plan

    from gonio.plan.adaptive import relative_rms

    f_truth = truth()
    wi, wo = eval_directions()
    f_true = f_truth.eval(wi, wo)
    t = Table(f"plan density and kind: lab time vs BRDF error ({MATERIAL['model']} with a narrow lobe, "
              f"simulated sessions at {RESOLUTION[0]}×{RESOLUTION[1]}, fitted {MATERIAL['model']})",
              ["plan", "parameters", "poses", "lab s", "lab vs default", "wall s", "usable samples",
               "sample rel RMS err", "BRDF rel RMS err", "err vs default", "fit s"], baseline=1, default=1)
    found = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (kind, label, params) in enumerate(_plans(quick)):
            plan = make_plan(kind, seed=0, **params)
            try:
                result, wall, s = simulate(plan, Path(tmp) / f"p{i}")
            except Exception as exc:  # a crashing session is a finding: say so, keep the other rows
                if i == 1:
                    raise  # the default session is every row's baseline
                t.notes.append(f"{kind} {label} ({len(plan)} poses): the session failed, no row: "
                               f"{type(exc).__name__}: {exc}")
                continue
            good = s.good()
            err, fit_s = fit_error(s, wi, wo, f_true)
            found.append((kind, label, len(plan), result, wall, len(good),
                          relative_rms(good.f, f_truth.eval(good.wi, good.wo)), err, fit_s, good, plan))
    base = next(r for r in found if "default" in r[1])
    t.baseline = t.default = found.index(base)
    for kind, label, n, result, wall, n_good, s_err, err, fit_s, *_ in found:
        t.add(kind, label, n, result.lab_time, result.lab_time / base[3].lab_time, wall, n_good, s_err, err,
              err / base[7], fit_s)
    t.notes.append("BRDF error: ‖fitted − true‖ / ‖true‖ over 20,000 random direction pairs with θi, θo ≤ "
                   f"{THETA_MAX_DEG:g}° (uniform in solid angle); sample error: the session's unflagged samples "
                   "against the true BRDF at their directions. Lab time includes device checks, darks and the "
                   f"light's warm-up ({overhead_lab(base[3]):.0f} s of the default session).")
    for row in _adaptive_rows(base[10], base[3], base[9], wi, wo, f_true, quick):
        t.add(*row)
    t.notes.append("rows from 'planner callback' on do not run sessions: they measure through the adaptive "
                   "planner's simulated measure callback (the true BRDF + Gaussian noise of the default session's "
                   "median σ/f, one sample per pose, no camera, no pose error); their 'err vs default' is against "
                   "the 'planner callback' row (the default plan's poses measured the same way). Adaptive: "
                   "gonio.plan.adaptive over an isotropic 10°/30° candidate set, lab time = the planner's account "
                   "(moves + settle + capture) + the default session's overhead. One seed per row: fits of the "
                   "two-lobe model have local minima.")
    lab0, err0 = base[3].lab_time, base[7]
    denser = [r for r in found if r[0] == "in_plane" and r[2] > base[2]]
    knee = (f"; the denser in-plane plan ({denser[0][2]} poses) costs {denser[0][3].lab_time / lab0:.2f}× the lab "
            f"time for {denser[0][7] / err0:.2f}× the error") if denser else ""
    t.why_default = (f"`gonio measure`'s plan: {base[2]} poses, {lab0:.0f} s lab, {err0:.2%} BRDF error{knee}; "
                     "sparser plans miss the narrow lobe (error × the table's ratios).")
    return t


def _adaptive_rows(default_plan, default_result, default_good, wi, wo, f_true, quick: bool):
    """Rows of adaptive plans and, as their baseline, the default plan's poses through the same callback."""
    from gonio.geometry import dirs_from_angles
    from gonio.plan.adaptive import adaptive_plan, fit_model, relative_rms
    from gonio.plan.generators import make_plan
    from gonio.plan.ordering import MotionModel
    from gonio.rig.kinematics import load_rig
    from gonio.samples import SampleSet

    rig = load_rig()
    cand = make_plan("isotropic", rig=rig, order="raster", theta_step=_D(10), phi_step=_D(30),
                     theta_max=_D(THETA_MAX_DEG))
    f_truth = truth()
    noise = float(np.median(default_good.sigma / np.maximum(np.abs(default_good.f), 1e-12)))
    rng = np.random.default_rng(0)

    def measure(poses):
        a, b = dirs_from_angles(*poses.T)
        f = f_truth.eval(a, b)
        sig = noise * f + 1e-5
        return SampleSet(a, b, f + rng.normal(size=f.shape) * sig, sig)

    over = overhead_lab(default_result)
    budget0 = default_result.lab_time - over
    pose_time = cand.capture.pose_time()
    fit = fit_model(MATERIAL["model"], n_starts=4)
    t0 = time.perf_counter()
    ref = fit(measure(default_plan.poses))
    secs = time.perf_counter() - t0
    default_err = relative_rms(ref.eval(wi, wo), f_true)
    rows = [("in_plane, planner callback", "default plan's poses", len(default_plan), default_result.lab_time, 1.0,
             secs, len(default_plan), noise, default_err, 1.0, secs)]
    for mult in ((1.0,) if quick else (0.5, 1.0, 2.0)):
        budget = mult * budget0
        t0 = time.perf_counter()
        res = adaptive_plan(cand, measure, fit, motion=MotionModel.from_rig(rig),
                            target_error=0.0, lab_budget=budget, n_initial=max(8, int(budget / pose_time / 3)),
                            batch=8, seed=0)
        wall = time.perf_counter() - t0
        err = relative_rms(res.model.eval(wi, wo), f_true)
        lab = res.lab_time + over
        rows.append(("adaptive", f"{mult:g}× default's pose budget", len(res.plan), lab,
                     lab / default_result.lab_time, wall, len(res.samples), float("nan"), err, err / default_err,
                     float("nan")))
    return rows


def _brackets(quick: bool):
    from gonio.plan.plan import CaptureSettings

    rows = [("1 exposure (16 ms) × 1 frame", CaptureSettings(exposures=(0.016,), frames=1)),
            ("1 exposure (16 ms) × 4 frames", CaptureSettings(exposures=(0.016,), frames=4)),
            ("3 exposures × 1 frame", CaptureSettings(frames=1)),
            ("3 exposures × 2 frames", CaptureSettings()),
            ("3 exposures × 4 frames", CaptureSettings(frames=4)),
            ("5 exposures (1–256 ms) × 2 frames", CaptureSettings(exposures=(0.001, 0.004, 0.016, 0.064, 0.256)))]
    return [rows[0], rows[3], rows[4]] if quick else rows


def capture_table(quick: bool = False) -> Table:
    """Lab time vs noise of the exposure bracket and the frames averaged, on one plan."""
    from gonio.cli.measure import DEFAULT_PLAN, DEFAULT_PLAN_PARAMS
    from gonio.plan.adaptive import relative_rms
    from gonio.plan.generators import make_plan
    from gonio.plan.plan import CaptureSettings

    params = ({"theta_i_step": _D(30), "theta_o_step": _D(30), "theta_max": _D(60)} if quick
              else {k: _D(v) for k, v in DEFAULT_PLAN_PARAMS.items()})
    plan = make_plan(DEFAULT_PLAN, seed=0, **params)
    f_truth = truth()
    rows = _brackets(quick)
    default = next(i for i, (_, c) in enumerate(rows) if c == CaptureSettings())
    t = Table(f"exposure bracket and frames averaged: lab time vs noise ({DEFAULT_PLAN} plan, {len(plan)} poses, "
              f"{MATERIAL['model']} with a narrow lobe)",
              ["capture", "capture s/pose", "lab s/pose", "lab s", "lab vs baseline", "usable samples", "flagged %",
               "median σ/f", "σ/f vs baseline", "sample rel RMS err"], baseline=0, default=default)
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, cap) in enumerate(rows):
            result, _, s = simulate(replace(plan, capture=cap), Path(tmp) / f"c{i}")
            good = s.good()
            rel = float(np.median(good.sigma / np.maximum(np.abs(good.f), 1e-12)))
            if i == 0:
                lab0, rel0 = result.lab_time, rel
            per_pose = (result.lab_time - overhead_lab(result)) / max(result.measured, 1)
            t.add(label, cap.capture_time(), per_pose, result.lab_time, result.lab_time / lab0, len(good),
                  100.0 * (1 - len(good) / max(len(s), 1)), rel, rel / rel0,
                  relative_rms(good.f, f_truth.eval(good.wi, good.wo)))
    t.why_default = ("the knee: the 3-exposure bracket (4, 16, 64 ms) is what keeps the narrow lobe's peak and the "
                     "diffuse tail usable (a single exposure loses most samples: flagged %); averaging frames lowers "
                     "σ/f only as 1/√frames while capture time grows linearly, and the sample error, dominated by "
                     "pose and calibration error, does not improve past 2 frames.")
    t.notes.append("lab s/pose: move + settle + darks + capture, without the session's fixed overhead "
                   f"(device checks, first darks, warm-up: {overhead_lab(result):.0f} s).")
    t.notes.append("σ/f: the pipeline's standard uncertainty over the value, median over unflagged samples; sample "
                   "error: unflagged samples against the true BRDF at their directions (includes pose and "
                   "calibration errors, which no amount of averaging removes). flagged: saturated in every "
                   "exposure, low signal, no board, ...")
    return t


def merl_table(quick: bool = False) -> Table:
    """Speed vs error of :meth:`gonio.io.merl.MerlTable.lookup`, nearest vs trilinear, on tables of
    two analytic materials tabulated at the cell centres."""
    from gonio.brdf import make
    from gonio.io.merl import MerlTable, cell_directions
    from gonio.plan.adaptive import relative_rms
    from sim.rig import DEFAULT_MATERIAL

    n = 100_000 if quick else 1_000_000
    wi, wo = eval_directions(n, 80.0, seed=1)
    cwi, cwo, above = cell_directions()
    t = Table(f"MERL lookup: nearest vs trilinear ({n:,} random direction pairs, θ ≤ 80°)",
              ["material", "method", "Mlookups/s", "speed vs nearest", "rel RMS err", "median rel err",
               "p99 rel err"], baseline=0, default=1)
    mats = [("sim default (GGX α 0.25)", make(DEFAULT_MATERIAL["model"], **DEFAULT_MATERIAL["params"])),
            ("narrow lobe (GGX α 0.1 + 0.3)", truth())]
    for label, m in mats:
        table = MerlTable(np.where(above[..., None], m.eval(cwi, cwo), np.nan))
        f = m.eval(wi, wo)
        ok = f.max(axis=-1) > 1e-6 * f.max()
        for method in ("nearest", "trilinear"):
            secs = time_call(lambda: table.lookup(wi, wo, method=method), min_time=0.05 if quick else 0.3, repeat=2)
            g = table.lookup(wi, wo, method=method)
            if method == "nearest":
                s0 = secs
            rel = np.abs(g[ok] - f[ok]) / f[ok]
            t.add(label, method, n / secs / 1e6, s0 / secs, relative_rms(g, f), float(np.median(rel)),
                  float(np.quantile(rel, 0.99)))
    t.why_default = ("`MerlTable.lookup` defaults to trilinear: the knee — an order of magnitude less error than "
                     "nearest for a constant factor in time, still millions of lookups per second; nearest "
                     "(`method=\"nearest\"`) is the MERL reference lookup, reproducing published values cell for cell.")
    t.notes.append("tables: each material evaluated at the cell centres (φh = 0); errors against the analytic model "
                   "at the query directions (relative errors where f > 1e-6 of the maximum).")
    return t


def precision_table(brdf_tables: list[Table]) -> Table | None:
    """float64 vs float32 summary over the models of :mod:`benchmarks.bench_brdf`'s speed table."""
    src = next((x for x in brdf_tables if "float32 Meval/s" in x.columns), None)
    if src is None or not src.rows:
        return None
    c = {name: i for i, name in enumerate(src.columns)}
    f64 = np.array([r[c["float64 Meval/s"]] for r in src.rows], float)
    f32 = np.array([r[c["float32 Meval/s"]] for r in src.rows], float)
    err = np.array([r[c["f32 max rel err"]] for r in src.rows], float)
    p99 = np.array([r[c["f32 p99 rel err"]] for r in src.rows], float)
    gm = lambda x: float(np.exp(np.mean(np.log(x))))  # noqa: E731 - geometric mean of rates
    t = Table(f"float64 vs float32 BRDF evaluation (summary of the {len(src.rows)} models above)",
              ["precision", "Meval/s (geometric mean)", "speed vs float64", "min speed-up", "max speed-up",
               "worst max rel err", "worst p99 rel err"], baseline=0, default=0,
              why_default="float64 (the project's numerics rule): float32's gain is modest and its error "
                          "(up to the worst column) exceeds the pipeline's typical uncertainty on some models.")
    t.add("float64", gm(f64), 1.0, 1.0, 1.0, 0.0, 0.0)
    t.add("float32", gm(f32), gm(f32 / f64), float((f32 / f64).min()), float((f32 / f64).max()),
          float(err.max()), float(p99.max()))
    return t


def run(quick: bool = False) -> list[Table]:
    return [plan_table(quick), capture_table(quick), merl_table(quick)]
