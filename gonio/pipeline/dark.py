"""Dark frames: captured with the light off at the same exposure and gain, cached, refreshed on schedule."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gonio.pipeline.target import CameraCalibration
from gonio.rig.interfaces import Camera, Clock

__all__ = ["DarkFrame", "DarkCache"]


@dataclass(frozen=True)
class DarkFrame:
    """Mean raw dark frame (H, W, C) float32, the variance of that mean (DN²), frames used, capture time."""

    mean: np.ndarray
    var: np.ndarray
    n: int
    time: float
    measured: bool


class DarkCache:
    """Dark frames per (exposure, gain), re-captured when older than ``max_age`` (by the session's clock).

    ``light`` is anything with ``set_light(on, level)`` (a :class:`gonio.rig.interfaces.RigController`):
    the light is switched off for the dark frames and back on at ``level`` afterwards, even on error.
    Without a light, the dark frame is the frame's black level only (dark current unknown) and is
    marked ``measured=False``. Variance of the mean follows the noise model (EMVA 1288) over ``n`` frames.
    A bad frame is re-captured up to ``retries`` times; ``frame_check(frame) -> pixels`` replaces
    :func:`~gonio.pipeline.hdr.check_frame` (the pipeline passes its own, with the size check).
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

    def _now(self) -> float:
        return self.clock.now() if self.clock is not None else 0.0

    def get(self, exposure: float, gain: float = 1.0) -> DarkFrame:
        """The cached dark frame for this exposure and gain, captured first if missing or stale."""
        key = (float(exposure), float(gain))
        d = self._cache.get(key)
        if d is None or self._now() - d.time > self.max_age:
            d = self._capture(*key)
            self._cache[key] = d
        return d

    def cached(self, exposure: float, gain: float = 1.0) -> DarkFrame | None:
        """The cached dark frame for this exposure and gain if there is a fresh one (never captures)."""
        d = self._cache.get((float(exposure), float(gain)))
        return d if d is not None and self._now() - d.time <= self.max_age else None

    def refresh(self, exposures, gain: float = 1.0) -> None:
        """Measure the dark frames of every exposure in one light-off period (the light is switched off
        once, not per exposure, and back on at ``level`` afterwards, even on error); replaces the cache."""
        self._cache.clear()
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
        """Forget every cached dark frame (e.g. after the camera's temperature changed)."""
        self._cache.clear()

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
                return frame, self._checked(frame)
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
                px = px.astype(np.float32)
                acc = px if acc is None else acc + px
                black = frame.black_level
                self.captures += 1
        finally:
            if switch_light:
                self.light.set_light(True, self.level)
        mean = acc / np.float32(self.n_frames)
        var = (noise.variance(mean - black, gain) / self.n_frames).astype(np.float32)
        return DarkFrame(mean, var, self.n_frames, self._now(), measured=True)
