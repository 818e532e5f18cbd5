"""Sphere versus flat sample (issue 30), on the simulated rig, the default flat session (the baseline) measured in
the same run:

1. **per material** (a diffuse, a plastic — the default material —, a rough metal and a chrome-like one), the
   default flat session and a sphere light sweep (camera still at 60°, light every 4° in its plane) of about the
   same lab time at 320×240: MERL cells filled and per lab minute, the per-cell error against the truth (cells
   binned by :class:`gonio.cells.CellAccumulator`; the truth binned from the same samples' directions), how often
   the truth lies within the cell's 2σ, the fitted GGX α, and for the sphere the footprint-aware fit
   (:func:`gonio.sphere.footprint.fit_footprint` on the kept per-pixel samples) with its peak value
   ``f(θh = 0, θd = 20°)`` against the truth's;
2. **a full table**: the default material on a sphere with the greedy plan (``gonio plan sphere --fill 0.9
   --fill-budget 1200``, :mod:`gonio.session.sphere_plan`) at the default camera (320×240;
   ``GONIO_SPHERE_RESOLUTION`` for another): the cells measured, as a share of the cells the rig can reach with the
   camera there (:func:`gonio.session.sphere_coverage.reachable_cells`: the limit of ever finer light sweeps, not a
   sweep's sample), per lab minute against the flat's, and where the lab time went; the coverage against lab time
   and by θh and θd band, with the cells' error per band;
3. **the plan at other cameras** (geometry only, nothing rendered): the greedy plan's cells and estimated lab time
   at 320×240, 640×480 and 1280×960;
4. **memory** of whole sphere sessions in a child process (``gonio measure``, 320×240, up to ~400 frames).

Per-cell errors are over the cells away from the silhouette (the pipeline rejects θo > 80°).
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import Table

MATERIALS = {
    "diffuse": {"model": "lambert", "params": {"albedo": [0.5, 0.35, 0.25]}},
    "plastic": {"model": "microfacet", "params": {"kd": [0.3, 0.12, 0.06], "ks": 0.8, "alpha": 0.25, "f0": 0.04,
                                                  "distribution": "ggx"}},
    "rough metal": {"model": "microfacet", "params": {"kd": [0.0, 0.0, 0.0], "ks": 1.0, "alpha": 0.3, "f0": 0.9,
                                                      "distribution": "ggx"}},
    "chrome-like": {"model": "microfacet", "params": {"kd": [0.0, 0.0, 0.0], "ks": 1.0, "alpha": 0.01, "f0": 0.95,
                                                      "distribution": "ggx"}},
}


#: the chrome-like sphere's highlight is ~100× the white reference: an expected bracket two rungs shorter (the
#: automatic exposure's ladder extends two rungs either side of it, gonio.plan.labtime.dark_exposures), so the
#: highlight's pixels are not saturated in every exposure
CHROME_EXPOSURES = (0.00025, 0.001, 0.004)


def _target() -> str:
    target = Path(tempfile.mkdtemp(prefix="bench-sphere-")) / "sphere.toml"
    target.write_text("[sphere]\nradius = 0.02\n")
    return str(target)


def _session(tmp: Path, name: str, material: dict, plan, target: str | None, resolution="320x240", keep=False,
             capture=None, **plan_params):
    import gonio
    from gonio.plan.generators import make_plan
    from gonio.session.material import material_from_dict

    mat = material_from_dict(material, source=name)
    with gonio.open_rig(sim=gonio.SimOptions(seed=1, resolution=resolution), material=mat, target=target) as rig:
        if isinstance(plan, str):
            plan = make_plan(plan, rig=rig.rig, capture=capture, **plan_params)
        label = plan if isinstance(plan, str) else plan.generator
        run = gonio.measure(rig, plan, tmp / f"{name}-{label}-{resolution}-{time.monotonic_ns()}", progress=None,
                            keep_pixels=keep)
    return run


def _cells(run, model):
    """The session's MERL cells: ``(has, rel, within)`` — (N_CELLS,) bool, the cells holding a sample; per such
    cell with truth > 1e-6 in every channel, |binned measured / binned truth − 1| (n, 3) and whether the truth is
    within the cell's 2σ (n, 3), with the cells' flat indices ``idx`` (n,)."""
    from gonio.cells import CellAccumulator
    from gonio.geometry import half_diff_from_dirs
    from gonio.store.directory import scan_samples

    acc, tru = CellAccumulator(), CellAccumulator()
    for k, (s, _) in sorted(scan_samples(Path(run.directory) / "samples.jsonl").records.items()):
        good = np.all(np.isfinite(s.f), axis=1) & (s.flags == 0)  # pose by pose: never all samples at once
        th, _, td, pd = half_diff_from_dirs(s.wi[good], s.wo[good])
        acc.add(th, td, pd, s.f[good], s.sigma[good])
        tru.add(th, td, pd, model.eval(s.wi[good], s.wo[good]), s.sigma[good])  # the truth as the cell's samples see it
    m, sig = acc.mean_sigma()
    t, _ = tru.mean_sigma()
    has = acc.count > 0
    idx = np.flatnonzero(has)
    m, sig, t = m[has], sig[has], t[has]
    ok = np.all(t > 1e-6, axis=1)
    return has, np.abs(m[ok] / t[ok] - 1), (np.abs(m - t) <= 2 * sig)[ok], idx[ok]


def _cell_stats(run, model):
    """(cells, median, p95 of |binned measured / binned truth − 1|, share of cells with the truth within 2σ)."""
    has, rel, within, _ = _cells(run, model)
    return int(has.sum()), float(np.median(rel)), float(np.percentile(rel, 95)), float(np.mean(within))


def _peak(params) -> float:
    """The specular peak ``f(θh = 0, θd = 20°)`` (red channel) of a microfacet model's parameters."""
    from gonio.brdf import make

    a = math.radians(20)
    wi = np.array([[math.sin(a), 0.0, math.cos(a)]])
    wo = np.array([[-math.sin(a), 0.0, math.cos(a)]])
    return float(make("microfacet", **params).eval(wi, wo)[0, 0])


