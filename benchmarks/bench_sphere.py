"""Sphere versus flat sample at equal lab time (issue 30): on the simulated rig, the default flat session (the
baseline, measured in the same run) and a sphere session whose plan takes about the same lab time, for a diffuse, a
plastic, a rough metal and a chrome-like material — MERL cells filled (and per lab minute), the per-cell error
against the truth (cells binned by :class:`gonio.cells.CellAccumulator`; the truth binned from the same
samples' directions, so both see the same cell extent), how often the truth lies within the cell's 2σ, and the
fitted GGX α against the truth.

Per-cell errors are over the cells away from the silhouette (the pipeline rejects θo > 80°). The chrome-like
sphere's peak is narrower than a pixel's footprint of normals at 320×240: its per-pixel values are footprint
averages, which the table shows rather than hides.
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


def _session(tmp: Path, name: str, material: dict, plan_name: str, target: str | None, resolution="320x240",
             **plan_params):
    import gonio
    from gonio.plan.generators import make_plan
    from gonio.io.material_toml import material_from_dict

    mat = material_from_dict(material, source=name)
    with gonio.open_rig(sim=gonio.SimOptions(seed=1, resolution=resolution), material=mat, target=target) as rig:
        plan = make_plan(plan_name, rig=rig.rig, **plan_params)
        t0 = time.perf_counter()
        run = gonio.measure(rig, plan, tmp / f"{name}-{plan_name}-{resolution}", progress=None)
        wall = time.perf_counter() - t0
    return run, wall


def _cells(samples, truth):
    """Binned measured and true values, cell σ and count (cells with ≥ 1 sample)."""
    from gonio.geometry import half_diff_from_dirs
    from gonio.cells import CellAccumulator

    th, _, td, pd = half_diff_from_dirs(samples.wi, samples.wo)
    acc, tru = CellAccumulator(), CellAccumulator()
    acc.add(th, td, pd, samples.f, samples.sigma)
    tru.add(th, td, pd, truth, samples.sigma)  # the same weights: the truth as the cell's samples see it
    m, s = acc.mean_sigma()
    t, _ = tru.mean_sigma()
    has = acc.count > 0
    return m[has], s[has], t[has]


def run(quick: bool = False) -> list[Table]:
    from gonio.brdf import make

    tab = Table("Sphere vs flat sample at equal lab time (simulated rig, 320×240 camera)",
                ["material", "sample", "poses", "lab min", "cells filled", "cells / lab min", "× flat",
                 "cell error median", "p95", "truth within 2σ", "fitted α (truth)"], baseline=0)
    mats = ["plastic"] if quick else list(MATERIALS)
    target = Path(tempfile.mkdtemp(prefix="bench-sphere-")) / "sphere.toml"
    target.write_text("[sphere]\nradius = 0.02\n")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for name in mats:
            mat = MATERIALS[name]
            model = make(mat["model"], **mat["params"])
            rows = []
            flat, _ = _session(tmp, name, mat, "half_diff", None)
            lab_flat = flat.lab_time
            # the sphere plan with about the flat session's lab time: light zenith step 4°, both sides of the camera
            step = math.radians(4 if not quick else 10)
            runs = [("flat", flat), ("sphere", _session(tmp, name, mat, "sphere", str(target), theta_i_step=step,
                                                        phi_i_step=math.pi)[0])]
            if not quick:  # the same plan with a camera of 4× the pixels: cells per frame scale with the sphere's pixels
                runs.append(("sphere, 640×480", _session(tmp, name, mat, "sphere", str(target), resolution="640x480",
                                                         theta_i_step=step, phi_i_step=math.pi)[0]))
            for label, r in runs:
                s = r.load().samples
                good = np.all(np.isfinite(s.f), axis=1) & (s.flags == 0)
                from gonio.samples import SampleSet

                s = SampleSet(s.wi[good], s.wo[good], s.f[good], s.sigma[good])
                truth = model.eval(s.wi, s.wo)
                m, sig, t = _cells(s, truth)
                ok = np.all(t > 1e-6, axis=1)
                rel = np.abs(m[ok] / t[ok] - 1).ravel()
                within = float(np.mean(np.abs(m - t) <= 2 * sig))
                alpha = ""
                if "alpha" in mat["params"]:
                    import gonio

                    fit = gonio.fit(s, "microfacet", fixed={"distribution": "ggx"}) if len(s.f) < 200000 else \
                        gonio.fit(SampleSet(s.wi[::4], s.wo[::4], s.f[::4], s.sigma[::4]), "microfacet",
                                  fixed={"distribution": "ggx"})
                    alpha = f"{fit.params['alpha']:.4f} ({mat['params']['alpha']})"
                cells = len(m)
                rows.append((name, label, r.poses_done, r.lab_time / 60, cells, cells / (r.lab_time / 60), rel, within,
                             alpha))
            base = rows[0][5]
            for name_, label, poses, lab, cells, rate, rel, within, alpha in rows:
                tab.add(name_, label, poses, f"{lab:.2f}", cells, f"{rate:.0f}", f"{rate / base:.1f}×",
                        f"{100 * np.median(rel):.2f} %", f"{100 * np.percentile(rel, 95):.1f} %",
                        f"{100 * within:.0f} %", alpha)
            tab.notes.append(f"{name}: flat {lab_flat / 60:.2f} lab min")
    tab.notes.append("cells: MERL cells holding ≥ 1 sample; errors: binned measured / binned truth − 1 over cells with "
                     "truth > 1e-6, every channel")
    return [tab, _memory(quick)]


def _memory(quick: bool) -> Table:
    """Peak resident memory of a whole sphere session (``gonio measure`` in a child process, 320×240): the frames
    are merged and reduced to samples pose by pose, so memory does not grow with the frames."""
    import resource
    import subprocess
    import sys

    tab = Table("Memory of a sphere session (gonio measure --sim, 320×240)",
                ["frames (poses)", "samples", "peak RSS MB", "wall s"], baseline=0)
    target = Path(tempfile.mkdtemp(prefix="bench-sphere-mem-")) / "sphere.toml"
    target.write_text("[sphere]\nradius = 0.02\n")
    sizes = [("30", "60"), ("20", "40")] if quick else [("30", "60"), ("4", "18")]  # ~20 and ~400 poses
    with tempfile.TemporaryDirectory() as d:
        for k, (ti, pi) in enumerate(sizes):
            out = Path(d) / f"s{k}"
            t0 = time.perf_counter()
            before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            subprocess.run([sys.executable, "-m", "gonio.cli.main", "measure", "--sim", "--target", str(target),
                            "--plan", "sphere", "--theta-i-step", ti, "--phi-i-step", pi, "--out", str(out), "--quiet"],
                           check=True, capture_output=True)
            peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # KiB, the largest child so far
            import json

            m = json.loads((out / "manifest.json").read_text())
            tab.add(m["last_run"]["poses"], m["last_run"]["samples"], f"{max(peak, before) / 1024:.0f}",
                    f"{time.perf_counter() - t0:.1f}")
    tab.notes.append("peak RSS: the largest child process's (getrusage RUSAGE_CHILDREN); the rows run in increasing size")
    return tab
