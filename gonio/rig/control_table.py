"""Dynamixel control tables as data (``gonio/rig/control_tables/<MODEL>.toml``).

Each table lists, per field, the address, size, access (``R``/``RW``), area (``EEPROM``/``RAM``),
default value and signedness, as in the ROBOTIS e-manual's "Control Table" of that model. The
driver (:mod:`gonio.rig.dynamixel`) and the emulator (``sim.servo_bus``) both read these files, so an
address is written down once.

Unit conversions (e-manual, "Profile Velocity(112)", "Profile Acceleration(108)", "Present
Position(132)"): one position tick is 360°/4096; one velocity unit is 0.229 rev/min; one
acceleration unit is 214.577 rev/min².
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from typing import Mapping

from gonio.config import parse_toml
from gonio.errors import ConfigError

#: Baud rates a port can be opened at: the SDK's PortHandler whitelist, plus 4,500,000 (X series Baud Rate(8) = 7),
#: which the SDK refuses and :class:`gonio.rig.dynamixel.PortHandler` sets as a custom rate (pyserial, termios2).
BAUD_RATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000,
              2000000, 2500000, 3000000, 3500000, 4000000, 4500000)


__all__ = ["Field", "ControlTable", "load_control_table", "model_names", "table_for_model_number"]


@dataclass(frozen=True)
class Field:
    """One control-table entry."""

    name: str
    address: int
    size: int
    access: str
    area: str
    default: int
    signed: bool = False

    @property
    def writable(self) -> bool:
        return "W" in self.access

    @property
    def eeprom(self) -> bool:
        return self.area == "EEPROM"

    def to_unsigned(self, value: int) -> int:
        """Two's-complement encoding of ``value`` in ``size`` bytes (what goes on the wire)."""
        return int(value) & ((1 << (8 * self.size)) - 1)

    def from_unsigned(self, raw: int) -> int:
        """Decode an unsigned wire value (the SDK returns unsigned) into this field's signed value."""
        raw = int(raw) & ((1 << (8 * self.size)) - 1)
        if self.signed and raw >= 1 << (8 * self.size - 1):
            raw -= 1 << (8 * self.size)
        return raw


@dataclass(frozen=True)
class ControlTable:
    """The control table of one servo model."""

    model: str
    model_number: int
    fields: Mapping[str, Field]
    ticks_per_rev: int = 4096
    position_max: int = 4095
    velocity_unit_rpm: float = 0.229
    acceleration_unit_rpm2: float = 214.577
    #: Baud Rate(8) register value → bits per second (the table's ``[baud_rates]``); empty if not given
    baud_rates: Mapping[int, int] = field(default_factory=dict)

    def baud_code(self, baud: int) -> int:
        """The Baud Rate(8) value that selects ``baud`` (ConfigError listing the rates this model supports)."""
        for code, rate in self.baud_rates.items():
            if rate == baud:
                return code
        raise ConfigError.field(self.model, "baud_rate", baud, "not a baud rate of this model; it supports "
                                + ", ".join(str(r) for r in sorted(self.baud_rates.values())))

    def __getitem__(self, name: str) -> Field:
        try:
            return self.fields[name]
        except KeyError:
            raise ConfigError(f"control table {self.model}: no field {name!r}") from None

    @property
    def size(self) -> int:
        """Bytes needed to hold every field (highest address + size)."""
        return max(f.address + f.size for f in self.fields.values())

    def span(self, first: str, last: str) -> tuple[int, int]:
        """``(address, length)`` of the contiguous block from field ``first`` through ``last``."""
        a, b = self[first], self[last]
        return a.address, b.address + b.size - a.address

    # -- unit conversions (e-manual units) -------------------------------------------------------
    def rad_per_tick(self) -> float:
        return 2.0 * math.pi / self.ticks_per_rev

    def velocity_to_rad_s(self, units: float) -> float:
        """Velocity register units (0.229 rev/min) → rad/s of the servo horn."""
        return units * self.velocity_unit_rpm * 2.0 * math.pi / 60.0

    def rad_s_to_velocity(self, rad_s: float) -> int:
        """rad/s of the horn → velocity register units (rounded down, so a speed limit holds; at least 1)."""
        return max(1, math.floor(rad_s * 60.0 / (2.0 * math.pi) / self.velocity_unit_rpm + 1e-9))

    def profile_limits(self, max_speed: float, max_accel: float, gear_ratio: float = 1.0) -> tuple[float, float]:
        """Joint-side speed (rad/s) and acceleration (rad/s²) a servo really runs at when the driver writes
        ``max_speed``/``max_accel`` (joint side, through ``gear_ratio``) as Profile Velocity/Acceleration:
        the registers round down (:meth:`rad_s_to_velocity`), so e.g. 80°/s² runs at 73.8°/s² on an X series
        servo (214.577 rev/min² units)."""
        g = float(gear_ratio)
        return (self.velocity_to_rad_s(self.rad_s_to_velocity(max_speed * g)) / g,
                self.acceleration_to_rad_s2(self.rad_s2_to_acceleration(max_accel * g)) / g)

    def acceleration_to_rad_s2(self, units: float) -> float:
        """Acceleration register units (214.577 rev/min²) → rad/s² of the horn."""
        return units * self.acceleration_unit_rpm2 * 2.0 * math.pi / 3600.0

    def rad_s2_to_acceleration(self, rad_s2: float) -> int:
        """rad/s² of the horn → acceleration register units (rounded down; at least 1)."""
        return max(1, math.floor(rad_s2 * 3600.0 / (2.0 * math.pi) / self.acceleration_unit_rpm2 + 1e-9))