def _footprint_fit(run, params, start):
    """α and the peak of the footprint-aware fit of the kept per-pixel samples (from the ordinary fit's values)."""
    from gonio.sphere.footprint import fit_footprint
    from gonio.sphere.pose import load_pixels

    px = load_pixels(run.directory)
    f, s = px["f"], px["sigma"]
    top = f[:, 0] > 1e-3 * np.nanmax(f[:, 0])  # the lobe's pixels, and every 8th of the others (f ≈ kd/π alike)
    keep = top | (np.arange(len(f)) % 8 == 0)
    p, info = fit_footprint("microfacet", start, px["wi_local"][keep], px["wo_local"][keep], px["footprint"][keep],
                            f[keep], s[keep], free=("ks", "alpha"))
    return p["alpha"], _peak(p) / _peak(params) - 1, info


def materials_table(quick: bool, mats=None) -> Table:
    import gonio
    from gonio.brdf import make
    from gonio.plan.plan import CaptureSettings
    from gonio.samples import SampleSet

    tab = Table("Sphere vs flat sample at about equal lab time (simulated rig, 320×240 camera)",
                ["material", "sample", "poses", "lab min", "cells filled", "cells / lab min", "× flat",
                 "cell error median", "p95", "truth within 2σ", "fitted α (truth)", "α, footprint fit",
                 "peak, footprint fit vs truth"], baseline=0)
    target = _target()
    mats = mats or (["chrome-like"] if quick else list(MATERIALS))
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for name in mats:
            mat = MATERIALS[name]
            model = make(mat["model"], **mat["params"])
            step = math.radians(4 if not quick else 20)
            runs = [("flat", _session(tmp, name, mat, "half_diff", None)),
                    ("sphere", _session(tmp, name, mat, "sphere", target, keep="alpha" in mat["params"],
                                        capture=CaptureSettings(exposures=CHROME_EXPOSURES)
                                        if name == "chrome-like" else None,
                                        theta_i_step=step, phi_i_step=math.pi))]
            base = None
            for label, r in runs:
                cells, med, p95, within = _cell_stats(r, model)
                rate = cells / (r.lab_time / 60)
                base = base or rate
                alpha = fp_alpha = fp_peak = ""
                if "alpha" in mat["params"]:
                    s = r.load().samples
                    good = np.all(np.isfinite(s.f), axis=1) & (s.flags == 0)
                    s = SampleSet(s.wi[good], s.wo[good], s.f[good], s.sigma[good])
                    fit = gonio.fit(s, "microfacet", fixed={"distribution": "ggx"})
                    alpha = f"{fit.params['alpha']:.4f} ({mat['params']['alpha']})"
                    if label == "sphere":
                        a, dpeak, info = _footprint_fit(r, mat["params"], {**fit.params, "distribution": "ggx"})
                        bound = f", on bound: {', '.join(info['on_bound'])}" if info["on_bound"] else ""
                        fp_alpha = (f"{a:.5f} ± {info['sigma']['alpha']:.5f}{bound}; image offset "
                                    f"({info['shift_px'][0]:+.3f}, {info['shift_px'][1]:+.3f}) px")
                        fp_peak = f"{100 * dpeak:+.1f} %"
                tab.add(name, label, r.poses_done, f"{r.lab_time / 60:.2f}", cells, f"{rate:.0f}",
                        f"{rate / base:.1f}×", f"{100 * med:.2f} %", f"{100 * p95:.1f} %", f"{100 * within:.0f} %",
                        alpha, fp_alpha, fp_peak)
    tab.notes.append("cells: MERL cells holding ≥ 1 sample; errors: binned measured / binned truth − 1 over cells with "
                     "truth > 1e-6, every channel; the chrome-like sphere's cells are footprint averages (a pixel "
                     "spans ~3° of normals, the lobe 0.6°): the footprint-aware fit models that, the cells do not")
    tab.notes.append("footprint fit: ks and α refitted to the kept per-pixel samples with the model averaged over "
                     "each pixel's footprint (gonio.sphere.footprint), the other parameters the ordinary fit's, α's "
                     "start a scan over log α, the sphere's image offset fitted with them (a registration error of "
                     "hundredths of a pixel widens a lobe narrower than a pixel); peak f(θh = 0, θd = 20°)")
    return tab


