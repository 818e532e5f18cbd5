"""A real camera through OpenCV ``VideoCapture`` (V4L2 / UVC webcams and machine-vision cameras with a
V4L2 driver), implementing :class:`gonio.rig.interfaces.Camera`.

Manual exposure: ``CAP_PROP_AUTO_EXPOSURE`` is switched to manual (V4L2 convention: 1 = manual,
3 = aperture priority; some backends use 0.25/0.75) and ``CAP_PROP_EXPOSURE`` set; the value read
back must match, otherwise :class:`~gonio.errors.HardwareError` says the driver does not allow
manual exposure. V4L2 expresses exposure in units of 100 µs (``exposure_unit``). Frames are
converted BGR -> RGB.

How the camera encodes light comes from its description (:mod:`gonio.rig.calibration`): a linear
camera (``linear=True``, 10–16-bit raw) is returned as is; an 8-bit gamma-encoded camera with a
response curve is returned linearized through it (uint16, ``linear=True``); without a curve its
frames say ``linear=False`` and a session refuses them.

Timeouts: ``VideoCapture.read`` has no timeout on V4L2 (``CAP_PROP_READ_TIMEOUT_MSEC`` applies to the
FFmpeg/GStreamer backends only, and only when opening), so the grab runs in a daemon worker thread
and :meth:`OpenCVCamera.capture` waits at most ``timeout`` seconds for it (real time), then raises
:class:`~gonio.errors.HardwareTimeout`. A read still blocked in the driver keeps the camera busy:
later captures wait for it within their own timeout.

Hardware trigger: with ``trigger`` set (e.g. ``RigController.trigger_camera``) the read is started
first, then the trigger fired for the exposure; no stale frames are flushed (a triggered camera
sends none).
"""

from __future__ import annotations

import math
import threading
from contextlib import contextmanager
from typing import Callable

import numpy as np

from gonio.errors import ConfigError, HardwareError, HardwareTimeout
from gonio.rig.interfaces import Clock, Frame

__all__ = ["OpenCVCamera", "open_camera"]


