"""Issue 28's definition of done for the stated uncertainties, alone: ``python -m benchmarks calibration_dod``.

The second table of ``python -m benchmarks calibration`` (:mod:`benchmarks.calibration_honesty`) without its first
(declared vs calibrated geometry on 20 + 10 rendered rigs, issue 15's goals): the same 20 runs (10 as-built rigs
drawn independently × 2 runs, each run with its own noise seed), each calibrated from rendered and detected frames
of the full plan, checked by ``gonio calibrate check``'s short plan, and measured with a GGX material and fitted.
Nothing that decides a DoD number is made smaller — the calibration plan, the frames (320 × 240 already), the check
and the measurement session are those of the full benchmark —; what is left out is the other table's ten rendered
calibrations (half the full benchmark's time). Tables: the DoD (coverage at 3σ, the largest mean bias, wi p95 ≤
0.25° per run, runs over it that ``calibrate check`` flags, α within 2σ) and every parameter's mean error in σ
units. ``--quick``: 2 runs (one rig, two noise seeds), for CI. ``GONIO_DOD_RUNS=N``: the first N runs only (the same
rigs and seeds: an investigation on a shared machine; the DoD is judged on 20). The runs go to one worker process
per core (run it under ``flock /tmp/gonio-bench.lock``: the machine is then the benchmark's), not
:func:`free_cores`'s count, which on a machine busy with other work falls to one.
"""

from __future__ import annotations


def run(quick: bool = False, jobs: int | None = None, runs: int | None = None):
    import os

    from benchmarks.calibration_honesty import table
    from gonio.batch import default_jobs

    if runs is None and os.environ.get("GONIO_DOD_RUNS"):
        runs = int(os.environ["GONIO_DOD_RUNS"])
    n = (2 if quick else 20) if runs is None else int(runs)
    return table(n, fit=True, jobs=min(default_jobs(), n) if jobs is None else jobs, per_parameter=True)
