"""A fit to a session's samples takes the errors they share within a pose into account (gonio.fit.correlated): with
a shared error per pose its stated σ covers the truth, where the independent-samples σ is many times too small."""

from __future__ import annotations

import numpy as np

from gonio.fit.fit import fit
from gonio.samples import SampleSet


def _session(seed, poses=12, per_pose=60, shared=0.02, own=0.002, stated_shared=True):
    """A Lambertian sample (albedo 0.5): each pose's values off by one relative error of ``shared`` (its geometry),
    each sample by its own ``own``; the samples state σ² = own² + shared² and sigma_pose = shared (or 0)."""
    rng = np.random.default_rng(seed)
    n = poses * per_pose
    ti, to = rng.uniform(0.1, 1.0, (2, n))
    pi_, po = rng.uniform(0, 2 * np.pi, (2, n))
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], -1)
    wo = np.stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)], -1)
    truth = 0.5 / np.pi
    pose = np.repeat(np.arange(poses), per_pose)
    f = truth * (1 + rng.normal(0, shared, (poses, 1))[pose] + rng.normal(0, own, (n, 3)))
    s_pose = np.full((n, 3), truth * shared)
    sigma = np.sqrt((truth * own) ** 2 + s_pose ** 2)
    return SampleSet(wi, wo, f, sigma, pose=pose, sigma_pose=s_pose if stated_shared else None)


def test_the_stated_sigma_covers_a_shared_error_per_pose():
    z, ratio = [], []
    for seed in range(30):
        r = fit(_session(seed), "lambert", report=False)
        a, u = np.asarray(r.params["albedo"]), np.asarray(r.uncertainty["albedo"])
        z.append(np.abs(a - 0.5) / u)
        # the independent-samples σ: per channel the scatter over √n
        ratio.append(u[0] / (0.02 * 0.5 / np.sqrt(12)))
        assert any("correlated within each of the 12 poses" in n for n in r.notes)
    z = np.concatenate(z)
    assert np.mean(z < 2) >= 0.85 and np.mean(z < 3) >= 0.97
    assert 0.7 < np.median(ratio) < 1.6  # about the pose-to-pose scatter over √(poses), not √(samples)


def test_without_a_stated_shared_part_the_cluster_robust_sigma_still_sees_it():
    """sigma_pose not recorded (older sessions): the scatter between poses shows the shared error."""
    z = []
    for seed in range(30):
        r = fit(_session(seed, stated_shared=False), "lambert", report=False)
        z.append(np.abs(np.asarray(r.params["albedo"]) - 0.5) / np.asarray(r.uncertainty["albedo"]))
    z = np.concatenate(z)
    assert np.mean(z < 3) >= 0.9


def test_samples_without_poses_keep_the_independent_estimate():
    s = _session(0)
    plain = SampleSet(s.wi, s.wo, s.f, s.sigma)  # pose −1: not a session's
    r = fit(plain, "lambert", report=False)
    assert not any("correlated" in n for n in r.notes)
