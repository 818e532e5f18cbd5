"""Adaptive sparse measuring under a prior (``gonio measure --plan sparse --adaptive``): after each pose, the next
is the one that most reduces the expected error of the reconstruction under the *posterior* of the samples
measured so far; stop at a target expected error or a pose budget.

:class:`PosteriorPlanner` is an :class:`gonio.plan.adaptive.AdaptivePlanner` (the same rounds, lab-time account,
manifest record and resume, :class:`gonio.session.adaptive.AdaptiveSession`) whose choices come from the prior:

* first round — the first ``n_initial`` poses of the fixed greedy A-optimal design under the prior
  (:func:`gonio.prior.design.select_directions`): nothing measured yet, the prior is all there is;
* after each round — the posterior of every usable sample so far (:class:`gonio.prior.Posterior`), its expected
  error (:meth:`~gonio.prior.Posterior.expected_error`, the RMS error of u = ln(f·cosθi·cosθo + ε) over the MERL
  cells: about a relative error), and the candidate that minimises the expected error *after* it
  (:meth:`~gonio.prior.Posterior.error_reduction`, the exact per-channel rank-one update — active learning
  by expected error reduction, Roy & McCallum, ICML 2001, in its closed Gaussian form; the A-optimal criterion
  of Chaloner & Verdinelli 1995 applied sequentially). In a linear-Gaussian model the posterior *covariance*
  does not depend on the measured values, so a criterion of the covariance alone is a fixed design measured in
  turn; what makes the choice adaptive is the error it targets: the cube-root error of the whole table
  (:meth:`~gonio.prior.Posterior.cbrt_weight`: each node weighted by (f̂ + ε)^⅔·cos^⅔θi, f̂ the posterior's
  value — where the material measured so far is bright, errors count more), and the candidate's noise in the
  mapped domain, predicted per channel from the posterior's value there: σ_u = σ_rel·f̂/(f̂ + ε) (delta method,
  :mod:`gonio.prior.mapping`); and a candidate counts the usable samples
  the nearest measured pose gave (within :data:`NEAR`): where the rig returned nothing usable (the board out of
  view at grazing angles, a shadow) the next pose is not chosen. ``batch`` > 1 picks that many greedily
  (:func:`select_directions` started from the posterior).

Stops: ``target`` (expected error ≤ ``target_error``), ``budget`` (``max_poses`` measured, or the lab-time
budget), ``exhausted`` (no candidate left). The manifest's ``adaptive`` section records ``planner = "prior"``
and the prior (name, file, SHA-256: a resumed session plans with the same prior, a changed file is refused).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from gonio.errors import ConfigError, DataError
from gonio.io.material_file import file_sha256 as _sha256
from gonio.plan.adaptive import AdaptivePlanner, AdaptiveSettings, Decision, Round
from gonio.plan.plan import Plan
from gonio.prior.design import SAMPLES_PER_POSE, SIGMA_REL, _directions, candidate_poses, select_directions
from gonio.prior.mapping import sigma_to_mapped
from gonio.prior.model import Prior
from gonio.samples import SampleSet

__all__ = ["SparseAdaptiveSettings", "PosteriorPlanner", "Reconstruction", "new_sparse_adaptive_manifest",
           "planner_from_manifest", "prior_record", "PLANNER"]

#: The manifest's ``adaptive.planner`` of a session planned by :class:`PosteriorPlanner`.
PLANNER = "prior"
#: Distance in (wi, wo) (the 6-vector of both directions) within which a measured pose's usable-sample count
#: predicts a candidate's: about 10° of one direction.
NEAR = 0.18


@dataclass(frozen=True)
class SparseAdaptiveSettings(AdaptiveSettings):
    """:class:`gonio.plan.adaptive.AdaptiveSettings` of a sparse adaptive session: ``n_initial`` poses of the
    fixed design first (default 4), then ``batch`` (default 1) per round; ``target_error`` is the posterior's
    expected error (0: run to the budget); ``max_poses`` the pose budget; ``sigma_rel`` the relative noise of a
    sample assumed while choosing; ``max_rounds`` follows from them."""

    n_initial: int = 4
    batch: int = 1
    target_error: float = 0.0
    max_poses: int = 20
    sigma_rel: float = SIGMA_REL
    max_rounds: int = 0  # derived: 1 + ceil((max_poses − n_initial) / batch)

    def __post_init__(self):
        mp = self.max_poses
        if isinstance(mp, bool) or not isinstance(mp, (int, np.integer)) or not 1 <= mp <= 1000:
            raise ConfigError.field("adaptive", "max_poses", mp, "must be an integer in [1, 1000]")
        object.__setattr__(self, "max_poses", int(mp))
        if isinstance(self.n_initial, (int, np.integer)) and not isinstance(self.n_initial, bool):
            object.__setattr__(self, "n_initial", int(min(self.n_initial, mp)))
        sr = self.sigma_rel
        if isinstance(sr, bool) or not isinstance(sr, (int, float)) or not (math.isfinite(sr) and sr > 0):
            raise ConfigError.field("adaptive", "sigma_rel", sr, "must be a positive number")
        if isinstance(self.batch, (int, np.integer)) and not isinstance(self.batch, bool) and self.batch >= 1 \
                and isinstance(self.n_initial, int) and self.n_initial >= 1:
            object.__setattr__(self, "max_rounds", 1 + math.ceil((mp - self.n_initial) / self.batch))
        super().__post_init__()

    def to_dict(self) -> dict[str, Any]:
        return {**super().to_dict(), "max_poses": self.max_poses, "sigma_rel": self.sigma_rel}


@dataclass(frozen=True)
class Reconstruction:
    """What a sparse adaptive session ends with (the manifest's ``adaptive.model``): the posterior of every
    usable sample; ``gonio reconstruct DIR`` writes its table."""

    posterior: Any
    prior_name: str = "prior"
    name: str = "prior posterior"

    @property
    def params(self) -> dict[str, Any]:
        return {"prior": self.prior_name, "samples": int(self.posterior.n_samples),
                "expected_error": float(self.posterior.expected_error())}


def _usable(samples: SampleSet) -> SampleSet:
    """Unflagged samples with finite values and σ > 0 (what :meth:`Posterior.update` takes)."""
    s = samples.good()
    ok = np.all(np.isfinite(s.f), axis=1) & np.all(np.isfinite(s.sigma) & (s.sigma > 0), axis=1)
    return s.subset(ok)


class PosteriorPlanner(AdaptivePlanner):
    """Plans the rounds of a sparse adaptive session under ``prior`` (module docstring); the rounds, the plan as
    data and the lab-time account are :class:`~gonio.plan.adaptive.AdaptivePlanner`'s."""

    #: what :meth:`decide`'s error is, for progress lines
    error_name = "expected error"

    def __init__(self, candidates: Plan, prior: Prior, *, motion, settings: SparseAdaptiveSettings | None = None,
                 prior_name: str = "prior"):
        super().__init__(candidates, fit=None, motion=motion, settings=settings or SparseAdaptiveSettings())
        self.prior, self.prior_name = prior, prior_name
        self._wi, self._wo = _directions(candidates.poses)
        self._posteriors: dict[int, Any] = {}

    def first_round(self) -> Round:
        """The first ``n_initial`` poses of the fixed greedy design under the prior."""
        s = self.settings
        d = select_directions(self.prior, self._wi, self._wo, s.n_initial, sigma_u=s.sigma_rel,
                              samples_per_pose=SAMPLES_PER_POSE)
        rnd = self._round(0, d.indices, None, 0.0)
        if len(rnd.candidates) == 0:
            raise ConfigError.field("adaptive", "lab_budget", s.lab_budget,
                                    f"too small for a single pose ({self.candidates.capture.pose_time():.3g} s each)")
        return rnd

    def posterior(self, samples: Sequence[SampleSet], n_rounds: int):
        """The posterior of the usable samples of the first ``n_rounds`` rounds (cached)."""
        if n_rounds not in self._posteriors:
            from gonio.prior.posterior import Posterior

            s = _usable(SampleSet.concat(samples[:n_rounds]))
            self._posteriors[n_rounds] = Posterior.start(self.prior).update_samples(s, source="session samples")
        return self._posteriors[n_rounds]

    def model(self, samples: Sequence[SampleSet], n_rounds: int) -> Reconstruction:
        return Reconstruction(self.posterior(samples, n_rounds), self.prior_name)

    def decide(self, rounds: Sequence[Round], samples: Sequence[SampleSet]) -> Decision:
        """After the last round: the posterior's expected error, and the next round or why to stop."""
        s = self.settings
        r = len(rounds) - 1
        if r < 0 or len(samples) != len(rounds):
            raise ValueError(f"decide: {len(rounds)} rounds but {len(samples)} sample sets")
        post = self.posterior(samples, r + 1)
        err = float(post.expected_error())
        rounds[r].error = err
        measured = np.concatenate([rd.candidates for rd in rounds])
        if err <= s.target_error:
            return Decision(err, "target")
        if rounds[r].cut or len(measured) >= s.max_poses:
            return Decision(err, "budget")
        left = np.setdiff1d(np.arange(len(self.candidates)), measured)
        if len(left) == 0:
            return Decision(err, "exhausted")
        n_eff = self._expected_samples(left, measured, SampleSet.concat(samples))
        if not np.any(n_eff > 0):
            return Decision(err, "exhausted")
        pick = self._select(left[n_eff > 0], post, min(s.batch, s.max_poses - len(measured)), n_eff[n_eff > 0])
        current = self.candidates.joints[rounds[r].candidates[-1]] if len(rounds[r].candidates) else None
        nxt = self._round(r + 1, pick, current, rounds[r].lab_total)
        if len(nxt.candidates) == 0:
            return Decision(err, "budget")
        return Decision(err, None, nxt)

    def _expected_samples(self, left: np.ndarray, measured: np.ndarray, samples: SampleSet) -> np.ndarray:
        """Usable samples a candidate is expected to give, from the rig's own verdict on the poses measured so far:
        those of the nearest measured pose when it lies within :data:`NEAR` in (wi, wo) (shadows, saturation, low
        signal depend on both directions), else :data:`gonio.prior.design.SAMPLES_PER_POSE`; and none when the
        nearest measured *camera direction* within :data:`NEAR` gave only samples without the board in view
        (``no_board``: a grazing view, whatever the light). A candidate expected to give nothing is not chosen."""
        from gonio.plan.adaptive import _nearest
        from gonio.samples import NO_BOARD

        n = len(self.candidates)
        usable = _usable(samples)
        counts = np.bincount(usable.pose.astype(np.int64), minlength=n) if len(usable) else np.zeros(n, np.int64)
        pose = samples.pose.astype(np.int64)
        seen = np.bincount(pose, minlength=n) > 0
        with_board = np.bincount(pose, weights=(samples.flags & NO_BOARD) == 0, minlength=n) > 0
        blind = seen & ~with_board
        dist, near = _nearest(self._x[left], self._x[measured])
        n_eff = np.where(dist <= NEAR, counts[measured[near]], SAMPLES_PER_POSE)
        dist_o, near_o = _nearest(self._x[left][:, 3:], self._x[measured][:, 3:])
        return np.where((dist_o <= NEAR) & blind[measured[near_o]], 0, n_eff)

    def _select(self, left: np.ndarray, post, k: int, n_eff: np.ndarray) -> np.ndarray:
        """``k`` candidates of ``left`` that most reduce the posterior's expected error (module docstring)."""
        s = self.settings
        wi, wo = self._wi[left], self._wo[left]
        if k > 1:
            d = select_directions(self.prior, wi, wo, k, sigma_u=s.sigma_rel, samples_per_pose=SAMPLES_PER_POSE,
                                  start=post)
            return left[d.indices]
        f, _ = post.predict(wi, wo)
        sigma_u = sigma_to_mapped(f, s.sigma_rel * f, self.prior.eps)
        gain = post.error_reduction(wi, wo, sigma_u, n_samples=np.maximum(n_eff, 1), node_weight=post.cbrt_weight())
        return left[[int(np.argmax(gain))]]


def prior_record(prior_arg) -> tuple[Prior, dict]:
    """``(prior, record)`` of a ``--prior`` value (None: the shipped prior): the manifest's record names the file
    and its SHA-256."""
    from gonio.prior.model import default_prior, default_prior_path, load_prior

    path = default_prior_path() if prior_arg is None else Path(prior_arg)
    prior = default_prior() if prior_arg is None else load_prior(path)
    return prior, {"name": "default" if prior_arg is None else str(prior_arg), "file": str(path.resolve()),
                   "sha256": _sha256(path)}


def _prior_from_record(rec, where: str) -> Prior:
    from gonio.prior.model import load_prior

    if not isinstance(rec, Mapping) or not all(isinstance(rec.get(k), str) for k in ("name", "file", "sha256")):
        raise DataError(f"{where}: adaptive.prior = {str(rec)[:60]!r}: must name the prior (name, file, sha256)")
    p = Path(rec["file"])
    if not p.is_file():
        raise DataError(f"{where}: adaptive.prior.file = {str(p)!r}: no such file (the session was planned with it)")
    if _sha256(p) != rec["sha256"]:
        raise DataError(f"{where}: adaptive.prior.file = {str(p)!r}: its content changed since the session started "
                        "(the poses so far were chosen with the old one)")
    return load_prior(p)


def new_sparse_adaptive_manifest(rig, *, prior_arg=None, settings: SparseAdaptiveSettings | None = None,
                                 capture=None) -> dict[str, Any]:
    """The ``plan`` and ``adaptive`` manifest entries of a new sparse adaptive session on ``rig``: the first round
    is planned at once (from the prior alone); :class:`gonio.session.adaptive.AdaptiveSession` plans the rest."""
    from dataclasses import replace

    from gonio.plan.adaptive import ADAPTIVE_FORMAT, round_entry
    from gonio.plan.ordering import MotionModel

    prior, rec = prior_record(prior_arg)
    cand = candidate_poses(rig)
    if capture is not None:
        cand = replace(cand, capture=capture)
    settings = settings or SparseAdaptiveSettings()
    planner = PosteriorPlanner(cand, prior, motion=MotionModel.from_rig(rig), settings=settings, prior_name=rec["name"])
    first = planner.first_round()
    return {"plan": planner.plan([first]),
            "adaptive": {"format": ADAPTIVE_FORMAT, "planner": PLANNER, "prior": rec, "candidates": cand.to_dict(),
                         "settings": settings.to_dict(), "rounds": [round_entry(first, 0)], "stop": None,
                         "model": None}}


def planner_from_manifest(ad: Mapping[str, Any], rig, where: str) -> PosteriorPlanner:
    """The planner of a recorded sparse adaptive session (the same prior file, unchanged; the same settings)."""
    from gonio.plan.ordering import MotionModel

    try:
        cand = Plan.from_dict(ad["candidates"], source=f"{where}: adaptive.candidates")
        settings = SparseAdaptiveSettings.from_dict(ad["settings"], source=f"{where}: adaptive.settings")
        prior = _prior_from_record(ad["prior"], where)
    except KeyError as exc:
        raise DataError(f"{where}: adaptive.{exc.args[0]}: missing") from None
    return PosteriorPlanner(cand, prior, motion=MotionModel.from_rig(rig), settings=settings,
                            prior_name=ad["prior"]["name"])
