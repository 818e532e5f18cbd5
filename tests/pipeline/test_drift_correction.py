"""Measuring before the light is warm: the photodiode reading taken with every frame removes the warm-up
drift, even in absolute mode where no white reference in the frame could (gonio.pipeline.hdr.merge_linear)."""

from __future__ import annotations

import numpy as np

from tests.pipeline.test_pipeline_accuracy import POSES, check, run_poses


def test_a_cold_light_is_corrected_from_the_photodiode(bench_factory, lambert):
    from sim.camera import SensorModel

    sn = SensorModel()
    scale = np.asarray(sn.responsivity) * sn.dn_per_electron  # DN/s per unit f·I·cosθ/r² at output 1
    # switched on at t = 0, 20 % short of its warm output, τ = 120 s: the frames see 0.80–0.81
    bench = bench_factory(lambert, drift=0.2, tau=120.0, absolute_scale=scale)
    samples = run_poses(bench, POSES[:2])
    assert bench.light.output() < 0.85  # still far from warm: uncorrected samples would be ~18 % low
    check(samples, lambert)  # median error <= 1 %, p95 <= 5 % per channel