@contextmanager
def _quiet_opencv(cv2):
    """Silence OpenCV's log (``cv2.utils.logging.setLogLevel``, which returns the previous level) for the
    duration of the block only, restoring the caller's level afterwards."""
    logging = getattr(getattr(cv2, "utils", None), "logging", None)
    if logging is None or not hasattr(logging, "setLogLevel"):  # a build without the logging bindings
        yield
        return
    previous = logging.setLogLevel(logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        logging.setLogLevel(previous)


class _Read:
    """One grab+read in a daemon thread (a blocked driver call cannot be interrupted from Python)."""

    def __init__(self, cap, flush: int):
        self.done = threading.Event()
        self.result: tuple[bool, object] = (False, None)
        self.error: BaseException | None = None
        self._cap, self._flush = cap, flush
        threading.Thread(target=self._run, name="gonio-camera-read", daemon=True).start()

    def _run(self) -> None:
        try:
            for _ in range(self._flush):
                self._cap.grab()
            self.result = self._cap.read()
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            self.error = exc
        finally:
            self.done.set()


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
    response : ResponseCurve, optional
        Inverse response of an 8-bit non-linear camera: frames are returned linearized through it.
    trigger : callable, optional
        ``trigger(exposure)`` fires the camera's hardware trigger (the rig controller).
    capture : object, optional
        An already opened ``cv2.VideoCapture``-like object (``device`` is then only its name).
    """

    def __init__(self, device: int | str, clock: Clock, *, backend: int = 200, exposure_unit: float = 1e-4,
                 linear: bool = False, bit_depth: int = 8, black_level: float = 0.0, flush: int = 2,
                 response=None, trigger: Callable[[float], None] | None = None, capture=None):
        self.device = device
        self.clock = clock
        self.exposure_unit = exposure_unit
        self.linear = linear
        self.bit_depth = bit_depth
        self.black_level = black_level
        self.flush = flush
        self.response = response
        self.trigger = trigger
        self._pending: _Read | None = None
        self._exposure: float | None = None
        self._gain: float | None = None
        if response is not None and (linear or bit_depth != 8):
            raise ConfigError.field(None, "camera.response", getattr(response, "source", None),
                                    "is for non-linear 8-bit cameras (linear = false, bit_depth = 8)")
        if capture is not None:
            self._cap = capture
            return
        if isinstance(device, str) and device.isdigit():
            device = int(device)
        if not isinstance(device, (int, str)) or isinstance(device, bool):
            raise ConfigError.field(None, "camera.device", device, "must be an index or a device path")
        import cv2

        with _quiet_opencv(cv2):  # OpenCV's own "[ WARN:0@...] can't open camera" lines: we raise one error
            self._cap = cv2.VideoCapture(device, backend)
        if not self._cap.isOpened():
            self._cap.release()
            raise HardwareError(f"camera {device!r}: cannot open (no such device, or busy)", device=str(device))
        self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)

    # -- settings ----------------------------------------------------------------------------------
    def _set_exposure(self, exposure: float) -> None:
        import cv2

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

    def info(self, probe_exposure: float = 0.01) -> dict:
        """Resolution, backend and whether manual exposure (``probe_exposure`` s) and gain 1 are accepted."""
        import cv2

        self._check_open()
        d = {"device": str(self.device), "backend": self._cap.getBackendName(),
             "width": int(self._cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
             "height": int(self._cap.get(cv2.CAP_PROP_FRAME_HEIGHT))}
        try:
            self._set_exposure(probe_exposure)
            d["manual_exposure"] = f"yes ({self._exposure:g} s read back for {probe_exposure:g} s)"
        except HardwareError as exc:
            d["manual_exposure"] = f"no: {exc}"
        d["gain"] = "yes" if self._cap.set(cv2.CAP_PROP_GAIN, 1.0) else "no (CAP_PROP_GAIN rejected)"
        return d

    def _check_open(self) -> None:
        if self._cap is None:
            raise HardwareError(f"camera {self.device!r}: capture after close", device=str(self.device))

    # -- capture -----------------------------------------------------------------------------------
    def _wait(self, read: _Read, deadline_s: float, what: str) -> None:
        if not read.done.wait(max(deadline_s, 0.0)):
            self._pending = read
            raise HardwareTimeout(f"camera {self.device!r}: no frame within {what}", device=str(self.device))
        self._pending = None

    def capture(self, exposure: float, gain: float = 1.0, *, timeout: float = 10.0) -> Frame:
        """Set exposure/gain (if changed), drop ``flush`` stale buffered frames (none when triggered),
        fire the trigger if any, and return the next frame within ``timeout`` seconds (real time)."""
        import time

        import cv2

        if not (exposure > 0 and math.isfinite(exposure)):
            raise ConfigError.field(None, "camera.exposure", exposure, "must be a positive number of seconds")
        if not (timeout > 0 and math.isfinite(timeout)):
            raise ConfigError.field(None, "camera.timeout", timeout, "must be a positive number of seconds")
        self._check_open()
        start = time.monotonic()  # a real-time bound on a driver call, not protocol time
        if self._pending is not None:  # a read that timed out earlier still holds the driver
            self._wait(self._pending, timeout, f"{timeout:g} s (still blocked in an earlier read)")
        if self._exposure is None or not math.isclose(self._exposure, exposure, rel_tol=1e-3):
            self._set_exposure(exposure)
        if gain != self._gain:
            if not self._cap.set(cv2.CAP_PROP_GAIN, gain) and gain != 1.0:
                raise HardwareError(f"camera {self.device!r}: gain {gain:g} not accepted", device=str(self.device))
            self._gain = gain
        t0 = self.clock.now()
        read = _Read(self._cap, 0 if self.trigger is not None else max(0, self.flush))
        if self.trigger is not None:
            self.trigger(float(self._exposure))
        self._wait(read, timeout - (time.monotonic() - start), f"{timeout:g} s")
        if read.error is not None:
            raise HardwareError(f"camera {self.device!r}: read failed: {read.error}", device=str(self.device))
        ok, img = read.result
        if not ok or img is None:
            raise HardwareError(f"camera {self.device!r}: no frame (read failed)", device=str(self.device))
        img = np.asarray(img)
        if img.ndim == 3 and img.shape[2] == 3:
            img = np.ascontiguousarray(img[..., ::-1])  # BGR -> RGB
        frame = Frame(pixels=img, exposure=float(self._exposure), gain=float(gain), bit_depth=self.bit_depth,
                      black_level=self.black_level, timestamp=t0, linear=self.linear,
                      meta={"device": str(self.device), "backend": self._backend_name(),
                            "trigger": "hardware" if self.trigger is not None else "free-running"})
        return self.response.linearize(frame) if self.response is not None else frame

    def _backend_name(self) -> str:
        try:
            return str(self._cap.getBackendName())
        except Exception:  # noqa: BLE001 - a name for the metadata only
            return "unknown"

    def close(self) -> None:
        if self._cap is not None:
            if self._pending is None or self._pending.done.is_set():
                self._cap.release()
            # else: a read is blocked in the driver; releasing under it may crash the process, so the
            # handle is left to the (daemon) reader and the process exit
            self._cap = None
            self._pending = None


def open_camera(device: int | str, settings, clock: Clock, *, width: int | None = None, height: int | None = None,
                **kw):
    """The camera a :class:`gonio.rig.calibration.CameraSettings` describes: a GenICam camera through
    Aravis (``backend = "aravis"``, :class:`gonio.rig.aravis.AravisCamera`, region ``width`` × ``height``
    from the calibration) or an :class:`OpenCVCamera`."""
    if settings.backend == "aravis":
        from gonio.rig.aravis import AravisCamera

        return AravisCamera(str(device), clock, pixel_format=settings.pixel_format, black_level=settings.black_level,
                            gain_unit=settings.gain_unit, width=width, height=height, **kw)
    return OpenCVCamera(device, clock, backend=settings.backend_id, exposure_unit=settings.exposure_unit,
                        linear=settings.linear, bit_depth=settings.bit_depth, black_level=settings.black_level,
                        response=settings.response, **kw)