def full_table(resolution: str | None = None, fill: float = 0.9, budget: float = 1200.0,
               steps: tuple[float, float] = (1.0, 3.0)) -> tuple[list[Table], dict]:
    """The default material: flat default session vs the greedy sphere plan at ``resolution`` (None: the simulated
    camera's default, :data:`gonio.session.options.DEFAULT_SIM_RESOLUTION`), candidates every ``steps`` degrees of
    light zenith and azimuth; then the coverage against lab time (the plan's prediction, pose by pose) and by
    θh and θd band (predicted and measured, with the measured cells' error there)."""
    import resource

    import gonio
    from gonio.session.options import DEFAULT_SIM_RESOLUTION, default_material
    from gonio.session.sphere_coverage import plan_coverage
    from gonio.session.sphere_plan import greedy_sphere_plan
    from gonio.sphere import Sphere

    resolution = resolution or DEFAULT_SIM_RESOLUTION
    mat = MATERIALS["plastic"]
    from gonio.brdf import make

    model = make(mat["model"], **mat["params"])
    assert default_material().params == mat["params"]  # the default material, as the issue asks
    tab = Table(f"A full table: the default material on a sphere, greedy plan (--fill {fill} --fill-budget "
                f"{budget:g}, candidates every {steps[0]:g}° × {steps[1]:g}°), {resolution}"
                + (" (the default camera)" if resolution == DEFAULT_SIM_RESOLUTION else ""),
                ["sample", "camera", "poses", "lab min", "cells filled", "of reachable", "cells / lab min", "× flat",
                 "cell error median", "p95", "truth within 2σ", "peak RSS MB"], baseline=0)
    sph = Sphere((0.0, 0.0, 0.02), 0.02)
    target = _target()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        flat = _session(tmp, "plastic", mat, "half_diff", None)
        with gonio.open_rig(sim=gonio.SimOptions(seed=1, resolution=resolution), target=target) as rig:
            calib = rig.calibration
            plan, info = greedy_sphere_plan(rig.rig, calib, sph, coverage=fill, budget=budget,
                                            theta_i_step=math.radians(steps[0]), phi_i_step=math.radians(steps[1]))
            cov = plan_coverage(plan, rig.rig, calib, sph)
            reach = cov.reachable
        sphere = _session(tmp, "plastic", mat, plan, target, resolution=resolution)
        base = None
        measured = {}
        for label, cam, r in (("flat", DEFAULT_SIM_RESOLUTION, flat), ("sphere", resolution, sphere)):
            has, rel, within, idx = _cells(r, model)
            cells = int(has.sum())
            med, p95, inside = float(np.median(rel)), float(np.percentile(rel, 95)), float(np.mean(within))
            rate = cells / (r.lab_time / 60)
            base = base or rate
            share = f"{100 * (has & cov.reach_mask).sum() / reach:.1f} %" if label == "sphere" else ""
            tab.add(label, cam, r.poses_done, f"{r.lab_time / 60:.2f}", cells, share, f"{rate:.0f}",
                    f"{rate / base:.1f}×", f"{100 * med:.2f} %", f"{100 * p95:.1f} %", f"{100 * inside:.0f} %",
                    f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f}")
            measured[label] = (has, rel, within, idx, r.lab_time)
        acc = _lab_account(sphere)
    tab.notes.append(f"reachable: the {reach} valid MERL cells the rig can fill with the camera still at 60° "
                     "(gonio.session.sphere_coverage.reachable_cells: the pipeline keeps the cell's θi, θo ≤ 80°, and "
                     f"its θd is within the light's reach; checked against a brute force over the sphere's normals); "
                     f"all {info['candidates']} candidate light positions together fill {info['candidates_reach']}; "
                     f"the plan expected {info['filled']} cells ({cov.of_reachable:.1%}) in "
                     f"{info['lab_s'] / 60:.1f} lab min")
    tab.notes.append("the sphere session's lab time: " + acc)
    tab.notes.append("peak RSS: this benchmark process so far (the rows run in order)")
    out = {"flat_rate": base, "plan": info, "predicted": cov}
    return [tab, _curve_table(info, cov, measured, base), _band_table(cov, measured["sphere"])], out


