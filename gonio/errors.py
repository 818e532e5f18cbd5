"""The one exception hierarchy of gonio (docs/architecture.md §3).

Every error a user can cause or a device can raise is a :class:`GonioError`; the CLI turns each into a
one-line message and a non-zero exit code, never a traceback.
"""

from __future__ import annotations


class GonioError(Exception):
    """Base of every error gonio raises on purpose."""

    exit_code = 1


class ConfigError(GonioError):
    """Bad user input: a file, field or value that cannot be used.

    The message names the source (file or option), the field and the offending value, e.g.
    ``ConfigError("material.toml: params.alpha = -1: must be in [0.0001, 1]")``.
    """

    exit_code = 2

    @classmethod
    def field(cls, source: str | None, field: str, value: object, why: str) -> "ConfigError":
        """Build the canonical one-line message ``source: field = value: why``."""
        where = f"{source}: " if source else ""
        return cls(f"{where}{field} = {value!r}: {why}")


class HardwareError(GonioError):
    """A device did not do what it was asked (after the retries it was allowed)."""

    exit_code = 3

    def __init__(self, message: str, *, device: str | None = None, code: int | None = None):
        super().__init__(message)
        self.device = device
        self.code = code


class HardwareTimeout(HardwareError):
    """No (complete) reply within the allowed time."""


class ChecksumError(HardwareError):
    """A reply arrived but its CRC/checksum did not match."""


class ServoAlarm(HardwareError):
    """A servo reported a Hardware Error Status (overload, overheating, voltage, encoder...)."""


class ControllerError(HardwareError):
    """The rig controller answered with an error code (see firmware_protocol/SPEC.md)."""


class SafetyStop(HardwareError):
    """A condition under which nothing may move or light up (E-stop, interlock, the light source over its
    temperature limit, a watchdog trip, a servo's hardware alarm): the session stops at once (no retry), with
    its own status (``safety stop: ...``) and exit code, and is resumed by a person once the cause is gone."""

    exit_code = 7


class EmergencyStop(SafetyStop):
    """The E-stop is pressed or an interlock is open: nothing may move or light up."""


class DataError(GonioError):
    """A malformed, truncated or inconsistent data file; the message names the file and the fault."""

    exit_code = 4


class UnreachablePose(GonioError):
    """The rig cannot reach a pose: outside joint limits, colliding arms, or a shadowed path."""

    exit_code = 5

    def __init__(self, message: str, *, reason: str = "unreachable"):
        super().__init__(message)
        self.reason = reason
