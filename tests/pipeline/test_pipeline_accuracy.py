"""Accuracy of the whole chain (render -> pipeline) against the analytic BRDF at the samples' angles."""

from __future__ import annotations

import numpy as np
import pytest

from gonio import samples as S
from gonio.brdf import make

# (θo, φo, θi, φi) in degrees: normal, oblique, grazing-ish, off-plane, near-specular.
POSES = [(0, 0, 40, 180), (30, 20, 20, 200), (50, 90, 60, 250), (60, 0, 10, 180), (65, 300, 45, 120),
         (35, 0, 35, 180)]


def run_poses(bench, poses=POSES):
    sets = [bench.measure(*p, index=k).samples for k, p in enumerate(poses)]
    return S.SampleSet.concat(sets)


def rel_errors(samples, material):
    good = samples.good()
    ref = material.eval(good.wi, good.wo)
    return (good.f - ref) / ref, good


def check(samples, material):
    rel, good = rel_errors(samples, material)
    assert len(good) >= 0.9 * len(samples), f"too many flagged: {S.flag_names(np.bitwise_or.reduce(samples.flags))}"
    med = np.median(np.abs(rel), axis=0)
    p95 = np.percentile(np.abs(rel), 95, axis=0)
    report = ", ".join(f"{c}: median {m:.3%} p95 {p:.3%}" for c, m, p in zip("RGB", med, p95))
    print(f"{len(good)} samples — {report}")
    assert np.all(med <= 0.01), report
    assert np.all(p95 <= 0.05), report
    return rel, good


def test_lambert_accuracy_per_channel(bench_factory, lambert):
    samples = run_poses(bench_factory(lambert))
    rel, good = check(samples, lambert)
    # every pose produced samples with positive uncertainty and real pixel counts
    assert set(np.unique(samples.pose)) == set(range(len(POSES)))
    assert np.all(good.sigma > 0) and np.all(good.n_pixels > 20)


def test_microfacet_ggx_accuracy(bench_factory):
    mat = make("microfacet", kd=[0.25, 0.2, 0.15], ks=0.6, alpha=0.3, f0=0.04, distribution="ggx")
    samples = run_poses(bench_factory(mat, seed=3))
    check(samples, mat)
    # the patch spans several degrees: it was cut into several angular bins per pose
    assert np.bincount(samples.pose).max() > 1


def test_uncertainty_is_consistent_with_the_error(bench_factory, lambert):
    """Few pixels per sample (fine bins, one frame): the noise dominates, z-scores ~ N(0, 1)."""
    from gonio.pipeline.acquire import PipelineSettings
    from gonio.pipeline.exposure import ExposureSettings

    st = PipelineSettings(max_bin_deg=0.2, max_bins=8, exposure=ExposureSettings(max_brackets=1, max_frames=1))
    bench = bench_factory(lambert, settings=st, sensor=None)
    samples = run_poses(bench, POSES[:3])
    rel, good = rel_errors(samples, lambert)
    z = (good.f - lambert.eval(good.wi, good.wo)) / good.sigma
    assert len(good) > 100
    assert 0.6 < np.std(z) < 1.6, np.std(z)


def test_light_drift_is_normalized_and_flagged(bench_factory, lambert):
    # the lamp warms up by 30 % with a 50 ms time constant: output changes across the bracket
    bench = bench_factory(lambert, drift=0.3, tau=0.05)
    res = bench.measure(30, 20, 20, 200)
    assert np.all(res.samples.flags & S.DRIFT)
    ref = lambert.eval(res.samples.wi, res.samples.wo)
    assert np.median(np.abs(res.samples.f / ref - 1)) < 0.01


def test_absolute_mode_from_a_calibrated_light(bench_factory, lambert):
    from sim.camera import SensorModel

    sn = SensorModel()
    scale = np.asarray(sn.responsivity) * sn.dn_per_electron  # DN/s per unit f·I·cosθ/r², I = 1
    samples = run_poses(bench_factory(lambert, absolute_scale=scale), POSES[:2])
    check(samples, lambert)


@pytest.mark.parametrize("bits", [16])
def test_16_bit_sensor(bench_factory, lambert, bits):
    from sim.camera import SensorModel

    samples = run_poses(bench_factory(lambert, sensor=SensorModel(bit_depth=bits)), POSES[:2])
    check(samples, lambert)