def _curve_table(info, cov, measured, flat_rate) -> Table:
    """Coverage against lab time: the greedy plan's prediction after each pose (its first minutes are the plan a
    shorter budget would take: the greedy never revisits), the measured session at its end."""
    tr = info["trace"].copy()
    scale = info["lab_s"] / tr[-1, 0]  # the greedy counts each move from the pose taken before; the tour moves less
    tr[:, 0] *= scale
    tab = Table("Coverage against lab time (the greedy plan's prediction, geometry only; the measured session last)",
                ["lab min", "poses", "cells", "of reachable", "cells / lab min", "× flat (measured)"], baseline=None)
    for m in (1, 2, 5, 10, 15, 20, 30):
        k = int(np.searchsorted(tr[:, 0], 60.0 * m, side="right"))
        if k == 0 or (k == len(tr) and tr[-1, 0] < 60.0 * m - 60.0):
            continue
        cells = tr[k - 1, 1]
        rate = cells / (tr[k - 1, 0] / 60)
        tab.add(f"{tr[k - 1, 0] / 60:.1f}", k, f"{cells:.0f}", f"{100 * cells / cov.reachable:.1f} %", f"{rate:.0f}",
                f"{rate / flat_rate:.1f}×")
    has, _, _, _, lab = measured["sphere"]
    n = int((has & cov.reach_mask).sum())
    tab.add(f"{lab / 60:.1f} (measured)", "", n, f"{100 * n / cov.reachable:.1f} %", f"{n / (lab / 60):.0f}",
            f"{n / (lab / 60) / flat_rate:.1f}×")
    tab.notes.append("a pose fills fewer new cells as the table fills (the greedy takes the best first): the rate "
                     "falls with lab time; the measured session also spends lab time on start-up darks and metering")
    tab.notes.append(f"lab time of the first k poses: the greedy's own count (each move from the pose taken before) "
                     f"times {scale:.3f}, the ordered tour's lab time over that count for the whole plan")
    return tab


