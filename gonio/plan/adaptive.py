"""Adaptive plans: measure coarse, fit, then add poses where the model is least certain or fits worst,
until a target error or a lab-time budget is reached ("model only what the data requires").

The loop is written against two callables so it runs on a rig, on the simulator, or on an analytic
material directly:

* ``measure(poses (k, 4)) -> SampleSet`` — measure the given poses (``pose`` column = row index into
  ``poses``, or −1 with one sample per pose in order);
* ``fit(samples) -> model`` — any object with ``eval(wi, wo) -> (..., 3)`` (e.g. a
  :class:`gonio.brdf.BRDF` built from a :func:`gonio.fit.fit` result; :func:`fit_model` makes one).

Selection (one round):

* *uncertainty* — query by committee (Seung, Opper & Sompolinsky, COLT 1992): the disagreement
  ``|f_k − f_{k−1}|`` of the last two fitted models at each candidate pose; where successive fits still
  disagree, the data do not pin the model down;
* *residual* — the relative residual ``|f_k − f_meas|`` of the nearest measured pose (distance in the
  6-D space of (wi, wo)), i.e. regions the model family fits badly get denser sampling;
* *coverage* — a small term proportional to the distance to the nearest measured pose.

Candidates are picked greedily by score, each pick damping the scores of its neighbours
(``1 − exp(−(d/ℓ)²)``) so a batch spreads out. The stopping error is the relative RMS error with
which the current model *predicts* a new batch before it is refitted (an out-of-sample estimate).
Lab time uses :mod:`gonio.plan.ordering`: each batch is ordered from the rig's current joints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from gonio.errors import ConfigError
from gonio.geometry import dirs_from_angles
from gonio.plan.ordering import MotionModel, optimize_order
from gonio.plan.plan import Plan
from gonio.samples import SampleSet

__all__ = ["AdaptiveResult", "adaptive_plan", "fit_model", "relative_rms"]


def relative_rms(pred, meas) -> float:
    """``‖pred − meas‖₂ / ‖meas‖₂`` over all samples and channels (0 if both vanish)."""
    pred, meas = np.asarray(pred, float), np.asarray(meas, float)
    den = float(np.sqrt(np.mean(meas ** 2)))
    num = float(np.sqrt(np.mean((pred - meas) ** 2)))
    return num / den if den > 0 else (0.0 if num == 0 else np.inf)


@dataclass
class AdaptiveResult:
    """Outcome of :func:`adaptive_plan`.

    ``plan`` holds the measured poses in measurement order; ``history`` one dict per round
    (``round``, ``n_poses``, ``lab_time``, ``error`` = relative RMS prediction error of that round's
    batch, None for the first); ``stop`` says why the loop ended (``target``, ``budget``,
    ``exhausted``, ``rounds``).
    """

    plan: Plan
    samples: SampleSet
    model: Any
    lab_time: float
    stop: str
    history: list[dict] = field(default_factory=list)


def _features(poses: np.ndarray) -> np.ndarray:
    wi, wo = dirs_from_angles(*poses.T)
    return np.hstack([wi, wo])


def _nearest(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each row of ``a``: distance to and index of its nearest row of ``b``."""
    from scipy.spatial import cKDTree

    d, i = cKDTree(b).query(a)
    return np.asarray(d, float), np.asarray(i, np.int64)


def _farthest_points(x: np.ndarray, k: int, rng) -> np.ndarray:
    """``k`` rows of ``x`` spread out by farthest-point sampling (Gonzalez 1985), seeded start."""
    chosen = [int(rng.integers(len(x)))]
    d = np.linalg.norm(x - x[chosen[0]], axis=1)
    for _ in range(min(k, len(x)) - 1):
        j = int(np.argmax(d))
        chosen.append(j)
        d = np.minimum(d, np.linalg.norm(x - x[j], axis=1))
    return np.array(chosen, np.int64)


def _by_pose(samples: SampleSet, k: int) -> SampleSet:
    """Samples whose ``pose`` column indexes the ``k`` requested poses (validated)."""
    if len(samples) == k and np.all(samples.pose == -1):
        return SampleSet(**{**samples.to_dict(), "pose": np.arange(k)})
    if len(samples) and (samples.pose.min() < 0 or samples.pose.max() >= k):
        raise ConfigError.field("adaptive", "measure(poses).pose", samples.pose.tolist()[:5],
                                f"must index the {k} requested poses")
    return samples


