"""Adaptive measurement sessions: a loop *around* the session runner (docs/architecture.md §1: plans are data, the
runner never decides what to measure).

Round *k*'s poses are a :class:`~gonio.plan.Plan` computed by :class:`gonio.plan.adaptive.AdaptivePlanner`
from the samples stored so far; the :class:`~gonio.session.runner.SessionRunner` measures that round on
the devices and appends to the one session store; then the next round is planned from the store's
samples, until the prediction error reaches the target, the lab-time budget is used up, the candidates
are exhausted or the round limit is reached.

The manifest is the record of the adaptation (rewritten atomically after every decision):

* ``plan`` — every round's poses so far, concatenated in measurement order (pose *k* of the store is
  row *k*, as for any plan, so ``gonio status``/``export``/``fit`` read an adaptive session unchanged);
* ``adaptive`` — ``planner`` (absent: the model-fitting planner; ``"prior"``: the sparse adaptive planner of
  :mod:`gonio.prior.adaptive`, which records its ``prior`` instead of ``fit``), ``candidates`` (the candidate plan), ``settings``
  (:class:`~gonio.plan.adaptive.AdaptiveSettings`), ``fit`` (:class:`FitSpec`), ``rounds`` (per round:
  first pose, candidate indices in order, the planner's lab-time estimate, whether it was cut to the
  budget, ``status`` planned/measured, the prediction ``error`` of the round, the model fitted after it,
  the runner's lab time), ``stop`` (why it stopped, None while running) and the final ``model``.

A round is written to the manifest *before* it is measured, so :meth:`AdaptiveSession.run` on a resumed
store (``gonio resume DIR``) finishes the round in flight and then continues adapting from the stored
samples. Rounds planned before an interruption are kept as planned. The decisions after it depend on
the re-measured samples' values (the lab-time account does not: it is the ordering model's, not the
clock's), so a resumed session chooses exactly the uninterrupted run's poses only when nothing after
the interruption depends on them (e.g. killed in the last round) or the re-measured samples are
identical. The simulator does not make them identical: the camera noise is seeded per pose, but the
photodiode noise stream, the servo encoder noise and the backlash after a restart are not, which moves
samples by 0.05-1 % — the level at which the residual and committee terms rank candidates when the
model fits well — so later rounds may pick other poses (tests/session/test_adaptive_session.py).

The runner is reused across rounds (``runner.plan`` and ``runner.store`` are set per round): dark
frames and the warm light carry over, so a round costs its poses plus the runner's start-of-run checks
(device status, a photodiode stability check).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence, TextIO

import numpy as np

from gonio.errors import ConfigError, DataError, GonioError
from gonio.plan.adaptive import ADAPTIVE_FORMAT, AdaptivePlanner, AdaptiveSettings, Round, fit_model, select_model
from gonio.plan.adaptive import round_entry as _round_entry
from gonio.plan.ordering import MotionModel
from gonio.plan.plan import Plan
from gonio.samples import SampleSet

__all__ = ["FitSpec", "AdaptiveSession", "AdaptiveSessionResult", "new_adaptive_manifest", "ADAPTIVE_FORMAT",
           "rounds_table", "model_table"]



@dataclass(frozen=True)
class FitSpec:
    """How each round's model is fitted: one ``model`` (a :mod:`gonio.brdf` name) or, with ``select``, the
    model chosen each round among those names by :func:`gonio.fit.select.select`."""

    model: str = "microfacet"
    select: tuple[str, ...] | None = None
    n_starts: int = 3

    def __post_init__(self):
        from gonio.brdf import MODELS

        names = list(self.select) if self.select is not None else [self.model]
        if self.select is not None and not names:
            raise ConfigError.field("--select", "models", [], "name at least one model")
        for n in names:
            if n not in MODELS:
                raise ConfigError.field("--select" if self.select is not None else "--model", "model", n,
                                        f"unknown model; known: {', '.join(sorted(MODELS))}")
        if self.select is not None:
            object.__setattr__(self, "select", tuple(names))
        if int(self.n_starts) != self.n_starts or self.n_starts < 1:
            raise ConfigError.field("adaptive", "fit.n_starts", self.n_starts, "must be an integer >= 1")

    def callable(self) -> Callable[[SampleSet], Any]:
        """The planner's ``fit`` callable (samples -> fitted BRDF)."""
        if self.select is not None:
            return select_model(self.select, n_starts=self.n_starts)
        return fit_model(self.model, n_starts=self.n_starts)

    def describe(self) -> str:
        return f"select among {', '.join(self.select)}" if self.select is not None else self.model

    def to_dict(self) -> dict[str, Any]:
        return {"model": self.model, "select": None if self.select is None else list(self.select),
                "n_starts": self.n_starts}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "FitSpec":
        sel = d.get("select")
        return cls(model=str(d.get("model", "microfacet")), select=None if sel is None else tuple(sel),
                   n_starts=int(d.get("n_starts", 3)))