def _band_table(cov, measured) -> Table:
    """Coverage and cell error per θh and θd band (9 bands of 10 index rows; MERL's θh rows are (i/90)²·90°)."""
    from gonio.io.merl import SHAPE
    from gonio.session.sphere_coverage import band_edges_deg

    has, rel, within, idx, _ = measured
    tab = Table("Coverage and cell error by band (the default camera's full table above)",
                ["band", "reachable cells", "filled, predicted", "filled, measured", "cell error median", "p95",
                 "truth within 2σ"], baseline=None)
    r = cov.reach_mask.reshape(SHAPE)
    f = cov.filled_mask.reshape(SHAPE)
    h = (has & cov.reach_mask).reshape(SHAPE)
    cell_axes = np.unravel_index(idx, SHAPE)
    for axis, name in ((0, "θh"), (1, "θd")):
        e = band_edges_deg(axis)
        for b in range(9):
            sl = [slice(None)] * 3
            sl[axis] = slice(10 * b, 10 * b + 10)
            n = int(r[tuple(sl)].sum())
            if n == 0:
                continue
            sel = (cell_axes[axis] >= 10 * b) & (cell_axes[axis] < 10 * b + 10)
            err = (f"{100 * np.median(rel[sel]):.2f} %", f"{100 * np.percentile(rel[sel], 95):.1f} %",
                   f"{100 * within[sel].mean():.0f} %") if sel.any() else ("", "", "")
            tab.add(f"{name} {e[b]:.1f}–{e[b + 1]:.1f}°", n, f"{100 * (f & r)[tuple(sl)].sum() / n:.1f} %",
                    f"{100 * h[tuple(sl)].sum() / n:.1f} %", *err)
    tab.notes.append("a cell whose θh is under ~4° is smaller than the normals one pixel spans (a pixel of a 19-px "
                     "radius sphere spans ~3° of normals, a MERL cell at θh = 1° spans 0.2° × 0.02°, twice): few pixel "
                     "centres land in one, whatever the light's step; the error columns say how its value and σ hold "
                     "up there (the pixel's value is its footprint's mean, binned at its centre)")
    return tab


def _lab_account(run) -> str:
    """Where a session's lab time went, from its records: frames per pose and lab seconds per pose."""
    from gonio.store.directory import scan_samples

    metas = [m for _, (_, m) in sorted(scan_samples(Path(run.directory) / "samples.jsonl").records.items())]
    frames = np.array([sum(m["frames"]) for m in metas], dtype=np.float64)
    exps = np.array([len(m["exposures_s"]) for m in metas], dtype=np.float64)
    n = max(len(metas), 1)
    return (f"{run.lab_time:.0f} s over {len(metas)} poses ({run.lab_time / n:.2f} s a pose): "
            f"{exps.mean():.2f} exposures and {frames.mean():.2f} frames a pose (+ 1 metering frame), "
            "settle 0.3 s, readout 0.05 s a frame, the rest moves and the start-up darks")


def _sim_calibration(w: int, h: int):
    from sim.rig import SimRigConfig

    return SimRigConfig.at_resolution(w, h).calibration()


