"""Adaptive plans: measure coarse, fit, then add poses where the model is least certain or fits worst,
until a target error or a lab-time budget is reached ("model only what the data requires").

The planner (:class:`AdaptivePlanner`) is data in, data out: from the candidate poses and the samples
measured so far it computes the next :class:`Round` (candidate indices in measurement order, with its
lab-time account) or says why to stop. It never measures. Two loops drive it:

* :func:`adaptive_plan` — written against two callables, so it runs on an analytic material directly:
  ``measure(poses (k, 4)) -> SampleSet`` (``pose`` column = row index into ``poses``, or −1 with one
  sample per pose in order) and ``fit(samples) -> model`` (any object with ``eval(wi, wo) -> (..., 3)``;
  :func:`fit_model` and :func:`select_model` make one from :mod:`gonio.fit`);
* :class:`gonio.session.adaptive.AdaptiveSession` — each round is a :class:`~gonio.plan.Plan` the
  session runner executes on the rig (or the simulator), appending to one session store.

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
Lab time uses :mod:`gonio.plan.ordering`: each batch is ordered from the rig's current joints and its
moves + settle + capture are added up; a batch is cut to what the budget still allows. That account
is a function of the poses only, so a resumed session makes the same decisions as an uninterrupted
one (the one-off costs of a session — device checks, warm-up, dark frames — are not in it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from gonio.errors import ConfigError
from gonio.geometry import dirs_from_angles
from gonio.plan.ordering import MotionModel, optimize_order
from gonio.plan.plan import Plan
from gonio.samples import SampleSet

__all__ = ["AdaptiveResult", "AdaptiveSettings", "AdaptivePlanner", "Round", "Decision", "adaptive_plan",
           "fit_model", "select_model", "relative_rms", "STOP_REASONS", "ADAPTIVE_FORMAT", "round_entry"]

#: Version of a session manifest's ``adaptive`` section (:mod:`gonio.session.adaptive`).
ADAPTIVE_FORMAT = 1

#: Why an adaptive plan stops: the prediction error reached the target, the lab-time budget is used up,
#: every candidate is measured, or the round limit was reached.
STOP_REASONS = ("target", "budget", "exhausted", "rounds")


def relative_rms(pred, meas) -> float:
    """``‖pred − meas‖₂ / ‖meas‖₂`` over all samples and channels (0 if both vanish)."""
    pred, meas = np.asarray(pred, float), np.asarray(meas, float)
    den = float(np.sqrt(np.mean(meas ** 2)))
    num = float(np.sqrt(np.mean((pred - meas) ** 2)))
    return num / den if den > 0 else (0.0 if num == 0 else np.inf)


@dataclass(frozen=True)
class AdaptiveSettings:
    """Parameters of an adaptive plan.

    Attributes
    ----------
    n_initial, batch : int
        Poses in the coarse first round (farthest-point spread) and in each later round.
    target_error : float
        Stop when a round's samples are predicted with relative RMS error ≤ this.
    lab_budget : float
        Lab seconds available for the poses (moves + settle + capture); ``inf`` for none.
    max_rounds : int
        Rounds at most (the first included).
    weights : (uncertainty, residual, coverage)
        Weights of the three selection terms.
    seed : int
        Seeds the first pose of the coarse round and the ordering heuristic.
    round_overhead : float
        Lab seconds every round costs besides its poses (a session's runner checks the devices and the
        light's stability at the start of each run: one photodiode step); counted against the budget.
    """

    n_initial: int = 24
    batch: int = 16
    target_error: float = 0.05
    lab_budget: float = math.inf
    max_rounds: int = 20
    weights: tuple[float, float, float] = (1.0, 1.0, 0.05)
    seed: int = 0
    round_overhead: float = 0.0

    def __post_init__(self):
        src = "adaptive"
        for name in ("n_initial", "batch", "max_rounds", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (0 if name == "seed" else 1):
                raise ConfigError.field(src, name, v, "must be an integer >= " + ("0" if name == "seed" else "1"))
            object.__setattr__(self, name, int(v))
        ro = float(self.round_overhead)
        if not math.isfinite(ro) or ro < 0:
            raise ConfigError.field(src, "round_overhead", self.round_overhead, "must be >= 0 seconds")
        object.__setattr__(self, "round_overhead", ro)
        for name in ("target_error", "lab_budget"):
            v = getattr(self, name)
            v = math.inf if v is None and name == "lab_budget" else v
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise ConfigError.field(src, name, v, "must be a number") from None
            if math.isnan(v) or v < 0 or (name == "lab_budget" and v == 0) or (name == "target_error" and math.isinf(v)):
                raise ConfigError.field(src, name, v, "must be >= 0" if name == "target_error" else
                                        "must be positive seconds")
            object.__setattr__(self, name, v)
        w = tuple(float(x) for x in np.asarray(self.weights, dtype=np.float64).reshape(-1))
        if len(w) != 3 or not all(math.isfinite(x) and x >= 0 for x in w):
            raise ConfigError.field(src, "weights", list(w), "need 3 non-negative numbers (uncertainty, residual, "
                                    "coverage)")
        object.__setattr__(self, "weights", w)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able (an infinite budget is ``None``)."""
        return {"n_initial": self.n_initial, "batch": self.batch, "target_error": self.target_error,
                "lab_budget": None if math.isinf(self.lab_budget) else self.lab_budget,
                "max_rounds": self.max_rounds, "weights": list(self.weights), "seed": self.seed,
                "round_overhead": self.round_overhead}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], source: str = "adaptive") -> "AdaptiveSettings":
        if not isinstance(d, Mapping):
            raise ConfigError.field(source, "settings", d, "must be a table")
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise ConfigError.field(source, f"settings.{unknown[0]}", d[unknown[0]], "unknown field")
        try:
            return cls(**dict(d))
        except ConfigError as exc:
            raise ConfigError(f"{source}: {str(exc).removeprefix('adaptive: ')}") from None


