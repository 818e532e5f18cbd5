"""A bus of emulated Dynamixel servos speaking Protocol 2.0 on a pseudo-terminal.

The host opens :attr:`ServoBus.path` with the real ``dynamixel-sdk``; nothing in gonio knows it is
simulated. What is emulated (ROBOTIS e-manual, X series / Protocol 2.0):

* packets: header, byte stuffing, CRC-16 (:mod:`sim.dxl_packet`); ping, broadcast ping, read, write,
  reg write / action, sync read / write, bulk read / write, reboot, factory reset (0xFF all: ID 1 and 57,600
  baud; 0x01 all but the ID; 0x02 all but ID and baud; a broadcast reset-all ignored, as firmware v42+ does),
  clear; status return level; a packet with a bad CRC addressed to a servo gets a status with the CRC error;
* provisioning: a model per servo (a mixed XM540/XM430 bus), Baud Rate(8) obeyed (a servo hears the host
  only at its rate, read from the pty's termios), ID and baud changes take effect at once (the status of the
  write goes out first), several servos at different rates, several servos sharing an ID (their replies
  collide, :meth:`ServoBus._send_together`);
* control table from ``gonio/rig/control_tables/<model>.toml``; EEPROM writes refused (access error)
  while Torque Enable is 1; read-only fields refused; in Position Control Mode a Goal Position outside
  [Min, Max] Position Limit is refused with the data-limit error; Homing Offset shifts Present Position;
* motion on the shared :class:`~gonio.rig.interfaces.Clock`: a Goal Position write starts the
  velocity-based profile from the present position at rest (Profile Velocity 0 = the Velocity Limit;
  Profile Acceleration 0 = infinite, i.e. rectangular profile), :func:`gonio.rig.kinematics.trapezoid_progress`;
  Moving, Moving Status, Present Velocity, Velocity/Position Trajectory follow it;
* the reported position is quantized to ticks with seeded Gaussian noise; :attr:`SimServo.joint_ticks`
  is the load side after a backlash (play) of ``backlash_ticks`` — what a camera would see;
* faults on demand: :meth:`SimServo.trip` (hardware error, e.g. overload: Hardware Error Status bit,
  alert bit 0x80 in every status, torque off until reboot); :attr:`ServoBus.faults`
  (:class:`sim.faults.LinkFaults`: corrupted, dropped, late replies); :meth:`SimServo.unplug`;
  :meth:`ServoBus.power_cycle` (RAM back to defaults, EEPROM kept).

Replies to sync and bulk read come in the order the IDs were listed (FIELD-NOTES.md). Simplifications:
a new goal during a move restarts the profile from rest; Drive Mode (reverse, time-based profile),
return delay time and PID dynamics are not modelled.

Run ``python -m sim.servo_bus --ids 1,2,3,4`` to serve a bus on real time for the lab CLI; ``--rig default`` for
the shipped rig's mixed XM540/XM430 servos at its 1 Mbps, ``--model 1=XM540-W270,2=XM430-W350 --baud 57600`` per
ID, ``--servo 1:XM540-W270@57600`` (repeatable) for factory servos (:func:`parse_servos`).
"""

from __future__ import annotations

import contextlib
import math
import threading
from typing import Iterable, Mapping

import numpy as np

from gonio.rig.clock import RealClock
from gonio.rig.control_table import ControlTable, load_control_table
from gonio.rig.kinematics import trapezoid_progress, trapezoid_time
from sim import dxl_packet as P
from sim.faults import LinkFaults
from sim.pty import PtyServer
from sim.seeding import SETUP, pose_rng, position_key

#: Instructions after which the servos' IDs may have changed (the bus re-groups them by ID).
_CHANGES_ID = frozenset({P.INST_WRITE, P.INST_ACTION, P.INST_FACTORY_RESET, P.INST_SYNC_WRITE, P.INST_BULK_WRITE})
#: Hardware Error Status bits (e-manual, "Shutdown(63)").
HW_INPUT_VOLTAGE, HW_OVERHEATING, HW_ENCODER, HW_ELECTRICAL_SHOCK, HW_OVERLOAD = 0x01, 0x04, 0x08, 0x10, 0x20