def cameras_table(flat_rate: float | None, quick: bool) -> Table:
    """The greedy plan at several cameras, from the geometry alone (nothing rendered)."""
    from gonio.plan import estimate_plan
    from gonio.rig.kinematics import load_rig
    from gonio.session.sphere_coverage import flat_cells_of_pose, plan_coverage
    from gonio.session.sphere_plan import greedy_sphere_plan
    from gonio.sphere import Sphere
    from gonio.pipeline.target import TargetLayout
    from gonio.plan.generators import make_plan

    rig = load_rig(None)
    sph = Sphere((0.0, 0.0, 0.02), 0.02)
    flat = make_plan("half_diff", rig=rig)
    flat_cells = np.unique(np.concatenate([flat_cells_of_pose(rig, j, TargetLayout()) for j in flat.joints]))
    flat_geo = len(flat_cells) / (estimate_plan(flat, rig).optimized / 60)
    tab = Table("The greedy sphere plan at other cameras (geometry only: cells its pixels' centres fall in, lab "
                "time estimated)", ["camera", "poses", "lab min (est.)", "cells", "of reachable", "cells / lab min",
                                    "× flat"], baseline=0)
    tab.add("flat, default plan (6 × 6 tile centres)", len(flat), f"{estimate_plan(flat, rig).optimized / 60:.2f}",
            len(flat_cells), "", f"{flat_geo:.0f}", "1.0×")
    cams = [(320, 240)] if quick else [(320, 240), (640, 480), (1280, 960)]
    kw = dict(theta_i_step=math.radians(10), phi_i_step=math.radians(30), stride=2, reach_step=math.radians(15),
              budget=60.0) if quick else {}
    for w, h in cams:
        calib = _sim_calibration(w, h)
        plan, info = greedy_sphere_plan(rig, calib, sph, coverage=0.9, **kw)
        lab = estimate_plan(plan, rig).optimized
        cov = info if quick else plan_coverage(plan, rig, calib, sph)
        filled = info["filled"] if quick else cov.filled
        share = info["filled"] / info["reachable"] if quick else cov.of_reachable
        rate = filled / (lab / 60)
        tab.add(f"sphere, {w}×{h}", len(plan), f"{lab / 60:.2f}", filled, f"{100 * share:.1f} %", f"{rate:.0f}",
                f"{rate / flat_geo:.1f}×")
    if flat_rate:
        tab.notes.append(f"the flat session measured {flat_rate:.0f} cells / lab min (table above): the geometry's "
                         "6 × 6 tiles are a rough stand-in for its tiles")
    tab.notes.append("estimated lab time: 1 frame per exposure of the expected bracket (gonio plan --estimate); a "
                     "measured session meters its own bracket per pose" + (" — quick: coarse candidates, every "
                                                                           "2nd pixel" if quick else ""))
    return tab


def _memory(quick: bool, resolution: str | None = None) -> Table:
    """Peak resident memory of a whole sphere session (``gonio measure`` in a child process, at ``resolution``,
    default the simulated camera's default, 320×240): the frames are merged and reduced to samples pose by pose, so
    memory does not grow with the frames."""
    import json
    import sys

    from gonio.session.options import DEFAULT_SIM_RESOLUTION

    resolution = resolution or DEFAULT_SIM_RESOLUTION
    tab = Table(f"Memory of a sphere session (gonio measure --sim, {resolution}"
                + (", the default resolution)" if resolution == DEFAULT_SIM_RESOLUTION else ")"),
                ["frames (poses)", "samples", "peak RSS MB", "wall s"], baseline=0)
    target = _target()
    sizes = [("30", "60"), ("20", "40")] if quick else [("30", "60"), ("4", "18")]  # ~20 and ~400 poses
    with tempfile.TemporaryDirectory() as d:
        for k, (ti, pi) in enumerate(sizes):
            out = Path(d) / f"s{k}"
            t0 = time.perf_counter()
            peak = _child_peak_rss([sys.executable, "-m", "gonio.cli.main", "measure", "--sim", "--target", target,
                                    "--plan", "sphere", "--theta-i-step", ti, "--phi-i-step", pi, "--out", str(out),
                                    "--quiet", "--sim-resolution", resolution])
            m = json.loads((out / "manifest.json").read_text())
            tab.add(m["last_run"]["poses"], m["last_run"]["samples"], f"{peak / 1024:.0f}",
                    f"{time.perf_counter() - t0:.1f}")
    tab.notes.append("peak RSS: the session process's own high-water mark (VmHWM of /proc/PID/status, read until it "
                     "exits; getrusage's RUSAGE_CHILDREN would count the benchmark process's memory at the fork)")
    return tab