@dataclass
class Round:
    """One round of an adaptive plan.

    Attributes
    ----------
    index : int
        0 for the coarse round.
    candidates : ndarray (k,) int
        Indices into the candidate plan, in measurement order.
    lab_time : float
        Estimated lab seconds of the round: the round overhead + moves (from the previous round's last
        pose) + settle + capture.
    lab_total : float
        Estimated lab seconds of this and every earlier round.
    cut : bool
        The selection was shortened to fit the lab-time budget.
    error : float or None
        Relative RMS error with which the model of the earlier rounds predicted this round's samples
        (None for the first round, or until the round is measured and assessed).
    """

    index: int
    candidates: np.ndarray
    lab_time: float
    lab_total: float
    cut: bool = False
    error: float | None = None

    def __post_init__(self):
        self.candidates = np.asarray(self.candidates, dtype=np.int64).reshape(-1)

    def to_dict(self) -> dict[str, Any]:
        return {"round": self.index, "candidate_index": self.candidates.tolist(), "n_poses": len(self.candidates),
                "lab_time_estimate_s": self.lab_time, "lab_total_estimate_s": self.lab_total, "cut": self.cut,
                "error": self.error}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "Round":
        return cls(index=int(d["round"]), candidates=np.asarray(d["candidate_index"], dtype=np.int64),
                   lab_time=float(d["lab_time_estimate_s"]), lab_total=float(d["lab_total_estimate_s"]),
                   cut=bool(d.get("cut", False)), error=None if d.get("error") is None else float(d["error"]))


def round_entry(rnd: "Round", first_pose: int) -> dict[str, Any]:
    """A round as a session manifest records it before it is measured (:mod:`gonio.session.adaptive`)."""
    return {**rnd.to_dict(), "first_pose": int(first_pose), "status": "planned", "model_after": None,
            "lab_time_s": 0.0}


@dataclass
class Decision:
    """What :meth:`AdaptivePlanner.decide` concluded after a round: its prediction error, and either
    why to stop or the next round."""

    error: float | None
    stop: str | None = None
    next: Round | None = None
    model: Any = None  #: the model fitted on every round so far (None if the planner did not need it)


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