def new_adaptive_manifest(candidates: Plan, settings: AdaptiveSettings, fit: FitSpec, rig) -> dict[str, Any]:
    """The ``plan`` and ``adaptive`` manifest entries of a new adaptive session on ``rig``: the coarse
    first round is planned (no measurement needed), later rounds are planned by :class:`AdaptiveSession`."""
    planner = AdaptivePlanner(candidates, fit.callable(), motion=MotionModel.from_rig(rig), settings=settings)
    first = planner.first_round()
    return {"plan": planner.plan([first]),
            "adaptive": {"format": ADAPTIVE_FORMAT, "candidates": candidates.to_dict(), "settings": settings.to_dict(),
                         "fit": fit.to_dict(), "rounds": [_round_entry(first, 0)], "stop": None, "model": None}}


def _model_dict(model) -> dict[str, Any] | None:
    if model is None:
        return None
    return {"model": getattr(model, "name", type(model).__name__), "params": dict(getattr(model, "params", {}))}


@dataclass
class AdaptiveSessionResult:
    """How an adaptive session (or this process's part of it) ended; the fields the CLI prints mirror
    :class:`gonio.session.runner.RunResult` (summed over the rounds run here)."""

    status: str = "completed"
    stop: str | None = None  #: why the adaptation stopped (None if it did not, e.g. interrupted)
    rounds: list[dict] = field(default_factory=list)  #: the manifest's round entries at the end
    model: Any = None  #: the model fitted on every sample (None if not reached)
    runs: list = field(default_factory=list)  #: the runner's RunResult of each round run here
    wall_time: float = 0.0
    error: GonioError | None = None

    @property
    def measured(self) -> int:
        return sum(r.measured for r in self.runs)

    @property
    def samples(self) -> int:
        return sum(r.samples for r in self.runs)

    @property
    def lab_time(self) -> float:
        return sum(r.lab_time for r in self.runs)

    @property
    def retries(self) -> int:
        return sum(r.retries for r in self.runs)

    @property
    def skipped(self) -> list:
        return [s for r in self.runs for s in r.skipped]

    @property
    def timings(self) -> list:
        return [t for r in self.runs for t in r.timings]

    @property
    def ok(self) -> bool:
        return self.status == "completed"

    def summary(self) -> dict:
        return {"status": self.status, "stop": self.stop, "rounds_run": len(self.runs), "poses": self.measured,
                "samples": self.samples, "retries": self.retries, "lab_time_s": self.lab_time,
                "wall_time_s": self.wall_time, "skipped": [{"pose": k, "reason": r} for k, r in self.skipped]}


class _RoundStore:
    """The session store as the runner sees it during one round: ``remaining`` lists only the round's
    unmeasured poses (poses of earlier rounds the runner skipped are not retried), and ``finish`` records
    the run's summary without closing the store — the adaptive session finishes it once, at the end."""

    def __init__(self, store, first: int, n: int):
        self._store, self.first, self.n = store, int(first), int(n)
        self.status: str | None = None

    def remaining(self, plan=None) -> np.ndarray:
        done = self._store.done_poses()
        return np.array([k for k in range(self.first, self.first + self.n) if k not in done], dtype=np.int64)

    def done_poses(self) -> set[int]:
        return self._store.done_poses()

    def append(self, pose_index, samples, meta=None) -> None:
        self._store.append(pose_index, samples, meta)

    def finish(self, exit_status: str, **fields: Any) -> None:
        self.status = str(exit_status)
        if fields:
            self._store.update_manifest(**fields)

    def __getattr__(self, name):  # anything else (directory, sample_count, ...) is the store's
        return getattr(self._store, name)