class SimServo:
    """One emulated servo: its control table memory and its motion on the clock."""

    def __init__(self, dxl_id: int, model: str, clock, *, rng: np.random.Generator, noise_ticks: float = 0.3,
                 backlash_ticks: float = 0.0, position: float = 2048.0, seed: int | None = None):
        self.table: ControlTable = load_control_table(model)
        self.clock = clock
        self.rng = rng
        #: with a seed, a servo at rest after a move reads one noise value drawn at the arrival from
        #: (seed, ID, goal) (sim.seeding): the readings at rest do not depend on how many reads the move
        #: before took, or on the other servos (bit-identical resume); while moving, per-read noise
        self.seed = seed
        self._rest_noise: float | None = None
        self.noise_ticks = float(noise_ticks)
        self.backlash_ticks = float(backlash_ticks)
        self.mem = bytearray(self.table.size)
        #: name -> (start, end, size, signed, mask) of every field: peek and poke run on every read of the bus
        self._slots = {f.name: (f.address, f.address + f.size, f.size, f.signed, (1 << (8 * f.size)) - 1)
                       for f in self.table.fields.values()}
        self._move_time = 0.0  #: duration of the move in ``_move`` (trapezoid_time, computed once per move)
        self.online = True
        self.horn = float(position)  #: true horn angle, ticks (physical: survives reboot and power cycle)
        self.joint_ticks = float(position)  #: load side after backlash, ticks
        self._move: tuple[float, float, float, float, float] | None = None  # t0, start, distance, v, a
        self._registered: tuple[int, bytes] | None = None
        self.reset(eeprom=True)
        self.poke("id", dxl_id)

    # -- memory ---------------------------------------------------------------------------------
    def reset(self, *, eeprom: bool = False, keep: Iterable[str] = ()) -> None:
        """Defaults into RAM (and EEPROM if asked), keeping the named fields; motion stops."""
        kept = {n: self.peek(n) for n in keep}
        self._update()
        self._move = None
        for f in self.table.fields.values():
            if eeprom or not f.eeprom:
                self.poke(f.name, f.default)
        for n, v in kept.items():
            self.poke(n, v)
        self._registered = None

    @property
    def dxl_id(self) -> int:
        return self.peek("id")

    def peek(self, name: str) -> int:
        """The field's value (two's complement for a signed field, as Field.from_unsigned decodes it)."""
        slot = self._slots.get(name)
        if slot is None:
            self.table[name]  # ConfigError naming the unknown field
        a, b, _, signed, _ = slot
        return int.from_bytes(self.mem[a:b], "little", signed=signed)

    def poke(self, name: str, value: int) -> None:
        """Store ``value`` in the field (its low bytes, as Field.to_unsigned encodes it)."""
        slot = self._slots.get(name)
        if slot is None:
            self.table[name]  # ConfigError naming the unknown field
        a, b, size, _, mask = slot
        self.mem[a:b] = (int(value) & mask).to_bytes(size, "little")

    # -- faults ---------------------------------------------------------------------------------
    def trip(self, bits: int = HW_OVERLOAD) -> None:
        """Raise a hardware error (default: overload): torque off, alert bit until reboot."""
        self._update()
        self._move = None
        self.poke("hardware_error_status", self.peek("hardware_error_status") | bits)
        self.poke("torque_enable", 0)

    def unplug(self, unplugged: bool = True) -> None:
        """Disconnect (no replies at all) or reconnect this servo."""
        self.online = not unplugged

    def reboot(self) -> None:
        """What the Reboot instruction does: RAM to defaults (clears the hardware error, torque off)."""
        self.reset(eeprom=False)

    # -- motion ---------------------------------------------------------------------------------
    def _profile(self) -> tuple[float, float]:
        """(v ticks/s, a ticks/s²) of the velocity-based profile (e-manual, Profile Velocity(112))."""
        t = self.table
        pv, vlim = self.peek("profile_velocity"), self.peek("velocity_limit")
        units = vlim if pv == 0 or pv > vlim else pv
        v = max(units, 1) * t.velocity_unit_rpm / 60.0 * t.ticks_per_rev
        pa = self.peek("profile_acceleration")
        a = math.inf if pa == 0 else pa * t.acceleration_unit_rpm2 / 3600.0 * t.ticks_per_rev
        return v, a

    def _update(self) -> None:
        now = self.clock.now()
        if self._move is not None:
            t0, start, dist, v, a = self._move
            if now - t0 < self._move_time:  # on the way: the profile's position and velocity now
                s, vel = trapezoid_progress(now - t0, dist, v, a, self._move_time)
                self.horn = start + float(s)
            else:  # arrived
                self.horn, self._move = start + dist, None
                vel = 0.0
                if self.seed is not None:  # at rest: one reading noise until the next move, from (seed, ID, goal)
                    self._rest_noise = float(pose_rng(self.seed, 0, "encoder", self.dxl_id,
                                                      position_key(self.horn)).normal(0.0, self.noise_ticks))
            traj_v = float(vel)
        else:
            traj_v = 0.0
        half = 0.5 * self.backlash_ticks
        self.joint_ticks = min(max(self.joint_ticks, self.horn - half), self.horn + half)
        offset = self.peek("homing_offset")
        if not self.noise_ticks:
            measured = round(self.horn)
        elif self._move is None and self._rest_noise is not None:
            measured = int(round(self.horn + self._rest_noise))
        else:
            measured = int(round(self.horn + self.rng.normal(0.0, self.noise_ticks)))
        self.poke("present_position", measured + offset)
        self.poke("position_trajectory", int(round(self.horn)) + offset)
        vunits = int(round(traj_v * 60.0 / self.table.ticks_per_rev / self.table.velocity_unit_rpm))
        self.poke("present_velocity", vunits)
        self.poke("velocity_trajectory", vunits)
        moving = self._move is not None
        self.poke("moving", int(moving))
        goal = self.peek("goal_position") - offset
        in_pos = abs(goal - self.horn) <= max(self.peek("moving_threshold"), 1)
        ptype = 0
        if moving:
            v, a = self._move[3], self._move[4]
            ptype = 1 if math.isinf(a) else (3 if abs(self._move[2]) >= v * v / a else 2)
        self.poke("moving_status", (int(in_pos and not moving)) | (int(moving) << 1) | (ptype << 4))
        self.poke("realtime_tick", int(now * 1000.0) % 32768)
        self.poke("present_temperature", 30)
        self.poke("present_input_voltage", 120)

    def _start_move(self, goal_ticks: float) -> None:
        self._update()
        v, a = self._profile()
        self._move = (self.clock.now(), self.horn, float(goal_ticks) - self.horn, v, a)
        self._move_time = float(trapezoid_time(self._move[2], v, a))
        self._update()

    # -- instructions ---------------------------------------------------------------------------
    def error_byte(self, error: int = 0) -> int:
        return error | (P.ERR_ALERT if self.peek("hardware_error_status") else 0)

    def read(self, address: int, length: int) -> tuple[int, bytes]:
        if address < 0 or length < 0 or address + length > len(self.mem):
            return P.ERR_ACCESS, b""
        self._update()
        return 0, bytes(self.mem[address:address + length])

    def write(self, address: int, data: bytes) -> int:
        """Write ``data`` at ``address`` with the control table's rules; returns the error number."""
        fields = [f for f in self.table.fields.values() if f.address < address + len(data) and address < f.address + f.size]
        if not fields or fields[0].address != address or fields[-1].address + fields[-1].size != address + len(data):
            return P.ERR_DATA_LENGTH if fields else P.ERR_ACCESS
        torque = self.peek("torque_enable")
        for f in fields:
            if not f.writable:
                return P.ERR_ACCESS
            if f.eeprom and torque and not (f.name == "torque_enable"):
                return P.ERR_ACCESS
        values = {f.name: f.from_unsigned(int.from_bytes(data[f.address - address:f.address - address + f.size], "little"))
                  for f in fields}
        if "goal_position" in values and self.peek("operating_mode") == 3:
            if not self.peek("min_position_limit") <= values["goal_position"] - self.peek("homing_offset") <= self.peek("max_position_limit"):
                return P.ERR_DATA_LIMIT
        if values.get("torque_enable") and self.peek("hardware_error_status"):
            return P.ERR_RESULT_FAIL
        self._update()
        for name, value in values.items():
            self.poke(name, value)
        if "torque_enable" in values:
            if values["torque_enable"]:
                self.poke("goal_position", self.peek("present_position"))  # no jump on torque-on
            else:
                self._move = None
        if "goal_position" in values and self.peek("torque_enable"):
            self._start_move(values["goal_position"] - self.peek("homing_offset"))
        if "operating_mode" in values:  # e-manual: switching mode resets the profile
            self.poke("profile_velocity", 0)
            self.poke("profile_acceleration", 0)
        return 0


