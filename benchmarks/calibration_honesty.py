"""Do the geometric calibration's stated uncertainties cover the truth, and a fit's? (issue 28)

Runs = as-built rigs × noise seeds, the rigs' errors drawn independently of :mod:`benchmarks.bench_calibration`'s
(:func:`independent_errors`: Gaussian, σ = half of :data:`sim.as_built.TOLERANCES`, clipped there, from their own
random stream). Per run, on frames rendered on the as-built rig and detected by gonio (as ``gonio calibrate
rig --sim`` does):

* the calibration: every identified parameter's signed error in units of its stated σ (coverage at 3σ, mean
  bias per parameter over the runs), the true wi error over random reachable poses after calibration (p95),
  what the calibration says of its own wi bound (:func:`gonio.rig.geocov.wi_error_p95`), and what ``gonio
  calibrate check`` would say (its short plan rendered and judged by :func:`gonio.rig.geocheck.check_geometry`,
  without the truth: a lab has none);
* with ``fit``: a measurement session on the simulated as-built rig (``gonio measure --sim --sim-as-built
  ERRORS.toml --rig CALIBRATED.toml``, a GGX material of α = :data:`ALPHA`) fitted with the microfacet model:
  is the true α within 2σ of the fitted one?
"""

from __future__ import annotations

import math

import numpy as np

#: The GGX roughness of the material measured on the as-built rigs.
ALPHA = 0.1


def independent_errors(rig, seed: int):
    """An as-built rig's errors independent of :meth:`sim.as_built.AsBuilt.from_seed`'s (module docstring)."""
    from gonio.rig.chain import ARM_FIELDS, CAMERA_FIELDS, ChainErrors
    from sim.as_built import TOLERANCES, AsBuilt

    rng = np.random.default_rng([int(seed), 28])

    def draw(fields):
        return {k: float(np.clip(rng.normal(0.0, TOLERANCES[k] / 2), -TOLERANCES[k], TOLERANCES[k])) for k in fields}

    e = ChainErrors(light=draw(ARM_FIELDS), camera=draw(CAMERA_FIELDS),
                    sample_height_mm=float(np.clip(rng.normal(0, TOLERANCES["sample_height_mm"] / 2),
                                                   -TOLERANCES["sample_height_mm"], TOLERANCES["sample_height_mm"])))
    return AsBuilt(rig, e, source=f"independent seed {seed}")


def _errors_toml(errors) -> str:
    d = errors.to_dict()
    lines = [f"sample_height_mm = {d['sample_height_mm']!r}"]
    for k in ("light", "camera"):
        lines.append(f"[{k}]")
        lines += [f"{f} = {v!r}" for f, v in d[k].items()]
    return "\n".join(lines) + "\n"


def run_result(source: str, options: dict) -> dict:
    """One run ``"RIG:NOISE"`` (module docstring); a module-level function of (str, dict) -> dict for
    :func:`gonio.batch.run_batch`."""
    import tempfile
    from pathlib import Path

    from gonio.rig.chain import angle_between_deg
    from gonio.rig.geocal import calibrate_geometry, calibrated_rig_text
    from gonio.rig.geocheck import check_geometry
    from gonio.rig.geocov import wi_error_p95, workspace_joints
    from gonio.rig.kinematics import load_rig, read_rig_text
    from sim.as_built import render_observations

    rig_seed, noise = (int(x) for x in source.split(":"))
    rig = load_rig("default")
    ab = independent_errors(rig, rig_seed)
    cams, highs, refused = render_observations(ab, options["plan"], noise)
    res = calibrate_geometry(rig, cams, highs)
    text, _ = read_rig_text("default")
    cal_text = calibrated_rig_text(text, res)
    cal = load_rig(text=cal_text, source="calibrated")
    truth = ab.errors.folded().vector()
    z = {}
    for (name, v, s, unit), t in zip(res.table(), truth):
        if not unit.startswith("not"):
            z[name] = (v - t) / s
    jw = workspace_joints(rig, 2000, seed=11)
    wi_true = float(np.percentile(angle_between_deg(cal.directions(jw)[0], ab.directions(jw)[0]), 95))
    ccams, chighs, _ = render_observations(ab, options["check_plan"], noise + 7919)
    chk = check_geometry(cal, ccams, chighs)
    out = {"run": source, "z": z, "wi_p95": wi_true, "bound": wi_error_p95(cal), "check_ok": chk.ok,
           "rejected": len(res.rejected), "frames": (len(cams), len(highs), len(refused))}
    if options.get("fit"):
        from gonio.api import fit as fit_source
        from gonio.cli.main import main

        with tempfile.TemporaryDirectory() as tmp:
            t = Path(tmp)
            (t / "cal.toml").write_text(cal_text)
            (t / "errors.toml").write_text(_errors_toml(ab.errors))
            (t / "mat.toml").write_text(f'model = "microfacet"\n[params]\nkd = [0.3, 0.12, 0.06]\nks = 0.8\n'
                                        f'alpha = {ALPHA}\nf0 = 0.04\ndistribution = "ggx"\n')
            code = main(["measure", "--sim", "--quiet", "--sim-as-built", str(t / "errors.toml"), "--rig",
                         str(t / "cal.toml"), "--material", str(t / "mat.toml"), "--seed", str(noise),
                         "--out", str(t / "s")])
            if code != 0:
                raise RuntimeError(f"run {source}: gonio measure exited {code}")
            r = fit_source(str(t / "s"), model="microfacet")
            a = r.params["alpha"]
            sa = r.uncertainty["alpha"]
            out["alpha"] = (float(np.ravel(a)[0]), float(np.ravel(sa)[0]))
    return out


