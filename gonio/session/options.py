"""Typed options of a session, validated where they are made: the simulated rig's settings
(:class:`SimOptions`), the devices of a real rig (:class:`HardwareOptions`), the light and dark strategy
(:class:`TimingOptions`), and the checks a session's directory, exposures and servos must pass before
anything is written.

Each option object is what the command line's flags become (``gonio measure --sim-resolution 320x240`` is
``SimOptions(resolution="320x240")``), and what a script gives :func:`gonio.session.api.open_rig` and
:func:`gonio.session.api.measure`; a bad value is a :class:`~gonio.errors.ConfigError` whose one line names the
option (``--sim-resolution``), so the command and a script get the same message.

>>> SimOptions(resolution="160x120").size
(160, 120)
>>> TimingOptions(warmup_wait=5.0).as_dict()
{'warmup_min': 5.0}
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

from gonio.errors import ConfigError

__all__ = ["SimOptions", "HardwareOptions", "TimingOptions", "DEFAULT_SIM_RESOLUTION", "parse_resolution",
           "default_session_dir", "check_session_dir", "check_exposures", "check_servo_models", "default_material",
           "load_material_file"]

DEFAULT_SIM_RESOLUTION = "320x240"


def parse_resolution(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` → ``(width, height)``, width in [64, 4096] and height in [48, 4096] (one line naming
    ``--sim-resolution`` otherwise)."""
    try:
        w, h = (int(x) for x in str(text).lower().split("x"))
    except ValueError:
        raise ConfigError.field("--sim-resolution", "resolution", text, "expected WIDTHxHEIGHT, e.g. 320x240") from None
    if not (64 <= w <= 4096 and 48 <= h <= 4096):
        raise ConfigError.field("--sim-resolution", "resolution", text, "width in [64, 4096], height in [48, 4096]")
    return w, h


