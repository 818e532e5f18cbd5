"""Dark frames: captured with the light off at the same exposure and gain, cached, refreshed on schedule —
or modelled (:class:`DarkModel`) from one measured dark set, kept current by single check frames.

Why a model: on this rig the only way to a dark frame is switching the light off (there is no shutter
and no lens cap the software can close), and a light switched off must warm up again. The dark level
of a frame is a pedestal plus dark current × exposure, per pixel, and the dark current follows the
sensor's temperature (EMVA Standard 1288 R4.0, 2021, §"Dark current" and §"Temperature dependency");
so one dark set over the session's exposures, fitted per pixel, predicts the dark frame of any exposure
at any sensor temperature, and one light-off frame now and then measures how far the dark current has
moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gonio.pipeline.target import CameraCalibration
from gonio.rig.interfaces import Camera, Clock

__all__ = ["DarkFrame", "DarkCache", "DarkModel", "frame_temperature"]

#: Prior of the dark current's doubling temperature (K) before the checks have measured it: typical CMOS
#: sensors double every 6–8 K (EMVA 1288 R4.0 §"Temperature dependency"; Janesick, *Scientific
#: Charge-Coupled Devices*, 2001, §7.1: 5–7 K for silicon near room temperature).
DOUBLING_PRIOR_C = 6.5
#: Relative standard uncertainty of that prior (it stands for any sensor until checks measured it).
DOUBLING_PRIOR_REL_U = 0.25
#: Range the fitted doubling temperature is held in (K); a fit at an end is reported as on the bound.
DOUBLING_RANGE_C = (3.0, 20.0)


def frame_temperature(frame) -> float | None:
    """The sensor temperature a frame reports (``meta["sensor_temp_c"]``, °C), or None."""
    t = (getattr(frame, "meta", None) or {}).get("sensor_temp_c")
    try:
        t = float(t)
    except (TypeError, ValueError):
        return None
    return t if math.isfinite(t) and -60.0 < t < 150.0 else None


@dataclass(frozen=True)
class DarkFrame:
    """Mean raw dark frame (H, W, C) float32, the variance of that mean (DN²), frames used, capture time."""

    mean: np.ndarray
    var: np.ndarray
    n: int
    time: float
    measured: bool
    modelled: bool = False  #: predicted by a :class:`DarkModel` (from measured darks), not captured for this exposure


@dataclass
class DarkModel:
    """Per-pixel dark level ``D(t, T) = b + k(T) · r · t`` of frames of exposure ``t`` at sensor temperature
    ``T``, fitted to one measured dark set (EMVA 1288 R4.0: dark signal = offset + dark current × exposure;
    dark current ∝ 2^((T − T0)/T_d)).

    ``offset`` b (DN) and ``rate`` r (DN/s) per pixel come from a weighted least-squares line through the
    dark set's means (weights: their noise-model variances); with one exposure only, b is the pedestal
    (black level) and r the rest, divided by the exposure. The scale ``k`` of the dark current is 1 when
    the set was measured; each check (:meth:`add_check`: a light-off frame) measures it again. With the
    sensor temperature known (frames that report it) ``k = c · 2^((T − T0)/T_d)``, ``c`` and ``T_d`` fitted
    to the checks by least squares in log₂ k (``T_d`` from the prior :data:`DOUBLING_PRIOR_C` until two
    temperatures ≥ 1 K apart were measured); without it ``k`` is the latest check's (piecewise constant
    in time). The predicted frame's variance adds the fit's (b, r) covariance and k's uncertainty.
    """

    offset: np.ndarray
    rate: np.ndarray
    var_offset: np.ndarray
    var_rate: np.ndarray
    cov: np.ndarray
    gain: float
    time: float
    temperature: float | None
    doubling_c: float = DOUBLING_PRIOR_C
    doubling_fitted: bool = False
    checks: list = field(default_factory=list)  #: (time, temperature or None, k, u_k) of each check
    _memo: dict = field(default_factory=dict, repr=False)  #: (exposure, k, u_k) -> predicted DarkFrame
    _law: tuple | None = field(default=None, repr=False)  #: (c, T_d) until the next check

    @classmethod
    def fit(cls, frames, gain: float, black_level: float, time: float, temperature: float | None) -> "DarkModel":
        """Fit ``b``, ``r`` per pixel to ``frames`` = ``[(exposure, DarkFrame), ...]`` (weighted least squares,
        closed form of the straight line; e.g. Press et al., *Numerical Recipes*, 3rd ed., §15.2), one
        weight per exposure. The returned variances of b and r are per pixel (the line's covariance
        scaled by each pixel's variance at the longest exposure relative to the weight there)."""
        ts = np.asarray([t for t, _ in frames], dtype=np.float64)
        if np.unique(ts).size < 2:  # one exposure: offset = the pedestal, the rest is dark current
            t, d = frames[0]
            b = np.full(d.mean.shape, black_level, np.float32)
            r = ((d.mean.astype(np.float64) - black_level) / t).astype(np.float32)
            z = np.zeros(d.mean.shape, np.float32)
            return cls(b, r, z, (d.var / t**2).astype(np.float32), z, float(gain), float(time), temperature)
        S = St = Stt = Sy = Sty = 0.0
        for t, d in frames:
            # one weight per exposure (the frame's mean variance): per-pixel weights from the measured values
            # would correlate with their noise and bias the line low
            w = 1.0 / max(float(np.mean(d.var, dtype=np.float64)), 1e-12)
            y = d.mean.astype(np.float64)
            S, St, Stt = S + w, St + w * t, Stt + w * t * t
            Sy, Sty = Sy + w * y, Sty + w * t * y
        det = S * Stt - St * St
        b = (Stt * Sy - St * Sty) / det
        r = (S * Sty - St * Sy) / det
        t_long, d_long = max(frames, key=lambda f: f[0])
        rel = d_long.var.astype(np.float64) / max(float(np.mean(d_long.var, dtype=np.float64)), 1e-12)
        f32 = np.float32
        return cls(b.astype(f32), r.astype(f32), (rel * Stt / det).astype(f32), (rel * S / det).astype(f32),
                   (rel * -St / det).astype(f32), float(gain), float(time), temperature)

    # -- the dark current's scale -----------------------------------------------------------------
    def scale(self, temperature: float | None) -> tuple[float, float]:
        """``(k, u_k)``: the dark current relative to the fit's, and its standard uncertainty, at the
        sensor ``temperature`` (None: unknown; the latest check's k)."""
        if temperature is None or self.temperature is None:
            if not self.checks:
                return 1.0, 0.0
            return self.checks[-1][2], self.checks[-1][3]
        if self._law is None:
            self._law = self._temperature_law()
        c, td = self._law
        dT = temperature - self.temperature
        k = c * 2.0 ** (dT / td)
        u_td = 0.0 if self.doubling_fitted else DOUBLING_PRIOR_REL_U  # relative uncertainty of T_d
        u = k * math.log(2.0) * abs(dT) / td * u_td
        if self.checks:
            u = math.hypot(u, self.checks[-1][3])
        return k, u

    def _temperature_law(self) -> tuple[float, float]:
        pts = [(self.temperature, 0.0)] + [(T, math.log2(max(k, 1e-3))) for _, T, k, _ in self.checks if T is not None]
        T = np.asarray([p[0] for p in pts])
        y = np.asarray([p[1] for p in pts])
        if T.max() - T.min() >= 1.0 and len(pts) >= 2:
            A = np.stack([np.ones_like(T), T - self.temperature], axis=1)
            (a, slope), *_ = np.linalg.lstsq(A, y, rcond=None)
            lo, hi = DOUBLING_RANGE_C
            td = float(np.clip(1.0 / slope, lo, hi)) if slope > 0 else hi
            self.doubling_c, self.doubling_fitted = td, True
            return 2.0 ** float(np.mean(y - (T - self.temperature) / td)), td
        td = self.doubling_c
        return 2.0 ** float(np.mean(y - (T - self.temperature) / td)), td

    @property
    def doubling_on_bound(self) -> bool:
        """The fitted doubling temperature sits at an end of :data:`DOUBLING_RANGE_C` (not identified)."""
        return self.doubling_fitted and self.doubling_c in DOUBLING_RANGE_C

    def add_check(self, exposure: float, dark: "DarkFrame", time: float, temperature: float | None) -> float:
        """Measure k from a dark frame ``dark`` of ``exposure`` (light off): the least-squares scale of the
        pixels' dark current, ``k = Σ s (m − b) / (Σ s² − t² Σ var r)`` with ``s = r · t``, the denominator
        corrected for the noise of the fitted r (errors in variables: without it k is attenuated by
        ``Σ var(s) / Σ s²``; Fuller, *Measurement Error Models*, 1987, §1.1); returns it."""
        s = self.rate.astype(np.float64) * exposure
        y = dark.mean.astype(np.float64) - self.offset
        ss = float(np.sum(s * s))
        noise = exposure**2 * float(np.sum(self.var_rate, dtype=np.float64))
        if not ss > 0:
            return 1.0
        k = float(np.sum(s * y) / (ss - noise if ss > 2 * noise else ss))
        u = math.sqrt(float(np.sum(s * s * (dark.var.astype(np.float64) + self.var_offset))) / ss**2)
        self.checks.append((float(time), temperature, k, u))
        self._law = None
        self._memo.clear()
        return k

    def frame(self, exposure: float, temperature: float | None, time: float) -> DarkFrame:
        """The predicted dark frame of ``exposure`` at ``temperature`` (see the class docstring)."""
        k, u = self.scale(temperature)
        hit = self._memo.get((exposure, k, u))
        if hit is not None:  # the same exposure at the same sensor temperature: a pose's frames, its meter
            return hit
        if len(self._memo) > 64:
            self._memo.clear()
        kt = np.float32(k * exposure)
        mean = self.offset + kt * self.rate
        var = self.var_offset + kt * kt * self.var_rate + np.float32(2.0) * kt * self.cov
        var += (self.rate * np.float32(exposure * u)) ** 2
        mean.flags.writeable = False
        var = np.maximum(var, 0.0)
        var.flags.writeable = False
        d = DarkFrame(mean, var, 0, float(time), measured=True, modelled=True)
        self._memo[(exposure, k, u)] = d
        return d


class DarkCache:
    """Dark frames per (exposure, gain), re-captured when older than ``max_age`` (by the session's clock).

    ``light`` is anything with ``set_light(on, level)`` (a :class:`gonio.rig.interfaces.RigController`):
    the light is switched off for the dark frames and back on at ``level`` afterwards, even on error.
    Without a light, the dark frame is the frame's black level only (dark current unknown) and is
    marked ``measured=False``. Variance of the mean follows the noise model (EMVA 1288) over ``n`` frames.
    A bad frame is re-captured up to ``retries`` times; ``frame_check(frame) -> pixels`` replaces
    :func:`~gonio.pipeline.hdr.check_frame` (the pipeline passes its own, with the size check).

    Modelled darks: after :meth:`fit_model` (on a measured set, :meth:`refresh`) :meth:`get` and
    :meth:`cached` return the :class:`DarkModel`'s prediction at the sensor temperature of the latest
    frame the owner passed to :meth:`note`, and :meth:`check` re-measures the dark current's scale from a few
    light-off frames at one exposure.
    """

    def __init__(self, camera: Camera, calib: CameraCalibration, *, light=None, clock: Clock | None = None,
                 n_frames: int = 4, max_age: float = 900.0, level: float = 1.0, frame_check=None,
                 retries: int = 2):
        self.camera = camera
        self.retries = max(0, int(retries))
        self._check = frame_check  # (frame) -> pixels; default gonio.pipeline.hdr.check_frame
        self.calib = calib
        self.light = light
        self.clock = clock
        self.n_frames = max(1, int(n_frames))
        self.max_age = float(max_age)
        self.level = level
        self._cache: dict[tuple[float, float], DarkFrame] = {}
        self.captures = 0  #: dark frames captured so far (for tests and reports)
        self.model: DarkModel | None = None  #: set by fit_model: darks are predicted, not captured
        self.temperature: float | None = None  #: sensor temperature of the latest noted frame (°C)
        self._black = 0.0
        self._temps: list[float] = []

    def note(self, frame) -> None:
        """Remember the sensor temperature ``frame`` reports (if any): the modelled darks follow it."""
        t = frame_temperature(frame)
        if t is not None:
            self.temperature = t
            self._temps.append(t)

    def _now(self) -> float:
        return self.clock.now() if self.clock is not None else 0.0

    def get(self, exposure: float, gain: float = 1.0) -> DarkFrame:
        """The cached dark frame for this exposure and gain, captured first if missing or stale."""
        key = (float(exposure), float(gain))
        if self.model is not None and self.model.gain == key[1]:
            return self.model.frame(key[0], self.temperature, self._now())
        d = self._cache.get(key)
        if d is None or self._now() - d.time > self.max_age:
            d = self._capture(*key)
            self._cache[key] = d
        return d

    def cached(self, exposure: float, gain: float = 1.0) -> DarkFrame | None:
        """The cached dark frame for this exposure and gain if there is a fresh one (never captures)."""
        if self.model is not None and self.model.gain == float(gain):
            return self.model.frame(float(exposure), self.temperature, self._now())
        d = self._cache.get((float(exposure), float(gain)))
        return d if d is not None and self._now() - d.time <= self.max_age else None

    def refresh(self, exposures, gain: float = 1.0) -> None:
        """Measure the dark frames of every exposure in one light-off period (the light is switched off
        once, not per exposure, and back on at ``level`` afterwards, even on error); replaces the cache
        (and forgets a fitted model)."""
        self._cache.clear()
        self.model = None
        self._temps = []
        keys = [(float(t), float(gain)) for t in exposures]
        if self.light is None:
            for key in keys:
                self._cache[key] = self._capture(*key)
            return
        self.light.set_light(False)
        try:
            for key in keys:
                self._cache[key] = self._capture(*key, switch_light=False)
        finally:
            self.light.set_light(True, self.level)

    def invalidate(self) -> None:
        """Forget every cached dark frame and the model (e.g. after the camera's settings changed)."""
        self._cache.clear()
        self.model = None

    def fit_model(self, gain: float = 1.0) -> DarkModel:
        """Fit a :class:`DarkModel` to the measured dark frames of ``gain`` (a set measured by :meth:`refresh`);
        from now on darks of that gain are predicted. Raises ValueError without measured frames."""
        frames = sorted((k[0], d) for k, d in self._cache.items() if k[1] == float(gain) and d.measured and d.n > 0)
        if not frames:
            raise ValueError("dark model: no measured dark frames to fit (refresh first)")
        temp = float(np.mean(self._temps)) if self._temps else None
        self.model = DarkModel.fit(frames, float(gain), self._black, self._now(), temp)
        return self.model

    def check(self, exposure: float, gain: float = 1.0, n_frames: int = 1) -> float:
        """Measure the modelled dark current's scale from ``n_frames`` light-off frames at ``exposure`` (the
        light switched off once and back on at ``level``, even on error); returns the new scale k."""
        if self.model is None:
            raise ValueError("dark model: check before fit_model")
        n, self.n_frames = self.n_frames, max(1, int(n_frames))
        self._temps = []
        try:
            d = self._capture(float(exposure), float(gain))
        finally:
            self.n_frames = n
        temp = float(np.mean(self._temps)) if self._temps else None
        if temp is not None:
            self.temperature = temp
        return self.model.add_check(float(exposure), d, self._now(), temp)

    def _checked(self, frame) -> np.ndarray:
        """The owner's frame check if given (the pipeline's: size at session start), else check_frame."""
        if self._check is not None:
            return self._check(frame)
        from gonio.pipeline.hdr import check_frame

        return check_frame(frame, self.calib)

    def _grab(self, exposure: float, gain: float):
        """One checked frame; a bad frame (:class:`~gonio.pipeline.hdr.BadFrame`) is re-captured up to
        ``retries`` times."""
        from gonio.pipeline.hdr import BadFrame

        for attempt in range(self.retries + 1):
            frame = self.camera.capture(exposure, gain)
            try:
                px = self._checked(frame)
                self.note(frame)
                return frame, px
            except BadFrame:
                if attempt == self.retries:
                    raise
        raise AssertionError("unreachable")  # pragma: no cover

    def _capture(self, exposure: float, gain: float, switch_light: bool = True) -> DarkFrame:
        noise = self.calib.noise
        if self.light is None:
            frame, px = self._grab(exposure, gain)
            mean = np.full(px.shape, frame.black_level, dtype=np.float32)
            return DarkFrame(mean, np.zeros(px.shape, np.float32), 0, self._now(), measured=False)
        if switch_light:
            self.light.set_light(False)
        try:
            acc, black = None, 0.0
            for _ in range(self.n_frames):
                frame, px = self._grab(exposure, gain)
                if acc is None:
                    acc = px.astype(np.float32)
                else:  # in place: each value cast to float32 and added, as acc + px.astype(float32) does
                    np.add(acc, px, out=acc, dtype=np.float32)
                black = frame.black_level
                self.captures += 1
            self._black = float(black)
        finally:
            if switch_light:
                self.light.set_light(True, self.level)
        mean = acc / np.float32(self.n_frames)
        var = (noise.variance(mean - black, gain) / self.n_frames).astype(np.float32)
        return DarkFrame(mean, var, self.n_frames, self._now(), measured=True)
