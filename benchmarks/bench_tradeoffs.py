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
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from benchmarks.common import Size, Table, round_time, size, time_call

#: The simulated sample of the plan and capture trades: Lambert + a broad and a narrow GGX lobe.
MATERIAL = {"model": "lambert+2ggx",
            "params": {"diffuse.albedo": [0.25, 0.2, 0.15], "lobe1.ks": 0.3, "lobe1.alpha": 0.3,
                       "lobe2.ks": 0.3, "lobe2.alpha": 0.1}}
#: Camera resolution of the simulated sessions (the `gonio measure --sim` default) ...
RESOLUTION = (320, 240)
#: ... and at the smoke size (`gonio bench --smoke`, the test suite's bench smoke: its numbers mean little): 56 % of
#: the pixels, the smallest camera at which the simulated board is still found (tests/session/conftest.py).
SMOKE_RESOLUTION = (240, 180)


def resolution(quick=False) -> tuple[int, int]:
    """The simulated camera of the plan and capture tables at this size (:data:`RESOLUTION`, :data:`SMOKE_RESOLUTION`)."""
    return SMOKE_RESOLUTION if size(quick) is Size.SMOKE else RESOLUTION
#: Largest zenith angle of the plans and of the directions the BRDF error is averaged over.
THETA_MAX_DEG = 70.0
_D = math.radians


def fitted_model(quick=False) -> str:
    """The model the plan table fits (and its adaptive sessions plan with): :data:`MATERIAL`'s; at the smoke
    size (``gonio bench --smoke``) one lobe fewer, whose fits take a tenth of the time (a smoke run checks that
    the table is made, its errors mean little)."""
    return "lambert+ggx" if size(quick) is Size.SMOKE else MATERIAL["model"]


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


#: Sessions already simulated in this process, by plan (:func:`simulate`): the trades that run the same plan
#: (the plan table's 30°/30° in-plane row is the capture table's automatic-exposure row) measure it once.
_SIMULATED: dict[tuple, tuple] = {}


def _plan_key(plan, camera) -> tuple:
    return plan.generator, np.asarray(plan.poses).tobytes(), repr(plan.capture), tuple(camera)


def simulate(plan, out: Path, camera: tuple[int, int] = RESOLUTION):
    """Run ``plan`` on the simulated rig rendering :data:`MATERIAL` with a ``camera`` (width, height) camera:
    ``(RunResult, wall s, SampleSet)``. The simulator is seeded, so a plan simulated before in this process (on the
    same camera) is not run again: its result, wall time (of the run that measured it) and samples are returned
    again."""
    from benchmarks.bench_session import _session
    from gonio.store.directory import load_session

    key = _plan_key(plan, camera)
    if key not in _SIMULATED:
        result, wall = _session(plan, camera, out, material=MATERIAL)
        _SIMULATED[key] = (result, wall, load_session(out)[1])
    return _SIMULATED[key]


def overhead_lab(result) -> float:
    """Lab seconds of a session not spent on its poses (device checks, darks, the light's warm-up)."""
    return result.lab_time - sum(t["move_lab"] + t["dark_lab"] + t["capture_lab"] for t in result.timings)


def fit_error(samples, wi, wo, f_true, n_starts: int = 4, model: str = MATERIAL["model"]) -> tuple[float, float]:
    """Fit ``model`` (default :data:`MATERIAL`'s) to ``samples``: ``(relative RMS error over (wi, wo), fit
    seconds)``."""
    from gonio.fit import fit
    from gonio.plan.adaptive import relative_rms

    t0 = time.perf_counter()
    res = fit(samples, model, n_starts=n_starts)
    secs = time.perf_counter() - t0
    return relative_rms(res.model.eval(wi, wo), f_true), secs


@dataclass(frozen=True)
class PlanRow:
    """One measured row of :func:`plan_table`: a simulated session and the fit of its samples."""

    kind: str
    label: str
    poses: int
    lab: float  #: the session's lab seconds, overheads included
    wall: float
    usable: int
    sample_err: float
    err: float  #: BRDF relative RMS error of the fitted model
    fit_s: float
    default: bool = False