@dataclass(frozen=True)
class SimOptions:
    """The simulated rig (:mod:`sim.rig`): camera resolution ``WxH``, per-frame faults (``KIND=RATE,...``),
    which controller answers (``firmware``: the reference firmware's host build, ``python``: the independent
    emulator, ``simavr``: the AVR binary in an emulated ATmega328P), the camera link (``direct`` or ``gige``:
    served as a GigE Vision device and read through Aravis, in ``pixel_format``) and the as-built assembly errors (a seed or an
    ERRORS.toml; empty: the rig as declared). ``seed`` seeds every noise source."""

    resolution: str | tuple[int, int] = DEFAULT_SIM_RESOLUTION
    frame_faults: str = ""
    controller: str = "firmware"
    camera: str = "direct"
    as_built: str = ""
    seed: int = 0
    #: The GenICam pixel format of the ``gige`` camera link (empty: the deepest colour format the simulated
    #: GigE camera offers, matching the default camera's 12 bits where it can; :mod:`gonio.session.rigs`).
    pixel_format: str = ""
    #: A sphere target as built: its true centre's offset (mm, x/y/z) from the declared one, unknown to the host
    #: (``--sim-sphere-offset``; the silhouette refinement finds it)
    sphere_offset_mm: tuple[float, float, float] | None = None

    def __post_init__(self):
        if self.sphere_offset_mm is not None:
            v = self.sphere_offset_mm
            if isinstance(v, str):
                try:
                    v = tuple(float(x) for x in v.split(","))
                except ValueError:
                    v = ()
            ok = len(v) == 3 and all(isinstance(x, (int, float)) and abs(x) <= 50 for x in v)
            if not ok:
                raise ConfigError.field("--sim-sphere-offset", "sphere_offset", self.sphere_offset_mm,
                                        "expected X,Y,Z in millimetres, each within ±50")
            object.__setattr__(self, "sphere_offset_mm", tuple(float(x) for x in v))
        if not isinstance(self.resolution, tuple):
            parse_resolution(self.resolution)
        if self.controller not in ("firmware", "python", "simavr"):
            raise ConfigError.field("--sim-controller", "controller", self.controller,
                                    "expected firmware, python or simavr")
        if self.camera not in ("direct", "gige"):
            raise ConfigError.field("--sim-camera", "camera", self.camera, "expected direct or gige")
        if self.pixel_format and self.camera != "gige":
            raise ConfigError.field("--sim-pixel-format", "pixel_format", self.pixel_format,
                                    "is the GenICam format of --sim-camera gige")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2 ** 32:
            raise ConfigError.field("--seed", "seed", self.seed, "expected an integer in [0, 2^32)")

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` of the simulated camera."""
        return tuple(self.resolution) if isinstance(self.resolution, tuple) else parse_resolution(self.resolution)


@dataclass(frozen=True)
class HardwareOptions:
    """A real rig's devices: the servo bus and rig controller serial ports (paths or pyserial URLs), the
    camera (OpenCV index or path, or a GenICam id) and its description file (CAMERA.toml: intrinsics,
    [noise], [camera])."""

    servo_port: str | None = None
    controller_port: str | None = None
    camera: str | None = None
    calibration: str | None = None

    def missing(self, rig: str | None = "given") -> list[str]:
        """The options a hardware session needs that are not given (``--rig`` first, as the command asks)."""
        return [o for o, v in (("--rig", rig), ("--servo-port", self.servo_port),
                               ("--controller-port", self.controller_port), ("--camera", self.camera),
                               ("--calibration", self.calibration)) if not v]


@dataclass(frozen=True)
class TimingOptions:
    """The light and dark strategy (:class:`gonio.plan.labtime.SessionTiming`): ``accurate`` waits until the
    light is stable and re-measures the whole dark set on schedule; ``warmup_wait`` seconds of warm-up before
    the first pose (default 0: the photodiode corrects the drift); ``darks`` ``model`` or ``measured``."""

    accurate: bool = False
    warmup_wait: float | None = None
    darks: str | None = None

    def as_dict(self) -> dict:
        """The :class:`SessionTiming` fields the manifest records (``timing``), validated."""
        from gonio.plan.labtime import SessionTiming

        d = {"warmup": "stable", "darks": "measured"} if self.accurate else {}
        if self.warmup_wait is not None:
            if self.accurate:
                raise ConfigError.field("--warmup-wait", "warmup_wait", self.warmup_wait,
                                        "--accurate waits until the light is stable: give one of them")
            if not (0 <= self.warmup_wait <= 3600):
                raise ConfigError.field("--warmup-wait", "warmup_wait", self.warmup_wait, "must be seconds in [0, 3600]")
            d["warmup_min"] = float(self.warmup_wait)
        if self.darks is not None:
            d["darks"] = self.darks
        SessionTiming(**d)
        return d


def default_session_dir() -> str:
    """``./gonio-session-YYYYmmdd-HHMMSS``: where a session goes when no directory is given."""
    return time.strftime("gonio-session-%Y%m%d-%H%M%S")


def check_session_dir(out: str, option: str = "--out") -> None:
    """Refuse, before anything starts, a directory holding a session or one that cannot be created
    (one line naming ``option``, the option that chose the directory)."""
    from gonio.io.outputs import session_root
    from gonio.store.directory import MANIFEST, SAMPLES

    d = Path(out)
    if d.exists() and not d.is_dir():
        raise ConfigError.field(option, "session directory", out, "exists and is not a directory")
    root = session_root(Path(os.path.realpath(d.absolute())) / "manifest.json")  # d itself, or inside another
    if root is not None and root != Path(os.path.realpath(d.absolute())):
        raise ConfigError.field(option, "session directory", out, f"is inside the session directory {root}: a "
                                "session holds only what it measured (choose a directory elsewhere)")
    if any((d / n).exists() for n in (MANIFEST, SAMPLES)):
        raise ConfigError.field(option, "session directory", out,
                                f"holds another session; choose a new directory or `gonio resume {out}`")
    parent = d if d.exists() else next((p for p in d.absolute().parents if p.exists()), Path("/"))
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError.field(option, "session directory", out, f"not writable ({parent} is read-only to you)")


def check_exposures(plan, limits, camera: str) -> None:
    """A fixed bracket's exposures lie in the camera's range ``limits`` (s), else one line naming the value —
    checked before the session directory is made (an exposure typed in milliseconds, ``--exposures 4,16,64``,
    left a session that failed at its first pose on every resume). Automatic exposure stays in range itself."""
    cap = plan.capture
    if cap.auto_exposure:
        return
    lo, hi = limits
    for t in cap.exposures:
        if not lo <= t <= hi:
            raise ConfigError.field("--exposures", "capture.exposures", t,
                                    f"must be in [{lo:g}, {hi:g}] s for {camera} (exposures are in seconds)")


def check_servo_models(rig) -> None:
    """Every joint's servo model has a control table (:func:`gonio.rig.control_table.load_control_table`), else
    one line naming the rig file and the joint — checked before the session directory is made (it was made, then
    left marked running with nothing in it, when the simulated bus refused the model)."""
    from gonio.rig.control_table import load_control_table

    for j in rig.joints:
        try:
            load_control_table(j.model)
        except ConfigError as exc:
            raise ConfigError(f"{rig.source}: joint {j.name}: {exc}") from None


def default_material():
    """The simulated sample's material when none is given (the shipped ``sim/materials/default.toml``)."""
    from importlib import resources

    from gonio.io.material_toml import load_material

    res = resources.files("sim") / "materials" / "default.toml"
    with resources.as_file(res) as p:
        return load_material(p)


def load_material_file(path: str | None):
    """The material of ``--material FILE`` — a material TOML (:func:`gonio.io.material_toml.load_material`) or a
    measured material or fit JSON (:func:`gonio.io.material_file.open_material`) — or the default."""
    from gonio.io.material_file import open_material

    return default_material() if path is None else open_material(path)
