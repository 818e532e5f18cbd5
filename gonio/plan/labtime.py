"""The lab-time cost model of a session: ONE account of what the session runner spends, used by the
estimator (:func:`gonio.plan.estimate_plan`, ``gonio plan --estimate``, ``gonio measure``'s announcement)
and by the runner itself (its ETA and the estimate it records next to the lab time it measured).

Costs (seconds of lab time), in the order the runner spends them (:mod:`gonio.session.runner`):

* **start-up**: dark frames with the light off, ``dark_frames`` frames at every exposure the session may
  use (the fixed bracket, or the whole exposure ladder of automatic exposure), then the light's warm-up;
* **per pose**: the move (concurrent joints, trapezoidal profiles, :mod:`gonio.plan.ordering`), the
  settle time, one metering frame (it also locates the board) and the bracket: ``Σ_k n_k (t_k + r)``
  with ``r`` the per-frame readout/transfer time;
* **dark re-measurement**: before a pose that starts more than ``dark_max_age`` after the last dark
  measurement started: with ``darks="measured"`` the whole dark set again, with ``darks="model"`` (the
  default) ``dark_check_frames`` light-off frames at the set's longest exposure that re-measure the
  modelled dark current (:class:`gonio.pipeline.dark.DarkModel`); then the warm-up again (switching the
  light off restarts it).

Warm-up (``warmup``): ``"corrected"`` (the default) switches the light on, checks the photodiode sees
it, waits ``warmup_min`` (0 by default) and measures: every frame is normalized by the photodiode
reading taken with it (and, in relative mode, by the white reference in the same frame), which removes
the warm-up drift (benchmarks/bench_labtime.py measures the accuracy). ``"stable"`` (``gonio measure
--accurate``, the conservative choice) waits until two photodiode readings one ``warmup_step`` apart
agree: at least one step (its lower bound), ``warmup_expected`` on average (the estimate; the simulated
lamp, depth 5 %, τ = 120 s, needs 210 s to reach 1e-3 between readings 15 s apart).

A frame costs its exposure plus the readout/transfer time (the camera integrates, then reads out and
transfers the frame; the EMVA 1288 timing model, EMVA Standard 1288 R4.0, 2021, §"Camera model").

With automatic exposure the bracket of a pose is chosen while measuring: the estimate uses the plan's
*expected* bracket (``CaptureSettings.exposures × frames``, by default 4/16/64 ms × 1: what
:func:`gonio.pipeline.exposure.plan_bracket` chooses where a sample tile has tens of pixels or more, 37 of
the default plan's 38 poses in the simulated sessions of benchmarks/bench_labtime.py) and says so. The
lower bound is what every pose costs at least: the metering frame at the exposure the runner meters at
(the expected bracket's shortest) and one frame at the ladder's shortest exposure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.errors import ConfigError

__all__ = ["SessionTiming", "LabAccount", "dark_exposures", "pose_capture_time", "session_lab_time"]


#: Longest wait or age a session's timing may name (a day): a larger one is a damaged or hostile value.
MAX_SECONDS = 86400.0


@dataclass(frozen=True)
class SessionTiming:
    """Session-level lab-time knobs shared by the runner (which spends them) and the estimator.

    Attributes
    ----------
    warmup : str
        ``"corrected"``: measure after ``warmup_min``, the photodiode corrects the drift; ``"stable"``:
        wait until the photodiode is stable (see the module docstring).
    warmup_min : float
        ``"corrected"``: lab seconds to wait after switching the light on (a short stabilisation).
    warmup_step : float
        Lab seconds between photodiode readings while the light warms up (``"stable"``).
    warmup_expected : float
        ``"stable"``: expected warm-up of the light to a stable reading (the estimate; the bound uses one step).
    darks : str
        ``"model"``: the start-up dark set is fitted per pixel (:class:`gonio.pipeline.dark.DarkModel`) and
        re-checked with ``dark_check_frames`` frames; ``"measured"``: the whole set is re-measured.
    dark_frames : int
        Frames averaged per dark exposure.
    dark_check_frames : int
        ``darks="model"``: light-off frames of a check.
    dark_max_age : float
        Dark frames are re-measured (or the model checked) and the light warmed up again when older than this.
    ladder_extra : int
        Automatic exposure: rungs of the exposure ladder beyond the expected bracket, each side.
    """

    warmup: str = "corrected"
    warmup_min: float = 0.0
    warmup_step: float = 15.0
    warmup_expected: float = 225.0
    darks: str = "model"
    dark_frames: int = 4
    dark_check_frames: int = 1
    dark_max_age: float = 900.0
    ladder_extra: int = 2

    def __post_init__(self):
        if self.warmup not in ("corrected", "stable"):
            raise ConfigError.field(None, "timing.warmup", self.warmup, "must be 'corrected' or 'stable'")
        if self.darks not in ("model", "measured"):
            raise ConfigError.field(None, "timing.darks", self.darks, "must be 'model' or 'measured'")
        for name in ("warmup_min", "warmup_step", "warmup_expected", "dark_max_age"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0 <= v <= MAX_SECONDS):
                raise ConfigError.field(None, f"timing.{name}", v, f"must be seconds in [0, {MAX_SECONDS:g}]")
        for name in ("dark_frames", "dark_check_frames"):
            if int(getattr(self, name)) < 1:
                raise ConfigError.field(None, f"timing.{name}", getattr(self, name), "must be >= 1")

    @classmethod
    def accurate(cls, **kw) -> "SessionTiming":
        """The conservative strategy: wait for a stable light, re-measure the whole dark set on schedule."""
        return cls(**{"warmup": "stable", "darks": "measured", **kw})

    def warm_time(self, bound: bool = False) -> float:
        """Lab seconds of one warm-up (``bound``: its minimum)."""
        if self.warmup == "corrected":
            return self.warmup_min
        return self.warmup_step if bound else self.warmup_expected

    def describe(self) -> str:
        """One line for messages: the strategy and its knobs."""
        warm = (f"drift-corrected from the photodiode (wait {self.warmup_min:g} s)" if self.warmup == "corrected"
                else "wait until the light is stable")
        dark = (f"modelled dark frames (checked every {self.dark_max_age:g} s)" if self.darks == "model"
                else f"dark frames re-measured every {self.dark_max_age:g} s")
        return f"light: {warm}; {dark}"


def dark_exposures(capture, timing: SessionTiming | None = None) -> tuple[float, ...]:
    """Exposures whose dark frames the session measures: the bracket, or with automatic exposure the
    ladder :func:`gonio.pipeline.exposure.exposure_ladder` builds around the expected bracket."""
    if not getattr(capture, "auto_exposure", False):
        return tuple(capture.exposures)
    from gonio.pipeline.exposure import ExposureSettings, exposure_ladder

    timing = timing or SessionTiming()
    es = ExposureSettings()
    return exposure_ladder(capture.exposures, es.step, extra=timing.ladder_extra, lo=es.min_exposure,
                           hi=es.max_exposure)


def pose_capture_time(capture, *, bound: bool = False, timing: SessionTiming | None = None) -> float:
    """Lab seconds of one pose's capture: a metering frame plus ``Σ_k n_k (t_k + readout)``.

    The runner meters every pose at ``capture.exposures[0]`` (:mod:`gonio.session.runner`), so the metering
    frame costs that exposure plus the readout in the estimate and in the bound. ``bound``: a true lower
    bound (automatic exposure: a bracket of one frame at the ladder's shortest exposure; a fixed bracket is
    captured as given). The estimate with automatic exposure: the expected bracket and frames."""
    r = capture.readout
    meter = capture.exposures[0] + r
    if bound and getattr(capture, "auto_exposure", False):
        return meter + (min(dark_exposures(capture, timing)) + r)
    return meter + capture.frames * sum(e + r for e in capture.exposures)


@dataclass(frozen=True)
class LabAccount:
    """Where the lab time of a session goes (seconds)."""

    total: float
    startup: float  #: first darks + warm-up
    moves: float
    settle: float
    capture: float
    refreshes: int  #: dark re-measurements or model checks (each with a warm-up)
    refresh_time: float
    ends: np.ndarray  #: lab time at the end of each pose, from the session's start

    def to_dict(self) -> dict:
        return {"total": self.total, "startup": self.startup, "moves": self.moves, "settle": self.settle,
                "capture": self.capture, "refreshes": self.refreshes, "refresh_time": self.refresh_time}


def session_lab_time(move_times, capture, timing: SessionTiming | None = None, *, bound: bool = False,
                     startup: bool = True) -> LabAccount:
    """Lab time of a session measuring poses whose moves take ``move_times`` (seconds, one per pose, in
    order), under the costs of the module docstring.

    ``bound``: every cost at its minimum (one warm-up step, the bound capture time): with the moves of
    a lower bound (MST) this is a true lower bound of the session. ``startup=False``: the session's
    darks and warm-up were already done (a resumed or adaptive round) at time 0.
    """
    timing = timing or SessionTiming()
    m = np.asarray(move_times, dtype=np.float64).reshape(-1)
    n = m.size
    exps = dark_exposures(capture, timing)
    darks = timing.dark_frames * sum(t + capture.readout for t in exps)
    warm = timing.warm_time(bound)
    recheck = darks if timing.darks == "measured" else timing.dark_check_frames * (max(exps) + capture.readout)
    cap = pose_capture_time(capture, bound=bound, timing=timing)
    cost = m + capture.settle + cap
    t0 = darks + warm if startup else 0.0
    t, t_dark, i, refreshes = t0, 0.0, 0, 0
    ends = np.empty(n, np.float64)
    window = 256
    for _ in range(n + 1):  # each round measures at least one pose (bounded)
        if i >= n:
            break
        # the poses up to the next refresh, in a window of the rest that doubles until it holds the
        # refresh (O(N) in all, where the whole rest each round was O(N · refreshes)); a prefix of
        # the cumulative sum is the same numbers as the whole one
        w = min(n - i, window)
        while True:
            c = cost[i:i + w]
            cum = np.cumsum(c)
            starts = t + cum - c
            due = np.flatnonzero(starts - t_dark > timing.dark_max_age)
            if due.size or i + w >= n:
                break
            w = min(n - i, 2 * w)
        j = int(due[0]) if due.size else c.size
        window = max(256, 2 * (j + 1))  # the next round is about as long
        ends[i:i + j] = t + cum[:j]
        if j == c.size:
            t = float(ends[-1]) if n else t
            break
        t_start = float(starts[j])
        t_dark = t_start
        t = t_start + recheck + warm
        refreshes += 1
        ends[i + j] = t + c[j]
        t = float(ends[i + j])
        i += j + 1
    total = float(ends[-1]) if n else t0
    return LabAccount(total=total, startup=t0, moves=float(m.sum()), settle=n * capture.settle, capture=n * cap,
                      refreshes=refreshes, refresh_time=refreshes * (recheck + warm), ends=ends)
