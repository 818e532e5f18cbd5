"""The geometric calibration's solver cost: :func:`gonio.rig.geocal.calibrate_geometry` with its least squares'
forward differences taken all columns at once (``jacobian="batched"``, the default:
:func:`gonio.rig.geocal_residuals.forward_jacobian`) against scipy taking them one column at a time
(``"2-point"``, the baseline), on the same observations in the same run; "identical" says whether every output
(errors, σ, covariance, residuals, evaluations, noise components, frames left out) is the same bit for bit.

Observations: geometric ones of a seeded as-built rig (:func:`sim.as_built.observe`; without covariances: each kind
rescaled by its scatter) and the same with per-observation covariances (the noise model of
:mod:`gonio.rig.geocal_noise`: variance components, outlier rejection), on the quick and the full calibration plans.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from benchmarks.common import Table, time_call


def _same(a, b) -> bool:
    """Every output of two calibrations equal, bit for bit."""
    arrays = [(a.errors.vector(), b.errors.vector()), (a.cov, b.cov), (a.residuals, b.residuals),
              (np.array(list(a.sigma.values())), np.array(list(b.sigma.values())))]
    return (all(np.array_equal(x, y, equal_nan=True) for x, y in arrays) and a.sigma.keys() == b.sigma.keys()
            and (a.nfev, a.noise, a.rejected, a.not_identified) == (b.nfev, b.noise, b.rejected, b.not_identified))


def run(quick: bool = False) -> list[Table]:
    from gonio.rig.geocal import calibrate_geometry, calibration_plan
    from gonio.rig.kinematics import load_rig
    from sim.as_built import AsBuilt, observe

    rig = load_rig("default")
    ab = AsBuilt.from_seed(rig, 7)
    t = Table("calibrate_geometry: the batched Jacobian against scipy's per-column finite differences (same run)",
              ["plan", "observations", "frames", "2-point (s)", "batched (s)", "vs 2-point", "identical"],
              baseline=None, default=None)
    cov_c, cov_h = np.diag([0.2 ** 2] * 3 + [0.02 ** 2] * 3), np.eye(2) * (0.2 / 380.0) ** 2  # observe()'s noise
    for plan_name in (("quick",) if quick else ("quick", "full")):
        cams, highs = observe(ab, calibration_plan(rig, quick=plan_name == "quick"), 7)
        for kind, (c, h) in (("geometric", (cams, highs)),
                             ("with covariances", ([replace(o, cov=cov_c) for o in cams],
                                                   [replace(o, cov=cov_h) for o in highs]))):
            res = {j: calibrate_geometry(rig, c, h, jacobian=j) for j in ("2-point", "batched")}
            secs = {j: time_call(lambda j=j: calibrate_geometry(rig, c, h, jacobian=j), min_time=0.3, repeat=3)
                    for j in res}
            t.add(plan_name, kind, len(c) + len(h), secs["2-point"], secs["batched"], secs["batched"] / secs["2-point"],
                  "yes" if _same(*res.values()) else "NO")
    t.notes.append("the baseline is the 2-point column, gonio's default the batched one (\"vs 2-point\": their ratio, "
                   "< 1 faster); wall seconds per calibration, best of 3 rounds (run with OPENBLAS_NUM_THREADS=1 for "
                   "numbers comparable with the test suite's one BLAS thread)")
    return [t]