class AdaptivePlanner:
    """Plans the rounds of an adaptive plan over ``candidates``; see the module docstring.

    Parameters
    ----------
    candidates : Plan
        The reachable poses to choose from, with their joints (e.g. a dense :func:`make_plan`).
    fit : callable(SampleSet) -> model
        Fits a model to samples whose ``pose`` column holds candidate indices.
    motion : MotionModel
        Joint limits for the lab-time account (:meth:`MotionModel.from_rig`).
    settings : AdaptiveSettings

    Fitted models are cached per number of rounds, so a loop that calls :meth:`decide` once per round
    fits once per round; the samples of a round must not change after it was assessed.
    """

    def __init__(self, candidates: Plan, fit: Callable[[SampleSet], Any], *, motion: MotionModel,
                 settings: AdaptiveSettings | None = None):
        if candidates.joints is None:
            raise ConfigError.field("adaptive", "candidates.joints", None, "the candidate plan needs joint angles")
        if len(candidates) == 0:
            raise ConfigError.field("adaptive", "candidates", 0, "no candidate pose")
        self.candidates, self.fit, self.motion = candidates, fit, motion
        self.settings = settings or AdaptiveSettings()
        self._x = _features(candidates.poses)
        self._models: dict[int, Any] = {}

    # -- rounds ---------------------------------------------------------------------------------
    def _round(self, index: int, pick: np.ndarray, current, lab_before: float) -> Round:
        """Order ``pick`` from ``current`` joints (None: anywhere) and cut it to the remaining budget."""
        s, joints = self.settings, self.candidates.joints
        order = pick[optimize_order(joints[pick], self.motion, start=current, seed=s.seed)]
        prev = joints[order[:1]] if current is None else np.asarray(current, dtype=np.float64)[None]
        steps = self.motion.move_time(np.vstack([prev, joints[order[:-1]]]), joints[order]) \
            + self.candidates.capture.pose_time()
        fits = int(np.searchsorted(np.cumsum(steps), s.lab_budget - lab_before - s.round_overhead, side="right"))
        lab = float(np.sum(steps[:fits])) + (s.round_overhead if fits else 0.0)
        return Round(index, order[:fits], lab, lab_before + lab, cut=fits < len(order))

    def first_round(self) -> Round:
        """The coarse round: ``n_initial`` candidates spread by farthest-point sampling.

        Raises :class:`ConfigError` if the lab-time budget does not allow a single pose."""
        s = self.settings
        rnd = self._round(0, _farthest_points(self._x, s.n_initial, np.random.default_rng(s.seed)), None, 0.0)
        if len(rnd.candidates) == 0:
            raise ConfigError.field("adaptive", "lab_budget", s.lab_budget,
                                    f"too small for a single pose ({self.candidates.capture.pose_time():.3g} s each)")
        return rnd

    def model(self, samples: Sequence[SampleSet], n_rounds: int):
        """The model fitted on the samples of the first ``n_rounds`` rounds (cached)."""
        if n_rounds not in self._models:
            self._models[n_rounds] = self.fit(SampleSet.concat(samples[:n_rounds]))
        return self._models[n_rounds]

    def decide(self, rounds: Sequence[Round], samples: Sequence[SampleSet]) -> Decision:
        """After the last of ``rounds`` was measured (``samples[k]``: round k's samples, ``pose`` =
        candidate index): its prediction error, and the next round or why to stop."""
        s = self.settings
        r = len(rounds) - 1
        if r < 0 or len(samples) != len(rounds):
            raise ValueError(f"decide: {len(rounds)} rounds but {len(samples)} sample sets")
        got = samples[r].good()
        err = None if r == 0 or len(got) == 0 else relative_rms(self.model(samples, r).eval(got.wi, got.wo), got.f)
        if err is not None and err <= s.target_error:
            return Decision(err, "target")
        if rounds[r].cut:
            return Decision(err, "budget")
        if r + 1 >= s.max_rounds:
            return Decision(err, "rounds")
        model = self.model(samples, r + 1)
        measured = np.concatenate([rd.candidates for rd in rounds])
        left = np.setdiff1d(np.arange(len(self.candidates)), measured)
        if len(left) == 0:
            return Decision(err, "exhausted", model=model)
        pick = self._select(left, measured, SampleSet.concat(samples).good(), model,
                            self.model(samples, r) if r >= 1 else None)
        current = self.candidates.joints[rounds[r].candidates[-1]] if len(rounds[r].candidates) else None
        nxt = self._round(r + 1, pick, current, rounds[r].lab_total)
        if len(nxt.candidates) == 0:
            return Decision(err, "budget", model=model)
        return Decision(err, None, nxt, model)

    def _select(self, left, measured, all_s: SampleSet, model, prev_model) -> np.ndarray:
        """Greedy batch of ``left`` candidates by the score of the module docstring."""
        w_unc, w_res, w_cov = self.settings.weights
        x, poses = self._x, self.candidates.poses
        scale = float(np.sqrt(np.mean(all_s.f ** 2))) if len(all_s) else 1.0
        scale = scale or 1.0
        wi_c, wo_c = dirs_from_angles(*poses[left].T)
        f_now = model.eval(wi_c, wo_c)
        unc = np.zeros(len(left)) if prev_model is None else \
            np.abs(f_now - prev_model.eval(wi_c, wo_c)).mean(axis=-1) / scale
        res_pose = np.zeros(len(poses))
        if len(all_s):
            np.maximum.at(res_pose, all_s.pose,
                          np.abs(model.eval(all_s.wi, all_s.wo) - all_s.f).mean(axis=-1) / scale)
        dist, near = _nearest(x[left], x[measured])
        score = w_unc * unc + w_res * res_pose[measured[near]] + w_cov * dist
        ell = float(np.median(dist)) + 1e-12
        chosen = []
        for _ in range(min(self.settings.batch, len(left))):
            j = int(np.argmax(score))
            chosen.append(left[j])
            score = score * (1.0 - np.exp(-(np.linalg.norm(x[left] - x[left[j]], axis=1) / ell) ** 2))
            score[j] = -np.inf
        return np.array(chosen, np.int64)

    # -- the plan as data -------------------------------------------------------------------------
    def plan(self, rounds: Sequence[Round], stop: str | None = None, extra: Mapping[str, Any] | None = None) -> Plan:
        """The poses of ``rounds``, concatenated in measurement order, as a :class:`Plan` (pose *k* of
        the plan is pose *k* of a session), with the settings, the candidate indices, the poses per
        round and ``stop`` in its parameters."""
        c = self.candidates
        idx = np.concatenate([r.candidates for r in rounds]) if rounds else np.zeros(0, np.int64)
        params = {"candidates": c.generator, "candidate_params": dict(c.params), **self.settings.to_dict(),
                  "stop": stop, "candidate_index": idx.tolist(), "round_sizes": [len(r.candidates) for r in rounds],
                  **dict(extra or {})}
        return Plan(poses=c.poses[idx], capture=c.capture, generator="adaptive", params=params, dropped=c.dropped,
                    joints=c.joints[idx], order="adaptive")