def _uniform_plans(quick: bool) -> list[tuple[str, str, dict, bool]]:
    """``(kind, label, params, is_default)`` of the uniform plans: each generator at a few densities, with
    the in-plane and half/difference densities around the default and around the knee."""
    from gonio.cli.measure import DEFAULT_PLAN, default_plan_params

    deflt = default_plan_params(DEFAULT_PLAN)
    t = _D(THETA_MAX_DEG)

    def ip(a, b, tmax=THETA_MAX_DEG):
        return {"theta_i_step": _D(a), "theta_o_step": _D(b), "theta_max": _D(tmax)}

    def hd(n, td, pd):
        return {"n_theta_h": n, "theta_d_step": _D(td), "phi_d_step": _D(pd), "theta_max": t}

    rows = [("in_plane", "30°/30°, θ ≤ 60°", ip(30, 30, 60), False),
            (DEFAULT_PLAN, f"{_params_label(DEFAULT_PLAN, deflt)} (gonio measure default)", deflt, True),
            ("half_diff", "4 θh, 20°/60°", hd(4, 20, 60), False),
            ("in_plane", "20°/20°", ip(20, 20), False),
            ("in_plane", "20°/10°", ip(20, 10), False),
            ("in_plane", "15°/10°", ip(15, 10), False),
            ("in_plane", "10°/5°", ip(10, 5), False),
            ("half_diff", "6 θh, 20°/60°", hd(6, 20, 60), False),
            ("half_diff", "5 θh, 15°/45°", hd(5, 15, 45), False),
            ("half_diff", "6 θh, 15°/45°", hd(6, 15, 45), False),
            ("half_diff", "7 θh, 15°/45°", hd(7, 15, 45), False),
            ("half_diff", "8 θh, 15°/45°", hd(8, 15, 45), False),
            ("half_diff", "10 θh, 10°/30°", hd(10, 10, 30), False),
            ("grid", "30°/90°", {"theta_step": _D(30), "phi_step": _D(90), "theta_max": t}, False),
            ("grid", "20°/60°", {"theta_step": _D(20), "phi_step": _D(60), "theta_max": t}, False),
            ("isotropic", "20°/45°", {"theta_step": _D(20), "phi_step": _D(45), "theta_max": t}, False)]
    # the default's parameters appear once (as the default row)
    rows = [r for r in rows if r[3] or not (r[0] == DEFAULT_PLAN and _same_params(r[2], deflt))]
    return rows[:2] if size(quick) is Size.SMOKE else rows[:3] if quick else rows


