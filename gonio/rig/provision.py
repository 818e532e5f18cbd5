"""Provisioning Dynamixel servos (what Dynamixel Wizard does on a lab's first day): find every servo on a bus
at every standard baud rate, give a factory servo (ID 1 at 57,600 baud) the ID and rate the rig file wants,
reset a servo to its factory settings — through the real ``dynamixel-sdk`` (:class:`gonio.rig.dynamixel.DynamixelBus`).

* :func:`scan_bus`: a broadcast ping at each rate of :data:`STANDARD_BAUDS` (Baud Rate(8) of the X series,
  ROBOTIS e-manual: 0 = 9,600, 1 = 57,600, 2 = 115,200, 3 = 1 M, 4 = 2 M, 5 = 3 M, 6 = 4 M, 7 = 4.5 M; the
  control tables' ``[baud_rates]``); replies that fail their CRC at a rate are counted there (two servos with
  one ID at one rate answer together and their packets collide).
* :func:`only_servo`: the one servo a change may be made to — refused when the bus holds more than one (or
  colliding replies, or none): an ID or baud change with two servos on the bus can give two servos one ID.
* :func:`change_id_baud`: torque off (the EEPROM area is writable only with Torque Enable 0, e-manual
  "Torque Enable(64)"), the ID written (no status awaited: it comes back under the new ID), then Baud Rate(8)
  (its status comes at the old rate, then the servo switches), the port reopened at the new rate and
  everything read back: a :class:`ProvisionError` unless the servo answers as asked.
* :func:`factory_reset`: Protocol 2.0 Factory Reset (instruction 0x06; 0xFF all: ID 1 and 57,600 baud; 0x01
  all but the ID; 0x02 all but ID and baud), then found again where it must answer and read back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

from gonio.errors import ConfigError, HardwareError, HardwareTimeout
from gonio.rig.control_table import ControlTable, table_for_model_number
from gonio.rig.dynamixel import MAX_ID, DynamixelBus

__all__ = ["STANDARD_BAUDS", "FACTORY_ID", "FACTORY_BAUD", "RESET_OPTIONS", "FoundServo", "BusScan", "ProvisionError",
           "scan_bus", "only_servo", "change_id_baud", "factory_reset"]

#: The X series' rates, most likely first (factory 57,600; the shipped rigs' 1 M), then the others.
STANDARD_BAUDS = (57600, 1000000, 115200, 2000000, 3000000, 4000000, 4500000, 9600)
FACTORY_ID, FACTORY_BAUD = 1, 57600
#: ``--factory-reset`` names → the instruction's parameter (Protocol 2.0 e-manual, "Factory Reset").
RESET_OPTIONS = {"all": 0xFF, "keep-id": 0x01, "keep-id-baud": 0x02}


class ProvisionError(HardwareError):
    """A servo did not end up as asked (read back differs), or the bus is not fit for the change."""


@dataclass(frozen=True)
class FoundServo:
    """One servo that answered: its rate, ID, model number and (if gonio has its control table) model name."""

    baud: int
    id: int
    model_number: int

    @property
    def table(self) -> ControlTable | None:
        return table_for_model_number(self.model_number)

    @property
    def model(self) -> str:
        t = self.table
        return t.model if t is not None else f"model {self.model_number}"

    def __str__(self) -> str:
        return f"ID {self.id} at {self.baud} baud ({self.model})"


@dataclass(frozen=True)
class BusScan:
    """What :func:`scan_bus` found: every servo, and per rate the status packets that arrived corrupted."""

    found: tuple[FoundServo, ...]
    corrupted: dict[int, int]
    bauds: tuple[int, ...]

    def lines(self) -> list[str]:
        rows = [f"{'baud':>8}  {'id':>3}  {'model':<12} model_number"]
        rows += [f"{s.baud:>8}  {s.id:>3}  {s.model:<12} {s.model_number}" for s in self.found]
        rows += [f"{b:>8}  {n} corrupted replies: two servos with one ID at this rate, or a noisy line"
                 for b, n in self.corrupted.items() if n]
        return rows


def scan_bus(port: str, bauds: Sequence[int] = STANDARD_BAUDS, *, max_id: int = MAX_ID, latency_timer_ms: float = 16.0,
             attempts: int = 2) -> BusScan:
    """Every servo on ``port`` at each rate of ``bauds`` (broadcast pings, :meth:`DynamixelBus.broadcast_ping`,
    each waiting for IDs up to ``max_id``; ``attempts`` pings per rate, their answers merged — a lost reply is
    not a missing servo)."""
    found: list[FoundServo] = []
    corrupted: dict[int, int] = {}
    for baud in bauds:
        ids: dict[int, int] = {}
        bad = 0
        with DynamixelBus(port, baud, latency_timer_ms=latency_timer_ms) as bus:
            for _ in range(max(1, attempts)):
                got, n = bus.broadcast_ping(max_id)
                ids.update(got)
                bad = max(bad, n)
        found += [FoundServo(baud, i, m) for i, m in sorted(ids.items())]
        corrupted[baud] = bad
    return BusScan(tuple(found), corrupted, tuple(bauds))


def only_servo(scan: BusScan, port: str) -> FoundServo:
    """The servo of a bus that holds exactly one; :class:`ProvisionError` naming what is there otherwise."""
    collided = [b for b, n in scan.corrupted.items() if n]
    if len(scan.found) == 1 and not collided:
        return scan.found[0]
    if not scan.found and not collided:
        raise HardwareTimeout(f"{port}: no servo answered at {', '.join(map(str, scan.bauds))} baud (power on? "
                              "the adapter's TTL/RS-485 side the servo is wired to?)", device=port)
    what = [str(s) for s in scan.found] + [f"colliding replies at {b} baud (servos sharing an ID)" for b in collided]
    raise ProvisionError(f"{port}: {len(scan.found)} servo{'s' if len(scan.found) != 1 else ''} answer"
                         f"{'s' if len(scan.found) == 1 else ''} ({'; '.join(what)}): connect one servo at a time "
                         "to change an ID, a baud rate or to reset it", device=port)


def _table(servo: FoundServo, port: str) -> ControlTable:
    table = servo.table
    if table is None:
        raise ConfigError.field(port, "model_number", servo.model_number,
                                f"servo {servo.id} has no control table in gonio (known: XM430-W350, XM540-W270)")
    return table


def _torque_off(bus: DynamixelBus, servo: FoundServo, table: ControlTable) -> None:
    """Torque Enable 0, read back: EEPROM writes are refused while it is 1 (e-manual, "Torque Enable(64)")."""
    bus.write(servo.id, table, "torque_enable", 0, alarm_ok=True)
    if bus.read(servo.id, table, "torque_enable", alarm_ok=True):
        raise ProvisionError(f"{bus.port_name}: servo {servo.id}: torque is still on after writing Torque Enable 0",
                             device=bus.port_name)


def _answer(bus: DynamixelBus, dxl_id: int, sleep: Callable[[float], None], seconds: float = 3.0) -> int:
    """Ping ``dxl_id`` until it answers (a servo restarting after a reset answers again within ~1 s)."""
    waited = 0.0
    while True:
        try:
            return bus.ping(dxl_id)
        except HardwareTimeout:
            if waited >= seconds:
                raise
            sleep(0.1)
            waited += 0.1


def _read_back(port: str, baud: int, dxl_id: int, model_number: int, *, latency_timer_ms: float,
               sleep: Callable[[float], None]) -> FoundServo:
    """Open ``port`` at ``baud`` and check that servo ``dxl_id`` answers with ``model_number``, and that its ID
    and Baud Rate registers say so; :class:`ProvisionError` naming what differs."""
    with DynamixelBus(port, baud, latency_timer_ms=latency_timer_ms) as bus:
        try:
            model = _answer(bus, dxl_id, sleep)
        except HardwareTimeout:
            raise ProvisionError(f"{port}: no servo answers as ID {dxl_id} at {baud} baud after the change: run "
                                 "`gonio servo setup --port ...` (it scans every rate) to find it", device=port) from None
        found = FoundServo(baud, dxl_id, model)
        table = _table(found, port)
        got = (model, bus.read(dxl_id, table, "id", alarm_ok=True), bus.read(dxl_id, table, "baud_rate", alarm_ok=True))
    want = (model_number, dxl_id, table.baud_code(baud))
    if got != want:
        raise ProvisionError(f"{port}: read back model {got[0]}, ID {got[1]}, Baud Rate(8) {got[2]}; expected "
                             f"model {want[0]}, ID {want[1]}, Baud Rate(8) {want[2]} ({baud} baud)", device=port)
    return found


def change_id_baud(port: str, servo: FoundServo, new_id: int, new_baud: int, *, latency_timer_ms: float = 16.0,
                   sleep: Callable[[float], None] | None = None) -> FoundServo:
    """Give ``servo`` (the only one on the bus: :func:`only_servo`) the ID ``new_id`` and the rate ``new_baud``,
    then read it back (module docstring). Returns the servo as it answers now."""
    import time

    sleep = sleep or time.sleep
    table = _table(servo, port)
    if not 0 <= new_id <= MAX_ID:
        raise ConfigError.field("--set-id", "id", new_id, f"servo IDs are 0..{MAX_ID}")
    code = table.baud_code(new_baud)  # ConfigError naming a rate this model does not have
    with DynamixelBus(port, servo.baud, latency_timer_ms=latency_timer_ms) as bus:
        _torque_off(bus, servo, table)
        dxl_id = servo.id
        if new_id != dxl_id:
            bus.write_unacknowledged(dxl_id, table, "id", new_id)
            sleep(0.05)  # the status under the new ID, if the servo sends one, arrives and is flushed
            try:
                model = _answer(bus, new_id, sleep, seconds=1.0)
            except HardwareTimeout:
                raise ProvisionError(f"{port}: servo {dxl_id} does not answer as ID {new_id} after the ID write (still "
                                     f"ID {dxl_id}? its EEPROM locked?)", device=port) from None
            if model != servo.model_number:
                raise ProvisionError(f"{port}: ID {new_id} answers with model {model}, not {servo.model_number}: "
                                     "another servo on the bus?", device=port)
            dxl_id = new_id
        if new_baud != servo.baud:
            bus.write(dxl_id, table, "baud_rate", code, alarm_ok=True)
    return _read_back(port, new_baud, new_id, servo.model_number, latency_timer_ms=latency_timer_ms, sleep=sleep)


def factory_reset(port: str, servo: FoundServo, option: str = "keep-id-baud", *, latency_timer_ms: float = 16.0,
                  sleep: Callable[[float], None] | None = None) -> FoundServo:
    """Protocol 2.0 Factory Reset of ``servo`` with ``option`` (:data:`RESET_OPTIONS`), torque off first; the
    servo is then found where it must answer (ID 1 / 57,600 baud for what was not kept) and read back."""
    import time

    sleep = sleep or time.sleep
    if option not in RESET_OPTIONS:
        raise ConfigError.field("--factory-reset", "factory_reset", option, f"must be one of {', '.join(RESET_OPTIONS)}")
    table = _table(servo, port)
    with DynamixelBus(port, servo.baud, latency_timer_ms=latency_timer_ms) as bus:
        _torque_off(bus, servo, table)
        bus.factory_reset(servo.id, RESET_OPTIONS[option])
    sleep(0.1)
    new_id = FACTORY_ID if option == "all" else servo.id
    new_baud = servo.baud if option == "keep-id-baud" else FACTORY_BAUD
    return _read_back(port, new_baud, new_id, servo.model_number, latency_timer_ms=latency_timer_ms, sleep=sleep)