class ServoBus(PtyServer):
    """Several :class:`SimServo` on one Protocol 2.0 bus, served on a pseudo-terminal.

    Parameters
    ----------
    servos : mapping id -> model name (e.g. ``{1: "XM540-W270", 2: "XM430-W350"}``), or a sequence of
        ``(id, model)`` / ``(id, model, baud)`` — one entry per physical servo, so two servos may share an ID
        (two factory servos: both ID 1)
    clock : Clock shared with the host code (``sim.clock.SimClock`` in tests; RealClock by default)
    seed : seed of the position noise
    noise_ticks, backlash_ticks : standard deviation of the position noise and the play, in ticks
    faults : link faults applied to every reply
    baud : the Baud Rate every servo without its own is set to. With a baud here or per servo, a servo hears
        and answers only while the line runs at its Baud Rate(8) (the host's rate is read from the pty's
        termios, :meth:`PtyServer.line_baud`): writing Baud Rate changes the rate it listens at, a factory
        reset brings it back to 57,600. ``None`` and no per-servo baud: the line's rate is not checked (every
        servo answers at any rate, the emulator before provisioning existed).

    Servos sharing an ID and a rate answer the same request together: their status packets collide on the
    wire (emulated as the bitwise AND of the packets, as overlapping UART frames on an open-drain line give;
    identical packets pass intact, different ones fail their CRC). Sync/bulk reads take the first of them.
    """

    def __init__(self, servos, clock=None, *, seed: int = 0, noise_ticks: float = 0.3, backlash_ticks: float = 0.0,
                 faults: LinkFaults | None = None, positions=None, baud: int | None = None):
        super().__init__("servo-bus", faults)
        self.clock = clock or RealClock()
        positions = positions or {}
        specs = [(i, m) for i, m in servos.items()] if isinstance(servos, Mapping) else [tuple(u) for u in servos]
        #: every physical servo on the bus, in the order given
        self.units: list[SimServo] = []
        seen: set[int] = set()
        for k, spec in enumerate(specs):
            i, model = int(spec[0]), str(spec[1])
            rate = spec[2] if len(spec) > 2 else baud
            # the first servo of an ID keeps the stream it always had (same noise as before); a second one its own
            rng = pose_rng(seed, SETUP, "encoder", i) if i not in seen else pose_rng(seed, SETUP, "encoder", i, k)
            seen.add(i)
            s = SimServo(i, model, self.clock, rng=rng, noise_ticks=noise_ticks, backlash_ticks=backlash_ticks,
                         position=positions.get(i, 2048.0), seed=seed)
            if rate is not None:
                s.poke("baud_rate", s.table.baud_code(int(rate)))
            self.units.append(s)
        #: the line's rate is checked against each servo's Baud Rate (see the class docstring)
        self.check_baud = baud is not None or any(len(spec) > 2 for spec in specs)
        self._by_id: dict[int, list[SimServo]] = {}
        self._reindex()
        self._parser = P.Parser()
        self._lock = threading.RLock()
        self.packets = 0  #: instruction packets handled

    @property
    def servos(self) -> dict[int, SimServo]:
        """``{id: servo}`` by current ID (the first servo of an ID shared by several)."""
        return {i: group[0] for i, group in self._by_id.items()}

    def servo(self, dxl_id: int) -> SimServo:
        return self._by_id[dxl_id][0]

    def _reindex(self) -> None:
        """Group the servos by their current ID (after an ID write or a factory reset)."""
        by_id: dict[int, list[SimServo]] = {}
        for s in self.units:
            by_id.setdefault(s.dxl_id, []).append(s)
        self._by_id = dict(sorted(by_id.items()))

    @staticmethod
    def baud_of(servo: SimServo) -> int | None:
        """The rate (bits/s) ``servo`` listens at: its Baud Rate(8) through the control table."""
        return servo.table.baud_rates.get(servo.peek("baud_rate"))

    @contextlib.contextmanager
    def atomic(self):
        """Hold the bus lock: no packet is handled while the block runs (read or change several servos
        consistently from another thread, e.g. the rig wiring reading every joint at one instant)."""
        with self._lock:
            yield self

    def power_cycle(self) -> None:
        """Switch the bus power off and on: every servo's RAM back to defaults (EEPROM kept)."""
        with self._lock:
            for s in self.units:
                s.reset(eeprom=False)
                s.online = True

    # -- packet handling ------------------------------------------------------------------------
    def on_bytes(self, data: bytes) -> None:
        with self._lock:
            line = self.line_baud() if self.check_baud else None
            for pkt in self._parser.feed(data):
                self.packets += 1
                self._line = line
                self._handle(pkt)
                if pkt.inst in _CHANGES_ID:
                    self._reindex()

    _line: int | None = None

    def _hears(self, s: SimServo) -> bool:
        """``s`` is powered, connected and listening at the line's rate."""
        return s.online and (self._line is None or self.baud_of(s) == self._line)

    def _listeners(self, dxl_id: int) -> list[SimServo]:
        return [s for s in self._by_id.get(dxl_id, ()) if self._hears(s)]

    def _live(self, dxl_id: int) -> SimServo | None:
        group = self._listeners(dxl_id)
        return group[0] if group else None

    @staticmethod
    def reframe(reply: bytes, rng) -> bytes | None:
        """The ``short`` link fault: the same status packet with 1..all of its parameter bytes removed and a
        *valid* CRC (only a host that checks the length against its request notices)."""
        pkts = P.Parser().feed(reply)
        if len(pkts) != 1 or pkts[0].inst != P.INST_STATUS or len(pkts[0].params) < 2:
            return None
        error, params = pkts[0].params[0], pkts[0].params[1:]
        keep = int(rng.integers(0, len(params)))
        return P.status(pkts[0].dxl_id, error, params[:keep])

    @staticmethod
    def _status(s: SimServo, error: int, params: bytes = b"", *, kind: str = "other") -> bytes | None:
        """``s``'s status packet, or None where its Status Return Level says it does not answer."""
        level = s.peek("status_return_level")
        if kind == "ping" or level >= 2 or (level == 1 and kind == "read"):
            return P.status(s.dxl_id, s.error_byte(error), params)
        return None

    def _reply(self, s: SimServo, error: int, params: bytes = b"", *, kind: str = "other") -> None:
        reply = self._status(s, error, params, kind=kind)
        if reply is not None:
            self.send(reply)

    def _send_together(self, replies: list[bytes]) -> None:
        """Status packets sent at the same instant by servos sharing an ID: one packet if alone, else the
        collision (bytewise AND, padded with idle-line 0xFF; class docstring)."""
        replies = [r for r in replies if r is not None]
        if not replies:
            return
        if len(replies) == 1:
            self.send(replies[0])
            return
        n = max(len(r) for r in replies)
        out = bytearray(b"\xff" * n)
        for r in replies:
            for k, b in enumerate(r):
                out[k] &= b
        self.send(bytes(out))

    def _handle(self, pkt: P.Packet) -> None:
        bid = pkt.dxl_id
        if not pkt.crc_ok:
            self._send_together([self._status(s, P.ERR_CRC) for s in self._listeners(bid)])
            return
        inst, p = pkt.inst, pkt.params
        u16 = lambda i: p[i] | (p[i + 1] << 8)  # noqa: E731
        if inst == P.INST_PING:
            targets = sorted(self._by_id) if bid == P.BROADCAST_ID else [bid]
            for i in targets:  # a broadcast ping: each ID in turn; servos sharing an ID collide
                self._send_together([self._status(s, 0, s.table.model_number.to_bytes(2, "little")
                                                  + bytes([s.peek("firmware_version")]), kind="ping")
                                     for s in self._listeners(i)])
            return
        if inst in (P.INST_SYNC_READ, P.INST_SYNC_WRITE, P.INST_BULK_READ, P.INST_BULK_WRITE):
            self._group(inst, p, u16)
            return
        if bid == P.BROADCAST_ID:
            targets = [s for s in self.units if self._hears(s)]
        else:
            targets = self._listeners(bid)
        reply = bid != P.BROADCAST_ID
        replies: list[bytes | None] = []
        for s in targets:
            if inst == P.INST_READ and len(p) == 4:
                err, data = s.read(u16(0), u16(2))
                replies.append(self._status(s, err, data, kind="read"))
            elif inst in (P.INST_WRITE, P.INST_REG_WRITE) and len(p) >= 3:
                if inst == P.INST_WRITE:
                    err = s.write(u16(0), p[2:])
                else:
                    s._registered, err = (u16(0), p[2:]), 0
                    s.poke("registered_instruction", 1)
                replies.append(self._status(s, err))
            elif inst == P.INST_ACTION:
                if s._registered is not None:
                    s.write(*s._registered)
                    s._registered = None
                    s.poke("registered_instruction", 0)
                replies.append(self._status(s, 0))
            elif inst == P.INST_REBOOT:
                replies.append(self._status(s, 0))
                s.reboot()
            elif inst == P.INST_FACTORY_RESET and len(p) == 1:
                keep = {0xFF: (), 0x01: ("id",), 0x02: ("id", "baud_rate")}.get(p[0])
                if keep is None:
                    replies.append(self._status(s, P.ERR_DATA_RANGE))
                    continue
                if not reply and not keep:  # e-manual: firmware v42+ ignores a broadcast reset-all
                    continue
                replies.append(self._status(s, 0))  # the status goes out first, at the old ID and rate
                s.reset(eeprom=True, keep=keep)  # reset-all: ID 1, 57,600 baud (the table's defaults)
            elif inst == P.INST_CLEAR:
                replies.append(self._status(s, 0))
            else:
                replies.append(self._status(s, P.ERR_INSTRUCTION))
        if reply:
            self._send_together(replies)

    def _group(self, inst: int, p: bytes, u16) -> None:
        if inst in (P.INST_SYNC_READ, P.INST_SYNC_WRITE):
            if len(p) < 4:
                return
            addr, length = u16(0), u16(2)
            if inst == P.INST_SYNC_READ:
                for i in p[4:]:  # reply in the order the IDs were listed
                    s = self._live(i)
                    if s is not None:
                        err, data = s.read(addr, length)
                        self._reply(s, err, data, kind="read")
            else:
                step = 1 + length
                for k in range(4, len(p) - step + 1, step):
                    s = self._live(p[k])
                    if s is not None:
                        s.write(addr, p[k + 1:k + step])
            return
        if inst == P.INST_BULK_READ:
            for k in range(0, len(p) - 4, 5):
                s = self._live(p[k])
                if s is not None:
                    err, data = s.read(u16(k + 1), u16(k + 3))
                    self._reply(s, err, data, kind="read")
            return
        k = 0  # bulk write: [id, addr, len, data] ...
        while k + 5 <= len(p):
            length = u16(k + 3)
            s = self._live(p[k])
            if s is not None:
                s.write(u16(k + 1), p[k + 5:k + 5 + length])
            k += 5 + length