@dataclass
class AdaptiveResult:
    """Outcome of :func:`adaptive_plan`.

    ``plan`` holds the measured poses in measurement order; ``history`` one dict per round
    (``round``, ``n_poses``, ``lab_time``, ``error`` = relative RMS prediction error of that round's
    batch, None for the first); ``stop`` says why the loop ended (one of :data:`STOP_REASONS`).
    """

    plan: Plan
    samples: SampleSet
    model: Any
    lab_time: float
    stop: str
    history: list[dict] = field(default_factory=list)
    rounds: list[Round] = field(default_factory=list)


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
                  seed: int = 0, round_overhead: float = 0.0) -> AdaptiveResult:
    """Grow a plan from ``candidates`` adaptively, measuring through ``measure`` (see the module
    docstring; the parameters are those of :class:`AdaptiveSettings`)."""
    settings = AdaptiveSettings(n_initial=n_initial, batch=batch, target_error=target_error, lab_budget=lab_budget,
                                max_rounds=max_rounds, weights=weights, seed=seed,
                                round_overhead=round_overhead)
    planner = AdaptivePlanner(candidates, fit, motion=motion, settings=settings)
    rounds: list[Round] = []
    sets: list[SampleSet] = []
    history: list[dict] = []
    rnd: Round | None = planner.first_round()
    stop = "rounds"
    for _ in range(settings.max_rounds):  # decide() stops at max_rounds; the bound is belt and braces
        if rnd is None:
            break
        order = rnd.candidates
        got = _by_pose(measure(candidates.poses[order]), len(order))
        got = SampleSet(**{**got.to_dict(), "pose": order[got.pose]})
        rounds.append(rnd)
        sets.append(got)
        d = planner.decide(rounds, sets)
        rnd.error = d.error
        history.append({"round": rnd.index, "n_poses": int(sum(len(r.candidates) for r in rounds)),
                        "lab_time": rnd.lab_total, "error": d.error})
        stop, rnd = d.stop or stop, d.next
    model = planner.model(sets, len(rounds))
    return AdaptiveResult(plan=planner.plan(rounds, stop), samples=SampleSet.concat(sets), model=model,
                          lab_time=rounds[-1].lab_total, stop=stop, history=history, rounds=rounds)


def fit_model(model: str = "lambert+ggx", **fit_kw) -> Callable[[SampleSet], Any]:
    """A ``fit`` callable for the planner built on :func:`gonio.fit.fit` (lazy import). The planner keeps the fitted
    model only, so the fit's report (error measures, goodness of fit, albedo check) is not computed unless
    ``report=True`` is passed."""

    def _fit(samples: SampleSet):
        from gonio.fit.fit import fit as do_fit

        return do_fit(samples, model, **{"report": False, **fit_kw}).build()

    return _fit


def select_model(candidates: Sequence[str] | None = None, **select_kw) -> Callable[[SampleSet], Any]:
    """A ``fit`` callable that chooses the model each round with :func:`gonio.fit.select.select`
    (default candidates: its own), so the model grows only as complex as the data require."""

    def _fit(samples: SampleSet):
        from gonio.fit.select import DEFAULT_CANDIDATES, select

        return select(samples, tuple(candidates or DEFAULT_CANDIDATES), **select_kw).winner.build()

    return _fit