def _same_params(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(math.isclose(a[k], b[k], rel_tol=1e-9) for k in a)


def _params_label(kind: str, p: dict) -> str:
    """A row label from a plan's parameters, in the style of the other rows."""
    deg = {k: math.degrees(v) for k, v in p.items() if k != "n_theta_h"}
    if kind == "half_diff":
        return f"{p['n_theta_h']} θh, {deg['theta_d_step']:g}°/{deg['phi_d_step']:g}°"
    if kind == "in_plane":
        return f"{deg['theta_i_step']:g}°/{deg['theta_o_step']:g}°"
    return ", ".join(f"{k} {v:g}°" for k, v in deg.items())


def adaptive_args(lab_budget: float, target_error: float, quick: bool = False):
    """The parsed options of ``gonio measure --sim --plan adaptive`` fitting :data:`MATERIAL`'s model with
    ``--lab-budget`` / ``--target-error`` (everything else the CLI's defaults; quick: a small session, smoke:
    one round after the coarse one)."""
    from gonio.cli.main import build_parser

    argv = ["measure", "--sim", "--plan", "adaptive", "--model", fitted_model(quick),
            "--lab-budget", repr(float(lab_budget)), "--target-error", repr(float(target_error))]
    if quick:
        argv += ["--coarse", "6", "--batch", "6", "--max-rounds", "1" if size(quick) is Size.SMOKE else "2"]
    return build_parser().parse_args(argv)


def simulate_adaptive(args, out: Path, n_starts: int | None = None, camera: tuple[int, int] = RESOLUTION):
    """Run the adaptive session ``args`` describe (:func:`gonio.cli.plan.adaptive_from_args`, then
    :class:`gonio.session.adaptive.AdaptiveSession` on the simulated rig rendering :data:`MATERIAL`):
    ``(AdaptiveSessionResult, wall s, SampleSet)``. ``n_starts``: the rounds' fits' starts instead of the
    CLI's (the quick tier's 1, as its uniform rows' fits)."""
    from dataclasses import replace

    from benchmarks.bench_session import _adaptive_session
    from gonio.cli.plan import adaptive_from_args
    from gonio.rig.kinematics import load_rig

    candidates, settings, spec = adaptive_from_args(args, load_rig(), source="bench --plan adaptive")
    if n_starts is not None:
        spec = replace(spec, n_starts=n_starts)
    return _adaptive_session(candidates, settings, spec, camera, out, material=MATERIAL)


def _adaptive_runs(default: PlanRow, overhead: float, quick: bool) -> list[tuple[str, object]]:
    """``(label, args)`` of the adaptive sessions: lab budgets of the default session's pose time (its lab
    time without the session's start-up overhead) and 1.5× it, and one run to the CLI's target error."""
    from gonio.cli.plan import ADAPTIVE_TARGET

    budget = max(default.lab - overhead, 1.0)
    if quick:
        rounds = 1 if size(quick) is Size.SMOKE else 2
        return [(f"budget 1× default's ({budget:.0f} s), coarse 6, 6 a round, ≤ {rounds} round{'s' * (rounds > 1)}",
                 adaptive_args(budget, 0.0, quick=quick))]
    return [(f"budget 1× default's ({budget:.0f} s)", adaptive_args(budget, 0.0)),
            (f"budget 1.5× default's ({1.5 * budget:.0f} s)", adaptive_args(1.5 * budget, 0.0)),
            (f"target error {ADAPTIVE_TARGET:g}, budget ≤ 3× default's", adaptive_args(3 * budget, ADAPTIVE_TARGET))]


def pareto_front(lab, err) -> np.ndarray:
    """Indices of the rows no other row beats in both lab time and error (ties kept), by lab time."""
    lab, err = np.asarray(lab, float), np.asarray(err, float)
    ok = np.isfinite(lab) & np.isfinite(err)
    idx = [i for i in np.flatnonzero(ok)
           if not np.any(ok & (lab <= lab[i]) & (err <= err[i]) & ((lab < lab[i]) | (err < err[i])))]
    return np.array(sorted(idx, key=lambda i: (lab[i], err[i])), dtype=np.int64)


def knee(lab, err) -> int:
    """Index of the knee of the lab time vs error trade: the Pareto-front row farthest below the chord
    from the cheapest to the most accurate front row, in (lab time, log error) scaled to the unit square
    (the "Kneedle" criterion, Satopää et al., *Finding a "Kneedle" in a Haystack*, ICDCS Workshops 2011).
    Ties (a front of one or two rows has no point below its chord) go to the more accurate row."""
    front = pareto_front(lab, err)
    if len(front) == 0:
        raise ValueError("no row with a finite lab time and error")
    x = np.asarray(lab, float)[front]
    y = np.log(np.asarray(err, float)[front])
    xs = (x - x[0]) / (x[-1] - x[0]) if x[-1] > x[0] else np.zeros_like(x)
    ys = (y - y[-1]) / (y[0] - y[-1]) if y[0] > y[-1] else np.zeros_like(y)
    d = 1.0 - xs - ys
    return int(front[np.flatnonzero(d >= d.max() - 1e-12)[-1]])


def why_default(rows: list[PlanRow]) -> str:
    """The table's ``why_default``, computed from its rows: the default, whether the Pareto front holds
    it (or which row dominates it), and the knee relative to the default."""
    lab = [r.lab for r in rows]
    err = [r.err for r in rows]
    d = next(i for i, r in enumerate(rows) if r.default)
    r0 = rows[d]

    def name(r):
        return f"{r.kind} {r.label.split(':')[0].replace(' (gonio measure default)', '')} ({r.poses} poses)"

    def vs(r):
        return f"{r.lab / r0.lab:.2f}× the default's lab time for {r.err / r0.err:.2f}× its error"

    front, skip = pareto_front(lab, err), []
    text = f"`gonio measure`'s plan, {name(r0)}: {r0.lab:.0f} s lab, {r0.err:.2%} BRDF error. "
    if d in front:
        text += "It is on the lab time / error Pareto front of these sessions. "
    else:
        dom = [i for i in range(len(rows)) if lab[i] <= lab[d] and err[i] <= err[d]
               and (lab[i] < lab[d] or err[i] < err[d])]
        best = min(dom, key=lambda i: err[i])
        skip.append(best)
        text += f"It is **not** on the Pareto front: {name(rows[best])} beats it in both ({vs(rows[best])}). "
    k = knee(lab, err)
    if k == d:
        text += "It is the knee of the front (farthest below the chord from the cheapest to the most accurate plan)."
    else:
        text += (f"The knee of the front (farthest below the chord from the cheapest to the most accurate plan, "
                 f"lab time vs log error) is {name(rows[k])}: {vs(rows[k])}.")
    cheaper = [i for i in front if lab[i] < lab[d] and i != k and i not in skip]
    if cheaper:
        c = cheaper[-1]
        text += f" The next cheaper plan on the front, {name(rows[c])}: {vs(rows[c])}."
    return text


def _session_row(kind, label, n, result, wall, s, wi, wo, f_true, f_truth, default=False, n_starts=4,
                 model=MATERIAL["model"]) -> PlanRow:
    from gonio.plan.adaptive import relative_rms

    good = s.good()
    err, fit_s = fit_error(s, wi, wo, f_true, n_starts, model)
    return PlanRow(kind, label, n, result.lab_time, wall, len(good),
                   relative_rms(good.f, f_truth.eval(good.wi, good.wo)), err, fit_s, default)


def plan_table(quick: bool = False) -> Table:
    """Lab time vs BRDF error of uniform and adaptive plans, every row a simulated session end to end
    fitted the same way; the default's place relative to the knee is computed from the rows."""
    from gonio.plan.generators import make_plan
    from sim import compiled

    f_truth = truth()
    wi, wo = eval_directions()
    f_true = f_truth.eval(wi, wo)
    model = fitted_model(quick)
    t = Table(f"plan density and kind: lab time vs BRDF error ({MATERIAL['model']} with a narrow lobe, "
              f"simulated sessions at {resolution(quick)[0]}×{resolution(quick)[1]}, fitted {model})",
              ["plan", "parameters", "poses", "lab s", "lab vs default", "wall s", "usable samples",
               "sample rel RMS err", "BRDF rel RMS err", "err vs default", "fit s"], baseline=1, default=1)
    rows: list[PlanRow] = []
    overhead, starts = None, 1 if quick else 4
    uniform = [(kind, label, make_plan(kind, seed=0, **params), is_default)
               for kind, label, params, is_default in _uniform_plans(quick)]
    # the simulated camera's compiled paths from the first frame when the table's sessions together would cost NumPy
    # more than their price (sim.compiled.expect: each session alone may forecast less; the same frames either way)
    w, h = resolution(quick)
    compiled.expect(w * h * 3, sum(len(plan) for _, _, plan, _ in uniform), sessions=len(uniform))
    with tempfile.TemporaryDirectory() as tmp:
        for i, (kind, label, plan, is_default) in enumerate(uniform):
            try:
                result, wall, s = simulate(plan, Path(tmp) / f"p{i}", resolution(quick))
                rows.append(_session_row(kind, label, len(plan), result, wall, s, wi, wo, f_true, f_truth, is_default,
                                         starts, model))
            except Exception as exc:  # a crashing session is a finding: say so, keep the other rows
                if is_default:
                    raise  # the default session is every row's baseline
                t.notes.append(f"{kind} {label} ({len(plan)} poses): the session failed, no row: "
                               f"{type(exc).__name__}: {exc}")
                continue
            if is_default:
                overhead = overhead_lab(result)
        base = next(r for r in rows if r.default)
        for j, (label, args) in enumerate(_adaptive_runs(base, overhead, quick)):
            try:
                result, wall, s = simulate_adaptive(args, Path(tmp) / f"a{j}", n_starts=1 if quick else None,
                                                    camera=resolution(quick))
                n = sum(r["n_poses"] for r in result.rounds)
                rows.append(_session_row("adaptive", f"{label}: {len(result.rounds)} rounds, stop: {result.stop}",
                                         n, result, wall, s, wi, wo, f_true, f_truth, n_starts=starts, model=model))
            except Exception as exc:
                t.notes.append(f"adaptive {label}: the session failed, no row: {type(exc).__name__}: {exc}")
    rows.sort(key=lambda r: (r.kind != base.kind, r.kind == "adaptive", r.kind, r.lab))
    t.baseline = t.default = rows.index(base)
    for r in rows:
        t.add(r.kind, r.label, r.poses, r.lab, r.lab / base.lab, r.wall, r.usable, r.sample_err, r.err,
              r.err / base.err, r.fit_s)
    t.why_default = why_default(rows)
    t.notes.append("BRDF error: ‖fitted − true‖ / ‖true‖ over 20,000 random direction pairs with θi, θo ≤ "
                   f"{THETA_MAX_DEG:g}° (uniform in solid angle) of {model} fitted to all of a session's "
                   f"samples (gonio.fit, {starts} starts); sample error: the session's unflagged samples against the true "
                   "BRDF at their directions. Lab time: the session's simulated clock, including device checks, "
                   f"darks and the light's warm-up ({overhead:.0f} s of the default session). One seed per row: fits "
                   "of the two-lobe model have local minima, so neighbouring densities can differ by more than "
                   "their sampling explains.")
    t.notes.append("adaptive rows: `gonio measure --sim --plan adaptive --model "
                   f"{model} --lab-budget S --target-error E` (gonio.cli.plan.adaptive_from_args + "
                   "gonio.session.adaptive.AdaptiveSession; CLI defaults otherwise: the isotropic 10°/30° "
                   "candidates, a coarse round of 24, 16 poses a round, each round fitted with "
                   f"{'1 start (quick run; the CLI: 3)' if quick else '3 starts'}). The budget "
                   "counts the poses and each round's light check, not the session's start-up, so its lab time "
                   "is comparable with a uniform session's; target error 0 runs to the budget. The rounds' fits "
                   f"are in the wall time; the BRDF error is the same {starts}-start fit as the uniform rows'.")
    return t


def _brackets(quick: bool):
    from gonio.plan.plan import CaptureSettings

    def fixed(**kw):
        return CaptureSettings(auto_exposure=False, **kw)

    rows = [("fixed: 1 exposure (16 ms) × 1 frame", fixed(exposures=(0.016,), frames=1)),
            ("fixed: 1 exposure (16 ms) × 4 frames", fixed(exposures=(0.016,), frames=4)),
            ("fixed: 3 exposures × 1 frame", fixed(frames=1)),
            ("fixed: 3 exposures (4, 16, 64 ms) × 2 frames", fixed(frames=2)),
            ("fixed: 3 exposures × 4 frames", fixed(frames=4)),
            ("fixed: 5 exposures (1–256 ms) × 2 frames", fixed(exposures=(0.001, 0.004, 0.016, 0.064, 0.256),
                                                              frames=2)),
            ("automatic exposure per pose", CaptureSettings())]
    return [rows[0], rows[6]] if size(quick) is Size.SMOKE else [rows[0], rows[3], rows[6]] if quick else rows


def capture_table(quick: bool = False) -> Table:
    """Lab time vs noise of the exposure bracket and the frames averaged, on one plan."""
    from gonio.cli.measure import DEFAULT_PLAN, default_plan_params
    from gonio.plan.adaptive import relative_rms
    from gonio.plan.generators import make_plan
    from gonio.plan.plan import CaptureSettings

    kind, params = (("in_plane", {"theta_i_step": _D(30), "theta_o_step": _D(30), "theta_max": _D(60)}) if quick
                    else (DEFAULT_PLAN, default_plan_params(DEFAULT_PLAN)))
    plan = make_plan(kind, seed=0, **params)
    f_truth = truth()
    rows = _brackets(quick)
    default = next(i for i, (_, c) in enumerate(rows) if c == CaptureSettings())
    t = Table(f"exposure bracket and frames averaged: lab time vs noise ({kind} plan, {len(plan)} poses, "
              f"{MATERIAL['model']} with a narrow lobe)",
              ["capture", "capture s/pose", "lab s/pose", "lab s", "lab vs baseline", "usable samples", "flagged %",
               "median σ/f", "σ/f vs baseline", "sample rel RMS err"], baseline=0, default=default)
    measured = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, cap) in enumerate(rows):
            result, _, s = simulate(replace(plan, capture=cap), Path(tmp) / f"c{i}", resolution(quick))
            good = s.good()
            if len(good):
                rel = float(np.median(good.sigma / np.maximum(np.abs(good.f), 1e-12)))
                err = relative_rms(good.f, f_truth.eval(good.wi, good.wo))
            else:  # every sample flagged (a single exposure that saturates the white reference): no statistics
                rel = err = float("nan")
            measured.append((label, cap, result, len(good), 100.0 * (1 - len(good) / max(len(s), 1)), rel, err))
    # the baseline is the first row that measured something: ratios against a row with no usable sample are empty
    t.baseline = next((i for i, m in enumerate(measured) if m[3]), 0)
    lab0, rel0 = measured[t.baseline][2].lab_time, measured[t.baseline][5]
    for label, cap, result, n_good, flagged, rel, err in measured:
        per_pose = (result.lab_time - overhead_lab(result)) / max(result.measured, 1)
        t.add(label, cap.capture_time(), per_pose, result.lab_time, result.lab_time / lab0, n_good, flagged, rel,
              rel / rel0, err)
    if any(not m[3] for m in measured):
        t.notes.append("rows with 0 usable samples: every pose flagged (e.g. the white reference saturated in the "
                       "only exposure), so they have no σ/f or error; the baseline is the first row with samples.")
    t.why_default = ("automatic exposure (gonio.pipeline.exposure: a metering frame per pose, a bracket from the "
                     "exposure ladder that keeps the sample and the white reference in the linear range, more frames "
                     "where the SNR is low): fixed brackets either lose the narrow lobe's peak or the diffuse tail "
                     "(flagged %) or spend capture time on every pose; averaging frames lowers σ/f only as "
                     "1/√frames while capture time grows linearly, and the sample error, dominated by pose and "
                     "calibration error, does not improve past 2 frames. `--exposures`/`--frames` fix a bracket.")
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
    from gonio.io.merl import MerlTable
    from gonio.plan.adaptive import relative_rms
    from sim.rig import DEFAULT_MATERIAL

    n = 20_000 if size(quick) is Size.SMOKE else 100_000 if quick else 1_000_000
    wi, wo = eval_directions(n, 80.0, seed=1)
    t = Table(f"MERL lookup: nearest vs trilinear ({n:,} random direction pairs, θ ≤ 80°)",
              ["material", "method", "Mlookups/s", "speed vs nearest", "rel RMS err", "median rel err",
               "p99 rel err"], baseline=0, default=1)
    mats = [("sim default (GGX α 0.25)", make(DEFAULT_MATERIAL["model"], **DEFAULT_MATERIAL["params"])),
            ("narrow lobe (GGX α 0.1 + 0.3)", truth())]
    for label, m in mats:
        table = MerlTable.from_brdf(m)  # evaluated above the horizon only (NaN below, as a MERL file marks them)
        f = m.eval(wi, wo)
        ok = f.max(axis=-1) > 1e-6 * f.max()
        for method in ("nearest", "trilinear"):
            secs = time_call(lambda: table.lookup(wi, wo, method=method), min_time=round_time(quick), repeat=2)
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