class AdaptiveSession:
    """Run (or resume) the adaptive session of ``store`` on ``devices``; see the module docstring.

    Parameters are those of :class:`~gonio.session.runner.SessionRunner`; ``store`` is an open
    :class:`~gonio.store.directory.SessionStore` whose manifest has an ``adaptive`` section
    (:func:`new_adaptive_manifest`).
    """

    def __init__(self, store, devices, calibration, layout, *, before_pose: Callable[[int], None] | None = None,
                 resume_command: str = "", stream: TextIO | None = sys.stderr, settings=None, pipeline_settings=None):
        from gonio.session.runner import SessionRunner

        self.store, self.devices, self.stream = store, devices, stream
        where = f"{store.directory}/manifest.json"
        ad = store.manifest_entry("adaptive")  # read only (the rounds are copied): not a copy of ~1 MB
        if not isinstance(ad, Mapping) or ad.get("format") != ADAPTIVE_FORMAT:
            raise DataError(f"{where}: adaptive.format = {ad.get('format') if isinstance(ad, Mapping) else ad!r}: "
                            f"expected an adaptive session, format {ADAPTIVE_FORMAT}")
        try:
            if ad.get("planner") == "prior":  # sparse adaptive: rounds chosen under a BRDF prior's posterior
                from gonio.prior.adaptive import planner_from_manifest

                self.planner = planner_from_manifest(ad, devices.rig, where)
                self.candidates, self.settings, self.fit = self.planner.candidates, self.planner.settings, None
            else:
                self.candidates = Plan.from_dict(ad["candidates"], source=f"{where}: adaptive.candidates")
                self.settings = AdaptiveSettings.from_dict(ad["settings"], source=f"{where}: adaptive.settings")
                self.fit = FitSpec.from_dict(ad["fit"])
                self.planner = AdaptivePlanner(self.candidates, self.fit.callable(),
                                               motion=MotionModel.from_rig(devices.rig), settings=self.settings)
            self.rounds = [dict(r) for r in ad["rounds"]]
        except KeyError as exc:
            raise DataError(f"{where}: adaptive.{exc.args[0]}: missing") from None
        self.stop: str | None = ad.get("stop")
        self.runner = SessionRunner(self._plan(), store, devices, calibration, layout, settings=settings,
                                    before_pose=before_pose, resume_command=resume_command, stream=stream,
                                    pipeline_settings=pipeline_settings)

    # -- manifest -------------------------------------------------------------------------------
    def _plan(self) -> Plan:
        return self.planner.plan([Round.from_dict(r) for r in self.rounds], self.stop)

    def _record(self, model=None, **fields) -> None:
        # the stored entries themselves (not a copy): the candidates, unchanged, are not encoded again
        ad = {**self.store.manifest_entry("adaptive"), "rounds": self.rounds, "stop": self.stop}
        if model is not None:
            ad["model"] = _model_dict(model)
        self.store.update_manifest(plan=self._plan(), adaptive=ad, **fields)

    def _say(self, msg: str) -> None:
        if self.stream is not None:
            self.stream.write(msg + "\n")
            self.stream.flush()

    # -- samples --------------------------------------------------------------------------------
    def _round_samples(self) -> list[SampleSet]:
        """The stored samples of each round, ``pose`` = candidate index."""
        samples = self.store.samples()
        out = []
        for r in self.rounds:
            first, cand = r["first_pose"], np.asarray(r["candidate_index"], dtype=np.int64)
            sel = (samples.pose >= first) & (samples.pose < first + len(cand))
            s = samples.subset(sel)
            out.append(SampleSet(**{**s.to_dict(), "pose": cand[s.pose - first]}))
        return out

    # -- the loop -------------------------------------------------------------------------------
    def run(self) -> AdaptiveSessionResult:
        """Measure the round in flight, then plan and measure rounds until the planner stops; always ends
        with ``store.finish(status)`` (``completed`` once the adaptation stopped)."""
        wall0 = time.perf_counter()
        res = AdaptiveSessionResult()
        try:
            for _ in range(self.settings.max_rounds + 1):  # one round per pass; the planner stops at max_rounds
                if self.rounds[-1]["status"] == "planned":
                    status = self._run_round(res)
                    if status != "completed":
                        res.status = status
                        break
                if self.stop is not None:
                    break
                self._decide(res)
                if self.stop is not None:
                    break
            else:  # pragma: no cover - the planner stops within max_rounds
                raise DataError(f"{self.store.directory}: adaptive session did not stop after "
                                f"{self.settings.max_rounds} rounds")
            if res.status == "completed" and self.stop is not None:
                res.model = self._final_model()
        except KeyboardInterrupt:  # Ctrl-C while planning (the runner handles it while measuring)
            res.status = "interrupted"
            self._say(f"interrupt: adaptive session stopped between rounds; resume with:\n  "
                      f"{self.runner.resume_command or 'gonio resume ' + str(self.store.directory)}")
        except GonioError as exc:
            res.status, res.error = f"error: {exc}", exc
            raise
        except BaseException as exc:
            res.status = f"error: {type(exc).__name__}: {exc}"
            raise
        finally:
            res.stop, res.rounds = self.stop, self.rounds
            res.wall_time = time.perf_counter() - wall0
            self.store.finish(res.status, last_run=res.summary())
        return res

    def _run_round(self, res: AdaptiveSessionResult) -> str:
        """Measure the last round's remaining poses; the round is ``measured`` once a run of it completed
        (poses the runner skipped as unmeasurable are not retried by later rounds)."""
        rnd = self.rounds[-1]
        view = _RoundStore(self.store, rnd["first_pose"], rnd["n_poses"])
        if not len(view.remaining()):  # every pose was stored before an interruption
            rnd["status"] = "measured"
            self._record()
            return "completed"
        self._say(f"adaptive round {rnd['round']}: {len(view.remaining())} of {rnd['n_poses']} poses to measure")
        self.runner.plan, self.runner.store = self._plan(), view
        self.runner.lab_offset = sum(float(r.get("lab_time_s") or 0.0) for r in self.rounds)  # the session's so far
        try:
            result = self.runner.run()
        except BaseException:
            if view.status is not None:
                res.status = view.status
            raise
        res.runs.append(result)
        rnd["lab_time_s"] = float(rnd.get("lab_time_s") or 0.0) + result.lab_time
        if result.status == "completed":
            rnd["status"] = "measured"
        self._record()
        if result.error is not None:
            res.error = result.error
        return result.status

    def _decide(self, res: AdaptiveSessionResult) -> None:
        """Assess the last round and plan the next one (or stop); recorded in the manifest at once."""
        rounds = [Round.from_dict(r) for r in self.rounds]
        w0 = time.perf_counter()
        d = self.planner.decide(rounds, self._round_samples())
        last = self.rounds[-1]
        last["status"], last["error"], last["model_after"] = "measured", d.error, _model_dict(d.model)
        last["plan_wall_s"] = time.perf_counter() - w0  # fitting + selection (real time, the rig idles)
        what = getattr(self.planner, "error_name", "prediction error")
        err = "" if d.error is None else f", {what} {d.error:.3g} (target {self.settings.target_error:g})"
        if d.stop is not None:
            self.stop = d.stop
            self._say(f"adaptive round {last['round']} assessed{err}: stop ({d.stop})")
        else:
            first = last["first_pose"] + last["n_poses"]
            self.rounds.append(_round_entry(d.next, first))
            self._say(f"adaptive round {last['round']} assessed{err}: next round {d.next.index}, "
                      f"{len(d.next.candidates)} poses{' (cut to the lab budget)' if d.next.cut else ''}")
        self._record()

    def _final_model(self):
        """The model fitted on every sample, recorded in the manifest (a failed fit is recorded too)."""
        try:
            model = self.planner.model(self._round_samples(), len(self.rounds))
        except GonioError as exc:
            self._record(adaptive_fit_error=str(exc))
            return None
        self._record(model=model)
        return model