def adaptive_plan(candidates: Plan, measure: Callable[[np.ndarray], SampleSet], fit: Callable[[SampleSet], Any], *,
                  motion: MotionModel, n_initial: int = 24, batch: int = 16, target_error: float = 0.05,
                  lab_budget: float = np.inf, max_rounds: int = 20, weights=(1.0, 1.0, 0.05),
                  seed: int = 0) -> AdaptiveResult:
    """Grow a plan from ``candidates`` adaptively (see the module docstring).

    Parameters
    ----------
    candidates : Plan
        The reachable poses to choose from, with their joints (e.g. a dense :func:`make_plan`).
    measure, fit : callable
        See the module docstring.
    motion : MotionModel
        Joint limits for the lab-time account (:meth:`MotionModel.from_rig`).
    n_initial, batch : int
        Poses in the coarse first round and in each later round.
    target_error : float
        Stop when a batch is predicted with relative RMS error ≤ this.
    lab_budget : float
        Lab seconds available (moves + settle + capture); a batch is cut to fit.
    weights : (uncertainty, residual, coverage)
        Weights of the three selection terms.
    """
    if candidates.joints is None:
        raise ConfigError.field("adaptive", "candidates.joints", None, "the candidate plan needs joint angles")
    if n_initial < 1 or batch < 1:
        raise ConfigError.field("adaptive", "n_initial/batch", (n_initial, batch), "must be >= 1")
    rng = np.random.default_rng(seed)
    poses, joints = candidates.poses, candidates.joints
    x = _features(poses)
    pose_time = candidates.capture.pose_time()
    measured: list[int] = []
    sets: list[SampleSet] = []
    history: list[dict] = []
    lab, current, model, prev_model = 0.0, None, None, None
    w_unc, w_res, w_cov = weights
    pick = _farthest_points(x, n_initial, rng)
    stop = "rounds"
    for rnd in range(max_rounds):
        # lab-time account: order the batch from where the rig is; cut it to the budget
        order = pick[optimize_order(joints[pick], motion, start=current, seed=seed)]
        steps = motion.move_time(np.vstack([joints[order[:1]] if current is None else current[None], joints[order[:-1]]]),
                                 joints[order]) + pose_time
        fits = int(np.searchsorted(np.cumsum(steps), lab_budget - lab, side="right"))
        order = order[:fits]
        if len(order) == 0:
            stop = "budget"
            break
        lab += float(np.sum(steps[:fits]))
        current = joints[order[-1]]
        got = _by_pose(measure(poses[order]), len(order))
        got = SampleSet(**{**got.to_dict(), "pose": order[got.pose]})
        err = None if model is None else relative_rms(model.eval(got.wi, got.wo), got.f)
        measured.extend(order.tolist())
        sets.append(got)
        history.append({"round": rnd, "n_poses": len(measured), "lab_time": lab, "error": err})
        if err is not None and err <= target_error:
            stop = "target"
            break
        if fits < len(pick):
            stop = "budget"
            break
        prev_model, model = model, fit(SampleSet.concat(sets))
        left = np.setdiff1d(np.arange(len(poses)), measured)
        if len(left) == 0:
            stop = "exhausted"
            break
        # scores of the unmeasured candidates
        all_s = SampleSet.concat(sets)
        scale = float(np.sqrt(np.mean(all_s.f ** 2))) or 1.0
        wi_c, wo_c = dirs_from_angles(*poses[left].T)
        f_now = model.eval(wi_c, wo_c)
        unc = np.zeros(len(left)) if prev_model is None else \
            np.abs(f_now - prev_model.eval(wi_c, wo_c)).mean(axis=-1) / scale
        res_pose = np.zeros(len(poses))
        np.maximum.at(res_pose, all_s.pose, np.abs(model.eval(all_s.wi, all_s.wo) - all_s.f).mean(axis=-1) / scale)
        dist, near = _nearest(x[left], x[np.array(measured)])
        score = w_unc * unc + w_res * res_pose[np.array(measured)[near]] + w_cov * dist
        ell = float(np.median(dist)) + 1e-12
        chosen = []
        for _ in range(min(batch, len(left))):
            j = int(np.argmax(score))
            chosen.append(left[j])
            score = score * (1.0 - np.exp(-(np.linalg.norm(x[left] - x[left[j]], axis=1) / ell) ** 2))
            score[j] = -np.inf
        pick = np.array(chosen, np.int64)
    samples = SampleSet.concat(sets)
    if model is None or stop in ("target", "budget", "rounds"):
        model = fit(samples)
    plan = Plan(poses=poses[measured], capture=candidates.capture, generator="adaptive",
                params={"candidates": candidates.generator, "candidate_params": dict(candidates.params),
                        "n_initial": n_initial, "batch": batch, "target_error": target_error,
                        "lab_budget": None if not np.isfinite(lab_budget) else lab_budget, "seed": seed,
                        "stop": stop, "candidate_index": list(map(int, measured))},
                dropped=candidates.dropped, joints=joints[measured], order="adaptive")
    return AdaptiveResult(plan=plan, samples=samples, model=model, lab_time=lab, stop=stop, history=history)


def fit_model(model: str = "lambert+ggx", **fit_kw) -> Callable[[SampleSet], Any]:
    """A ``fit`` callable for :func:`adaptive_plan` built on :func:`gonio.fit.fit.fit` (lazy import)."""

    def _fit(samples: SampleSet):
        from gonio.brdf import make
        from gonio.fit.fit import fit as do_fit

        res = do_fit(samples, model, **fit_kw)
        return make(res.model, **res.params)

    return _fit