def _child_peak_rss(cmd) -> int:
    """Run ``cmd`` and return its peak resident memory (KiB): ``VmHWM`` of ``/proc/PID/status``, polled until it
    exits, every 0.2 s — the child's own address space (a child's ``ru_maxrss`` also counts the parent's pages it was
    forked with: Linux keeps the pre-exec high-water mark). Raises ``CalledProcessError`` when it fails."""
    import subprocess

    err_file = tempfile.TemporaryFile()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err_file)
    peak = 0
    status = Path(f"/proc/{proc.pid}/status")
    while proc.poll() is None:
        try:
            for line in status.read_text().splitlines():
                if line.startswith("VmHWM:"):
                    peak = max(peak, int(line.split()[1]))
        except (OSError, ValueError):
            pass
        time.sleep(0.2)
    err_file.seek(0)
    err = err_file.read()
    err_file.close()
    if proc.returncode:
        raise subprocess.CalledProcessError(proc.returncode, cmd, stderr=err)
    return peak


def trade(quick: bool = False) -> list[Table]:
    """``gonio bench``'s sphere-vs-flat row: the cameras table (quick: 320×240 only, coarse candidates: about a
    second, nothing rendered)."""
    tab = cameras_table(None, quick)
    tab.default = 1
    tab.why_default = ("one sphere frame holds a sample per pixel: the greedy light plan fills cells per lab minute "
                       "many times faster than the flat sample's tiles")
    return [tab]


def run(quick: bool = False):
    """The tables, each yielded as it is made (``python -u -m benchmarks sphere`` prints each when done, so a run
    cut short keeps what it measured): the full table first (the issue's coverage and lab time, then its coverage
    against lab time and by band), the default and the chrome-like material, the cameras, memory, then the other two
    materials. ``GONIO_SPHERE_BUDGET``: the full table's --fill-budget (lab seconds, default 1200: the issue's 20
    minutes); ``GONIO_SPHERE_RESOLUTION``: its camera (default: the simulated camera's, 320x240);
    ``GONIO_SPHERE_STEPS``: its candidates' light zenith and azimuth steps in degrees (default ``1,3``, as
    ``gonio plan sphere --fill``); ``GONIO_SPHERE_ONLY``: the tables to make, a comma list of ``full``,
    ``materials``, ``cameras``, ``memory`` (default all); ``GONIO_SPHERE_MEMORY_RESOLUTION``: the memory table's
    camera (default 320x240)."""
    import os

    only = {x.strip() for x in os.environ.get("GONIO_SPHERE_ONLY", "full,materials,cameras,memory").split(",")}
    flat_rate = None
    if not quick:
        if "full" in only:
            steps = tuple(float(x) for x in os.environ.get("GONIO_SPHERE_STEPS", "1,3").split(","))
            tabs, out = full_table(os.environ.get("GONIO_SPHERE_RESOLUTION") or None,
                                   budget=float(os.environ.get("GONIO_SPHERE_BUDGET", "1200")), steps=steps)
            flat_rate = out["flat_rate"]
            yield from tabs
        if "materials" in only:
            yield materials_table(quick, ["plastic", "chrome-like"])
    elif "materials" in only:
        yield materials_table(quick)
    if "cameras" in only:
        yield cameras_table(flat_rate, quick)
    if "memory" in only:
        yield _memory(quick, os.environ.get("GONIO_SPHERE_MEMORY_RESOLUTION") or None)
    if not quick and "materials" in only:
        yield materials_table(quick, ["diffuse", "rough metal"])