def _fmt_value(v) -> str:
    """A parameter value as ``gonio fit``'s table shows it: floats at 5 significant digits, an RGB triple as
    ``r, g, b`` (one value when the three are equal, e.g. a tied f0)."""
    if isinstance(v, (list, tuple, np.ndarray)):
        vals = [_fmt_value(x) for x in np.asarray(v).ravel().tolist()]
        return vals[0] if vals and all(x == vals[0] for x in vals) else ", ".join(vals)
    if isinstance(v, (float, np.floating)):
        return "inf" if math.isinf(v) else ("-" if math.isnan(v) else f"{float(v):.5g}")
    return str(v)


def model_table(model) -> list[str]:
    """The fitted model for the CLI: its name, then one ``parameter  value`` line per parameter."""
    name = getattr(model, "name", type(model).__name__)
    params = dict(getattr(model, "params", {}) or {})
    return [f"fitted on every sample: model {name}"] + [f"  {k:<18} {_fmt_value(v)}" for k, v in params.items()]


def rounds_table(rounds: Sequence[Mapping[str, Any]]) -> list[str]:
    """One line per round for the CLI: poses, estimated lab time, prediction error, model."""
    out = []
    for r in rounds:
        err = "-" if r.get("error") is None else f"{r['error']:.4f}"
        m = (r.get("model_after") or {}).get("model", "-")
        out.append(f"  round {r['round']}: {r['n_poses']:3d} poses, est. lab {r['lab_time_estimate_s']:8.1f} s "
                   f"(total {r['lab_total_estimate_s']:8.1f} s){' cut' if r.get('cut') else ''}, "
                   f"prediction error {err}, model after it: {m}")
    return out
