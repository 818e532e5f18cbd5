"""Small capability interfaces of the rig's devices (docs/architecture.md §1, §7).

Each device kind is a :class:`typing.Protocol` with a few methods; a real implementation and a
simulated twin satisfy the same protocol, so the session runner cannot tell them apart. Every
blocking call has a finite timeout. Units: seconds, radians, metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Protocol, Sequence, runtime_checkable

import numpy as np


@runtime_checkable
class Clock(Protocol):
    """Source of time for hardware code (real or simulated)."""

    simulated: bool

    def now(self) -> float:
        """Seconds since an arbitrary origin."""

    def sleep(self, seconds: float) -> None:
        """Wait ``seconds`` (really, or by advancing simulated time)."""


@dataclass(frozen=True)
class Frame:
    """One camera frame and what is needed to interpret its pixels radiometrically.

    Attributes
    ----------
    pixels : ndarray
        Raw sensor values, shape ``(H, W)`` or ``(H, W, 3)`` (RGB order), integer dtype.
    exposure : float
        Exposure time actually used, seconds.
    gain : float
        Analogue gain actually used (linear factor, 1 = unity).
    bit_depth : int
        Significant bits per pixel value (8, 10, 12, 14 or 16).
    black_level : float
        Pedestal added by the sensor, in pixel units (subtracted by the pipeline).
    timestamp : float
        Capture time from the session's :class:`Clock`, seconds.
    linear : bool
        True if pixel values are proportional to irradiance × exposure (above black level).
    meta : mapping
        Anything else the backend knows (device name, temperature, trigger mode...).
    """

    pixels: np.ndarray
    exposure: float
    gain: float
    bit_depth: int
    black_level: float
    timestamp: float
    linear: bool = True
    meta: Mapping[str, object] = field(default_factory=dict)

    @property
    def saturation_level(self) -> int:
        """Largest value the sensor can report."""
        return (1 << self.bit_depth) - 1


@runtime_checkable
class Camera(Protocol):
    """A camera that captures one frame at a requested exposure and gain."""

    def capture(self, exposure: float, gain: float = 1.0, *, timeout: float = 10.0) -> Frame:
        """Capture one frame; raise :class:`gonio.errors.HardwareError` on failure."""

    def close(self) -> None:
        """Release the device."""


class PhotodiodeReading(tuple):
    """One reference-photodiode reading: ``(mean, sem)`` — it unpacks and compares as that pair, as
    ``read_photodiode`` always returned — plus when it was taken.

    Attributes
    ----------
    mean, sem : float
        Mean of the samples and its standard uncertainty (relative units, 1 = full level warmed up).
    samples : int
        Number of ADC conversions averaged.
    time : float or None
        The instant the mean stands for, on the host's :class:`Clock` (seconds; the session's lab time):
        the middle of the controller's sampling window as the host places it (see
        :meth:`gonio.rig.controller.RigController.read_photodiode`); None if not known.
    uptime : float or None
        The same instant on the controller's own clock (seconds since its reset, the timer of STATUS's
        uptime), exact to 1 ms; None from a protocol 2.0 controller, which does not send it.
    span : float or None
        Seconds from the first to the last conversion (None if not known).
    """

    def __new__(cls, mean: float, sem: float, *, samples: int = 1, time: float | None = None,
                uptime: float | None = None, span: float | None = None):
        self = super().__new__(cls, (float(mean), float(sem)))
        self.samples, self.time, self.uptime, self.span = int(samples), time, uptime, span
        return self

    mean = property(lambda self: self[0])
    sem = property(lambda self: self[1])

    def __reduce__(self):
        return (_photodiode_reading, (self[0], self[1], self.samples, self.time, self.uptime, self.span))

    def __repr__(self) -> str:
        return (f"PhotodiodeReading(mean={self[0]!r}, sem={self[1]!r}, samples={self.samples}, "
                f"time={self.time!r}, uptime={self.uptime!r}, span={self.span!r})")


def _photodiode_reading(mean, sem, samples, time, uptime, span) -> PhotodiodeReading:
    return PhotodiodeReading(mean, sem, samples=samples, time=time, uptime=uptime, span=span)


@dataclass(frozen=True)
class ControllerStatus:
    """What the rig controller reports about itself (see firmware_protocol/SPEC.md)."""

    estop: bool
    interlock_open: bool
    light_on: bool
    light_level: float
    temperature_c: float
    uptime_s: float
    flags: int = 0
    #: why the controller last reset ("power-on", "hardware watchdog", ...; protocol ≥ 2.2), None if not said
    reset_cause: str | None = None

    @property
    def stop_reason(self) -> str | None:
        """Why nothing may move and the light is off: ``"E-stop is pressed"``, ``"enclosure interlock is open"``,
        or None when both are clear."""
        if self.estop:
            return "E-stop is pressed"
        return "enclosure interlock is open" if self.interlock_open else None

    def unsafe_reason(self, light_was_on: bool) -> str | None:
        """The first *unsafe* status flag in words and what a person does about it (firmware_protocol/SPEC.md
        §4.2, §4.6), or None: E-stop,
        interlock, over-temperature (with the temperature), and — when ``light_was_on`` (the host switched the
        light on in this session) — a watchdog trip (the light went off behind the host's back). Bits that
        are not unsafe (LIGHT_ON, NOT_CONFIGURED, TRIGGER_ACTIVE) and reserved bits are ignored."""
        from firmware_protocol import codec as fp

        what = self.stop_reason
        if what:
            return what
        if self.flags & fp.FLAG_OVERTEMP:
            return (f"light source over its temperature limit ({self.temperature_c:.1f} °C), the controller "
                    "switched the light off: let it cool (check its fan and heat sink)")
        if light_was_on and self.flags & fp.FLAG_WATCHDOG_TRIPPED:
            return ("the controller's watchdog switched the light off (it heard nothing from this host for too "
                    "long): check the host (suspended? overloaded? cable?)")
        return None


@runtime_checkable
class RigController(Protocol):
    """The rig's microcontroller: light source, reference photodiode, camera trigger, E-stop."""

    def set_light(self, on: bool, level: float = 1.0) -> None:
        """Switch the light on/off at relative level 0..1."""

    def read_photodiode(self, samples: int = 1) -> tuple[float, float]:
        """Mean reference photodiode reading and its standard uncertainty (relative units): a
        :class:`PhotodiodeReading` (a ``(mean, sem)`` pair that also says when it was taken) or a plain pair."""

    def trigger_camera(self, exposure: float) -> None:
        """Fire the camera's hardware trigger for ``exposure`` seconds."""

    def status(self) -> ControllerStatus:
        """Current status (E-stop, interlocks, light, temperature)."""

    def heartbeat(self) -> None:
        """Tell the controller the host is alive (feeds its watchdog)."""

    def close(self) -> None:
        """Switch the light off if possible and release the port."""


@runtime_checkable
class Axes(Protocol):
    """A set of named joints moved together (e.g. Dynamixel servos on one bus).

    Joint angles are radians in the rig's joint frame (after gear ratio and zero offset).
    """

    names: Sequence[str]

    def move_to(self, targets: Mapping[str, float], *, timeout: float = 60.0) -> dict[str, float]:
        """Move all named joints together, wait until settled; return the *measured* angles."""

    def positions(self) -> dict[str, float]:
        """Measured joint angles now."""

    def close(self) -> None:
        """Leave the joints in a safe state and release the bus."""