def summary(rows: list[dict]) -> dict:
    """Coverage, mean bias per parameter, wi p95 per run, check flags, α coverage over ``rows``."""
    names = sorted({n for r in rows for n in r["z"]})
    zs = {n: np.array([r["z"][n] for r in rows if n in r["z"]]) for n in names}
    allz = np.concatenate(list(zs.values()))
    bias = {n: float(np.mean(v)) for n, v in zs.items()}
    wi = np.array([r["wi_p95"] for r in rows])
    over = wi > 0.25
    flagged = np.array([not r["check_ok"] for r in rows])
    out = {"runs": len(rows), "n_params": int(allz.size), "z": zs, "within_3sigma": float(np.mean(np.abs(allz) < 3)),
           "within_1sigma": float(np.mean(np.abs(allz) < 1)), "bias": bias,
           "worst_bias": max(bias.items(), key=lambda kv: abs(kv[1])) if bias else ("", math.nan),
           "outside_3sigma": sorted(((r["run"], n, float(z)) for r in rows for n, z in r["z"].items() if abs(z) >= 3),
                                    key=lambda t: -abs(t[2])),
           "wi_p95": wi, "wi_ok": float(np.mean(~over)), "over_flagged": int(np.sum(over & flagged)),
           "over": int(np.sum(over)), "false_alarms": int(np.sum(~over & flagged)),
           "rejected": int(sum(r["rejected"] for r in rows))}
    fits = [r["alpha"] for r in rows if "alpha" in r]
    if fits:
        a = np.array(fits)
        k = np.abs(a[:, 0] - ALPHA) / a[:, 1]
        out.update(alpha_within_2sigma=float(np.mean(k < 2)), alpha_z=k, alpha=a,
                   alpha_bias=float(np.mean(a[:, 0] - ALPHA)), alpha_bias_sigma=float(np.mean((a[:, 0] - ALPHA) / a[:, 1])),
                   alpha_bias_se=float(np.std(a[:, 0], ddof=1) / np.sqrt(len(a))) if len(a) > 1 else math.nan)
    return out


def parameter_table(s: dict):
    """Per calibration parameter over the runs: mean signed error in σ units (the bias the goal bounds by 0.5σ),
    its standard error (the spread over √runs), the rms of the z-scores, the share within 3σ."""
    from benchmarks.common import Table

    t = Table(f"calibration parameters' error in units of their stated σ over {s['runs']} runs",
              ["parameter", "mean (bias)", "± s.e.", "rms", "within 3σ", "|bias| ≤ 0.5σ"])
    for n in sorted(s["z"], key=lambda n: -abs(s["bias"][n])):
        z = s["z"][n]
        t.add(n, f"{np.mean(z):+.2f}", f"{np.std(z, ddof=1) / np.sqrt(len(z)):.2f}" if len(z) > 1 else "—",
              f"{np.sqrt(np.mean(z ** 2)):.2f}", f"{100 * np.mean(np.abs(z) < 3):.0f} %",
              "yes" if abs(np.mean(z)) <= 0.5 else "no")
    return t