def parse_servos(ids: str | None = None, model: str = "XM430-W350", baud: str | None = None, rig: str | None = None,
                 extra=()) -> list[tuple]:
    """The servos of ``python -m sim.servo_bus``: ``[(id, model, baud | None), ...]``.

    ``ids`` ``"1,2,3,4"``; ``model`` one name for every ID or per ID ``"1=XM540-W270,2=XM430-W350"`` (an ID named
    there and not in ``ids`` is added); ``baud`` one rate for all or per ID ``"1=57600,2=1000000"``; ``rig`` a rig
    file or shipped name: its joints' IDs and models at its [bus] baud (``baud`` overrides it: a rig's servos still
    at the factory rate); ``extra`` more servos as ``"ID:MODEL[@BAUD]"`` (an ID may repeat: two servos answering
    to one ID)."""
    from gonio.errors import ConfigError

    def pairs(text, what, conv):
        out = {}
        for part in text.split(","):
            i, sep, v = part.partition("=")
            try:
                if not sep:
                    raise ValueError
                out[int(i)] = conv(v.strip())
            except ValueError:
                raise ConfigError.field(f"--{what}", what, text, f"bad pair {part!r}: expected ID=VALUE,...") from None
        return out

    per_model = pairs(model, "model", str) if "=" in model else {}
    per_baud = pairs(baud, "baud", int) if baud and "=" in baud else {}
    try:
        all_baud = int(baud) if baud and "=" not in baud else None
    except ValueError:
        raise ConfigError.field("--baud", "baud", baud, "expected a rate (57600) or ID=RATE pairs") from None
    units: dict[int, list] = {}
    if rig is not None:
        from gonio.rig.kinematics import load_rig

        r = load_rig(rig)
        units = {j.servo_id: [j.model, r.baud] for j in r.joints}
    for i in [int(x) for x in (ids or "").split(",") if x.strip()] + list(per_model) + list(per_baud):
        units.setdefault(i, [None, None])
    out = []
    for i, (m, b) in sorted(units.items()):
        m = per_model.get(i) or m or (model if not per_model else "XM430-W350")
        b = per_baud.get(i, all_baud if all_baud is not None else b)
        out.append((i, m, b))
    for spec in extra:
        head, _, rate = spec.partition("@")
        i, _, m = head.partition(":")
        try:
            out.append((int(i), m or "XM430-W350", int(rate) if rate else all_baud))
        except ValueError:
            raise ConfigError.field("--servo", "servo", spec, "expected ID:MODEL[@BAUD], e.g. 1:XM540-W270@57600") from None
    for _, m, b in out:
        table = load_control_table(m)  # ConfigError naming an unknown model
        if b is not None:
            table.baud_code(b)  # ConfigError naming a rate the model does not have
    return out