def _parse(model: str, text: str, source: str) -> ControlTable:
    data = parse_toml(text, source)
    fields = {}
    for name, spec in data.get("fields", {}).items():
        try:
            f = Field(name, int(spec["address"]), int(spec["size"]), str(spec["access"]), str(spec["area"]),
                      int(spec["default"]), bool(spec.get("signed", False)))
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError.field(source, f"fields.{name}", spec, f"needs address, size, access, area, default ({exc})")
        if f.size not in (1, 2, 4) or f.access not in ("R", "RW") or f.area not in ("EEPROM", "RAM"):
            raise ConfigError.field(source, f"fields.{name}", spec, "size must be 1/2/4, access R/RW, area EEPROM/RAM")
        fields[name] = f
    for key in ("model_number",):
        if key not in data:
            raise ConfigError.field(source, key, None, "missing")
    bauds = data.get("baud_rates", {})
    try:
        baud_rates = {int(k): int(v) for k, v in bauds.items()}
    except (AttributeError, TypeError, ValueError):
        raise ConfigError.field(source, "baud_rates", bauds, "must map register values to baud rates") from None
    return ControlTable(model=str(data.get("model", model)), model_number=int(data["model_number"]), fields=fields,
                        baud_rates=baud_rates,
                        ticks_per_rev=int(data.get("ticks_per_rev", 4096)),
                        position_max=int(data.get("position_max", 4095)),
                        velocity_unit_rpm=float(data.get("velocity_unit_rpm", 0.229)),
                        acceleration_unit_rpm2=float(data.get("acceleration_unit_rpm2", 214.577)))


def model_names() -> list[str]:
    """Models with a control table shipped in ``gonio/rig/control_tables``."""
    folder = resources.files("gonio.rig") / "control_tables"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


@lru_cache(maxsize=None)
def load_control_table(model: str) -> ControlTable:
    """The control table of ``model`` (e.g. ``"XM430-W350"``); ConfigError for unknown models."""
    if model not in model_names():
        raise ConfigError.field(None, "model", model, f"no control table; known: {', '.join(model_names())}")
    path = resources.files("gonio.rig") / "control_tables" / f"{model}.toml"
    return _parse(model, path.read_text(encoding="utf-8"), f"control_tables/{model}.toml")


def table_for_model_number(number: int) -> ControlTable | None:
    """The shipped table whose Model Number(0) is ``number``, or None."""
    for name in model_names():
        table = load_control_table(name)
        if table.model_number == number:
            return table
    return None
