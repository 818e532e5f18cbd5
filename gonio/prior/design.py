"""Choosing the few poses to measure: Bayesian A-optimal design under a prior, within the rig's reach.

Candidates (:func:`candidate_poses`) are the poses of an isotropic grid (φi = 0; θi, θo, φo on a grid) that the
rig can reach — joint limits, arm collisions and the camera's shadow are decided by
:meth:`gonio.rig.kinematics.Rig.solve_many` through :func:`gonio.plan.generators.make_plan`, so an unreachable
pose is never a candidate.

Selection (:func:`select_directions`): greedy A-optimality (Chaloner & Verdinelli, "Bayesian experimental
design: a review", Statist. Sci. 10(3), 1995, §2.2; the greedy rank-one form as in Krause, Singh & Guestrin,
JMLR 9, 2008): start from the prior covariance S = diag(s²) of the coefficients and add, one at a time, the
candidate that most reduces the expected reconstruction error tr(M·S), M = Bᵀ diag(Q) B (Q: the nodes' shares of
the MERL cells, :mod:`gonio.prior.posterior`). For a candidate with design row a and noise v the reduction is
(Sherman–Morrison) ``a S M S aᵀ / (v + a S aᵀ)``; v = σ_u²/k + h·τ² (the pose's k samples average the noise
σ_u, not the prior's residual τ² at that direction). Nielsen et al. 2015 instead minimise the condition number
of the sampled principal components (:mod:`gonio.prior.nielsen`); the A-optimal choice uses the components'
variances and the residual, which the condition number ignores.

:func:`sparse_plan` orders the chosen poses for lab time (:func:`gonio.plan.ordering.optimize_order`) and returns
an ordinary :class:`gonio.plan.Plan` (generator ``"sparse"``) with the expected error in its parameters; ``gonio
measure --plan-file`` and ``gonio measure --plan sparse`` run it like any plan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gonio.prior.model import Prior

__all__ = ["CANDIDATES", "SAMPLES_PER_POSE", "candidate_poses", "select_directions", "Design", "sparse_plan",
           "expected_error_curve"]

#: Candidate grid (radians) of :func:`candidate_poses`: the ``isotropic`` generator at 5° in θ, 10° in φo, θ ≤ 80°.
CANDIDATES = {"theta_step": math.radians(5.0), "phi_step": math.radians(10.0), "theta_max": math.radians(80.0)}
#: Samples one pose gives on the default target (one per reflectance tile; a simulated session of the default
#: plan: 1093 samples from 38 poses).
SAMPLES_PER_POSE = 28
#: Relative noise of one sample assumed while planning (the default capture's median σ/f is ~0.6 %).
SIGMA_REL = 0.01


def candidate_poses(rig=None, **params):
    """Reachable candidate poses on ``rig`` (default rig if None): a raster-ordered :class:`gonio.plan.Plan`
    of the ``isotropic`` generator with :data:`CANDIDATES` (overridden by ``params``, radians)."""
    from gonio.plan.generators import make_plan

    return make_plan("isotropic", rig=rig, order="raster", **{**CANDIDATES, **params})


def _directions(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from gonio.geometry import dirs_from_angles

    p = np.asarray(poses, dtype=np.float64)
    return dirs_from_angles(p[:, 0], p[:, 1], p[:, 2], p[:, 3])


@dataclass(frozen=True)
class Design:
    """The chosen candidates (indices into the candidate list, in the order chosen) and the expected error
    (:meth:`gonio.prior.posterior.Posterior.expected_error`) after each: ``errors[0]`` before any sample."""

    indices: np.ndarray
    errors: np.ndarray

    @property
    def expected_error(self) -> float:
        return float(self.errors[-1])


def select_directions(prior: Prior, wi, wo, n: int, *, sigma_u: float = SIGMA_REL, samples_per_pose: int = 1,
                      start=None) -> Design:
    """Greedy A-optimal choice of ``n`` of the candidate direction pairs ``wi``, ``wo`` (N, 3) (module
    docstring). ``start``: a :class:`gonio.prior.posterior.Posterior` to continue from (adaptive measuring);
    the planning covariance is then its mean over channels."""
    h = prior.grid.weights(wi, wo)
    a = np.asarray(h @ prior.basis)
    v = sigma_u ** 2 / max(samples_per_pose, 1) + h @ prior.residual
    m = prior.basis.T @ (prior.basis * prior.weight[:, None])
    s = np.diag(prior.variance) if start is None else start.covariance.mean(axis=0)
    q = prior.weight
    base, total = float(np.sum(q * prior.residual)), float(np.sum(q))

    def err(cov):
        return math.sqrt((float(np.sum(m * cov)) + base) / total)

    chosen, errors = [], [err(s)]
    avail = np.ones(len(a), dtype=bool)
    for _ in range(min(n, len(a))):
        ps = a @ s
        gain = np.sum((ps @ m) * ps, axis=1) / np.maximum(v + np.sum(ps * a, axis=1), 1e-300)
        gain[~avail] = -np.inf
        j = int(np.argmax(gain))
        sa = s @ a[j]
        s = s - np.outer(sa, sa) / (v[j] + a[j] @ sa)
        s = 0.5 * (s + s.T)
        avail[j] = False
        chosen.append(j)
        errors.append(err(s))
    return Design(np.array(chosen, dtype=np.int64), np.array(errors))


def expected_error_curve(prior: Prior, n_max: int, rig=None, **kw) -> np.ndarray:
    """Expected error after 0…``n_max`` greedily chosen reachable poses (``errors`` of :class:`Design`)."""
    cand = candidate_poses(rig)
    wi, wo = _directions(cand.poses)
    return select_directions(prior, wi, wo, n_max, samples_per_pose=SAMPLES_PER_POSE, **kw).errors


def sparse_plan(n: int, prior: Prior, *, rig=None, capture=None, order: str = "optimized", seed: int = 0,
                time_budget: float | None = None, prior_name: str | None = None, sigma_rel: float = SIGMA_REL,
                source: str | None = None):
    """A :class:`gonio.plan.Plan` of ``n`` poses chosen under ``prior`` among the poses ``rig`` reaches (module
    docstring), ordered for lab time; ``plan.params`` holds ``n``, the prior's name and the expected error."""
    from gonio.errors import ConfigError
    from gonio.plan.ordering import MotionModel, optimize_order
    from gonio.plan.plan import Plan

    if isinstance(n, bool) or int(n) != n or not 1 <= n <= 1000:
        raise ConfigError.field(source, "n", n, "must be an integer in [1, 1000]")
    n = int(n)
    cand = candidate_poses(rig)
    wi, wo = _directions(cand.poses)
    design = select_directions(prior, wi, wo, n, sigma_u=sigma_rel, samples_per_pose=SAMPLES_PER_POSE)
    idx = design.indices
    from gonio.rig.kinematics import Rig, load_rig

    rig = rig if isinstance(rig, Rig) else load_rig(rig)
    params = {"n": n, "prior": prior_name or prior.metadata.get("name") or "custom", "rig": rig.name, "seed": seed,
              "expected_error": design.expected_error, "expected_error_prior": float(design.errors[0]),
              "error_measure": "expected RMS error of ln(f·cosθi·cosθo + ε) over the MERL cells (docs/prior.md)",
              "candidates": {k: v for k, v in CANDIDATES.items()}, "samples_per_pose": SAMPLES_PER_POSE}
    plan = Plan(poses=cand.poses[idx], capture=capture or cand.capture, generator="sparse", params=params,
                dropped=cand.dropped, joints=cand.joints[idx], order="generated")
    if order == "optimized" and len(plan) > 1:
        perm = optimize_order(plan.joints, MotionModel.from_rig(rig), seed=seed, time_budget=time_budget,
                              initial=np.arange(len(plan)))
        plan = plan.reordered(perm, "optimized")
    elif order == "raster":
        from gonio.plan.ordering import raster_order

        plan = plan.reordered(raster_order(plan.poses), "raster")
    return plan