def table(runs: int, *, fit: bool, jobs: int, quick: bool = False, per_parameter: bool = False):
    """The benchmark table over ``runs`` runs (rigs 0, 1, ..., two runs per rig, every run with its own noise seed:
    the frames' noise, the check's and the measurement session's; runs that shared a seed shared their noise fields
    — the same pixels' noise in every frame k — and the mean biases over them were averages over two draws); with
    ``per_parameter`` also :func:`parameter_table` (a list of the two tables is returned then)."""
    import time

    from benchmarks.common import Table
    from gonio.batch import run_batch
    from gonio.rig.geocal import calibration_plan
    from gonio.rig.kinematics import load_rig
    from gonio.session.geocal_session import check_session_plan

    rig = load_rig("default")
    check = check_session_plan(rig)
    kinds = check.params["kinds"]
    options = {"plan": calibration_plan(rig, quick=quick), "fit": fit,
               "check_plan": {k: check.joints[[i for i, x in enumerate(kinds) if x == k]] for k in ("camera", "highlight")}}
    sources = [f"{1000 + k // 2}:{100 + k}" for k in range(runs)]
    t0 = time.perf_counter()
    rows = run_batch(run_result, sources, options, jobs=jobs, desc="calibration honesty")
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        raise RuntimeError(f"run {failed[0]['source']}: {failed[0]['error']}")
    s = summary(rows)
    t = Table(f"stated uncertainties against the truth: {s['runs']} runs (as-built rigs drawn independently, 2 runs "
              f"each, every run its own noise seed, rendered + detected frames{', quick plan' if quick else ''})",
              ["quantity", "measured", "goal (issue 28)", "met"])
    wb = s["worst_bias"]
    t.add("calibration parameters within 3σ", f"{100 * s['within_3sigma']:.1f} % of {s['n_params']} "
          f"({100 * s['within_1sigma']:.0f} % within 1σ)", "≥ 99 %", "yes" if s["within_3sigma"] >= 0.99 else "no")
    t.add("largest mean bias of a parameter (σ units)", f"{wb[1]:+.2f} ({wb[0]})", "|bias| ≤ 0.5σ",
          "yes" if abs(wb[1]) <= 0.5 else "no")
    t.add("runs with wi p95 ≤ 0.25° after calibration", f"{100 * s['wi_ok']:.0f} % (p95 per run: "
          f"{', '.join(f'{x:.3f}' for x in s['wi_p95'])})", "≥ 95 %", "yes" if s["wi_ok"] >= 0.95 else "no")
    t.add("runs over 0.25° that `calibrate check` flags", f"{s['over_flagged']} of {s['over']} "
          f"(and {s['false_alarms']} flagged within it)", "all", "yes" if s["over_flagged"] == s["over"] else "no")
    if "alpha_within_2sigma" in s:
        t.add(f"fitted GGX α within 2σ of the truth ({ALPHA})", f"{100 * s['alpha_within_2sigma']:.0f} % "
              f"(|error|/σ per run: {', '.join(f'{x:.1f}' for x in s['alpha_z'])})", "≥ 90 %",
              "yes" if s["alpha_within_2sigma"] >= 0.9 else "no")
    t.notes.append("mean signed error / σ per parameter: " + ", ".join(
        f"{n} {b:+.2f}" for n, b in sorted(s["bias"].items(), key=lambda kv: -abs(kv[1]))[:8]) + " (largest 8)")
    if s["outside_3sigma"]:
        t.notes.append("outside 3σ: " + ", ".join(f"run {r} {n} {z:+.1f}σ" for r, n, z in s["outside_3sigma"][:8]))
    t.notes.append(f"frames left out as outliers by the calibration (gonio.rig.geocal.OUTLIER_P): {s['rejected']} "
                   f"over all runs; the calibrations' own wi bound (p95, gonio.rig.geocov.wi_error_p95): "
                   + ", ".join(f"{r['bound']:.3f}" for r in rows))
    if "alpha" in s:
        t.notes.append("fitted α ± σ per run (σ includes the calibration's error shared by all poses, "
                       "gonio.fit.geometry): " + ", ".join(f"{a:.5f} ± {e:.5f}" for a, e in s["alpha"]))
        t.notes.append(f"α bias over the runs: mean α − {ALPHA} = {s['alpha_bias']:+.6f} ± {s['alpha_bias_se']:.6f} "
                       f"(s.e.), mean (α − {ALPHA})/σ = {s['alpha_bias_sigma']:+.2f}")
    t.notes.append(f"this run: {time.perf_counter() - t0:.0f} s wall, {jobs} worker process(es)")
    return [t, parameter_table(s)] if per_parameter else t
