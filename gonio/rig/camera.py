"""A real camera through OpenCV ``VideoCapture`` (V4L2 / UVC webcams and machine-vision cameras with a
V4L2 driver), implementing :class:`gonio.rig.interfaces.Camera`.

Manual exposure: ``CAP_PROP_AUTO_EXPOSURE`` is switched to manual (V4L2 convention: 1 = manual,
3 = aperture priority; some backends use 0.25/0.75) and ``CAP_PROP_EXPOSURE`` set; the value read
back must match, otherwise :class:`~gonio.errors.HardwareError` says the driver does not allow
manual exposure. V4L2 expresses exposure in units of 100 µs (``exposure_unit``). Frames are
converted BGR -> RGB; 8-bit frames from such drivers are usually gamma-encoded (``linear=False``),
so the pipeline needs a response calibration for them.
"""

from __future__ import annotations

import math

import numpy as np

from gonio.errors import ConfigError, HardwareError
from gonio.rig.interfaces import Clock, Frame

__all__ = ["OpenCVCamera"]


class OpenCVCamera:
    """Camera over ``cv2.VideoCapture``.

    Parameters
    ----------
    device : int or str
        Device index (``0``) or path (``/dev/video0``).
    clock : Clock
        Timestamps the frames.
    backend : int
        ``cv2.CAP_*`` API preference (default ``CAP_V4L2`` = 200; ``0`` = any).
    exposure_unit : float
        Seconds per unit of ``CAP_PROP_EXPOSURE`` (V4L2: 100 µs).
    linear, bit_depth, black_level : as in :class:`~gonio.rig.interfaces.Frame`.
    """

    def __init__(self, device: int | str, clock: Clock, *, backend: int = 200, exposure_unit: float = 1e-4,
                 linear: bool = False, bit_depth: int = 8, black_level: float = 0.0, flush: int = 2):
        import cv2

        self._cv2 = cv2
        self.device = device
        self.clock = clock
        self.exposure_unit = exposure_unit
        self.linear = linear
        self.bit_depth = bit_depth
        self.black_level = black_level
        self.flush = flush
        if isinstance(device, str) and device.isdigit():
            device = int(device)
        if not isinstance(device, (int, str)) or isinstance(device, bool):
            raise ConfigError.field(None, "camera.device", device, "must be an index or a device path")
        self._cap = cv2.VideoCapture(device, backend)
        if not self._cap.isOpened():
            self._cap.release()
            raise HardwareError(f"camera {device!r}: cannot open (no such device, or busy)", device=str(device))
        self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        self._exposure: float | None = None
        self._gain: float | None = None

    def _set_exposure(self, exposure: float) -> None:
        cv2 = self._cv2
        if not (self._cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1) or self._cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 0.25)):
            raise HardwareError(f"camera {self.device!r}: the driver does not allow manual exposure "
                                "(CAP_PROP_AUTO_EXPOSURE rejected)", device=str(self.device))
        want = exposure / self.exposure_unit
        ok = self._cap.set(cv2.CAP_PROP_EXPOSURE, want)
        got = self._cap.get(cv2.CAP_PROP_EXPOSURE)
        if not ok or not math.isclose(got, want, rel_tol=0.05, abs_tol=1.0):
            raise HardwareError(f"camera {self.device!r}: exposure {exposure:g} s not accepted "
                                f"(driver reports {got:g} units)", device=str(self.device))
        self._exposure = got * self.exposure_unit

    def capture(self, exposure: float, gain: float = 1.0, *, timeout: float = 10.0) -> Frame:
        """Set exposure/gain (if changed), drop ``flush`` stale buffered frames, return the next one."""
        cv2 = self._cv2
        if not (exposure > 0 and math.isfinite(exposure)):
            raise ConfigError.field(None, "camera.exposure", exposure, "must be a positive number of seconds")
        if self._cap is None:
            raise HardwareError(f"camera {self.device!r}: capture after close", device=str(self.device))
        if self._exposure is None or not math.isclose(self._exposure, exposure, rel_tol=1e-3):
            self._set_exposure(exposure)
        if gain != self._gain:
            if not self._cap.set(cv2.CAP_PROP_GAIN, gain) and gain != 1.0:
                raise HardwareError(f"camera {self.device!r}: gain {gain:g} not accepted", device=str(self.device))
            self._gain = gain
        for _ in range(max(0, self.flush)):
            self._cap.grab()
        t0 = self.clock.now()
        ok, img = self._cap.read()
        if not ok or img is None:
            raise HardwareError(f"camera {self.device!r}: no frame (read failed)", device=str(self.device))
        if img.ndim == 3:
            img = np.ascontiguousarray(img[..., ::-1])  # BGR -> RGB
        return Frame(pixels=img, exposure=float(self._exposure), gain=float(gain), bit_depth=self.bit_depth,
                     black_level=self.black_level, timestamp=t0, linear=self.linear,
                     meta={"device": str(self.device), "backend": self._cap.getBackendName()})

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None