def main(argv=None) -> int:  # pragma: no cover - interactive tool
    import argparse
    import sys

    from gonio.errors import GonioError

    ap = argparse.ArgumentParser(prog="python -m sim.servo_bus", description="Serve emulated Dynamixel servos on a pty.")
    ap.add_argument("--ids", help="comma-separated IDs (default 1,2,3,4 unless --rig, --model ID=... or --servo)")
    ap.add_argument("--model", default="XM430-W350", help="one model for every ID, or per ID: 1=XM540-W270,2=XM430-W350")
    ap.add_argument("--baud", help="the servos' baud rate (one, or per ID: 1=57600,2=1000000); they answer only at "
                                   "it. Default: the rig's [bus] baud with --rig, else any rate (not checked)")
    ap.add_argument("--rig", help="a rig file or shipped name: its joints' IDs and models at its [bus] baud (e.g. "
                                  "the shipped mixed XM540/XM430 rig: --rig default)")
    ap.add_argument("--servo", action="append", default=[], metavar="ID:MODEL[@BAUD]",
                    help="one more servo (repeatable; an ID may repeat: e.g. two factory servos --servo 1:XM540-W270@57600 "
                         "--servo 1:XM430-W350@57600)")
    ap.add_argument("--seconds", type=float, default=3600.0, help="serve this long, then exit")
    args = ap.parse_args(argv)
    ids = args.ids
    if ids is None and args.rig is None and "=" not in args.model and not args.servo and "=" not in (args.baud or ""):
        ids = "1,2,3,4"
    try:
        servos = parse_servos(ids, args.model, args.baud, args.rig, args.servo)
    except GonioError as exc:
        print(f"python -m sim.servo_bus: {exc}", file=sys.stderr)
        return 2
    # a servo without a rate of its own, when others have one, listens at its register's factory 57,600
    bus = ServoBus([(i, m, b) if b is not None else (i, m) for i, m, b in servos])
    print("; ".join(f"ID {i} {m}" + (f" @ {b}" if b else "") for i, m, b in servos), file=sys.stderr)
    bus.serve_interactively(args.seconds)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
