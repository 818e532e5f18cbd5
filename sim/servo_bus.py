"""A bus of emulated Dynamixel servos speaking Protocol 2.0 on a pseudo-terminal.

The host opens :attr:`ServoBus.path` with the real ``dynamixel-sdk``; nothing in gonio knows it is
simulated. What is emulated (ROBOTIS e-manual, X series / Protocol 2.0):

* packets: header, byte stuffing, CRC-16 (:mod:`sim.dxl_packet`); ping, broadcast ping, read, write,
  reg write / action, sync read / write, bulk read / write, reboot, factory reset, clear; status return
  level; a packet with a bad CRC addressed to a servo gets a status with the CRC error;
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

Run ``python -m sim.servo_bus --ids 1,2,3,4`` to serve a bus on real time for the lab CLI.
"""

from __future__ import annotations

import contextlib
import math
import threading
from typing import Iterable

import numpy as np

from gonio.rig.clock import RealClock
from gonio.rig.control_table import ControlTable, load_control_table
from gonio.rig.kinematics import trapezoid_progress, trapezoid_time
from sim import dxl_packet as P
from sim.faults import LinkFaults
from sim.pty import PtyServer
from sim.seeding import SETUP, pose_rng, position_key

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
    servos : mapping id -> model name (e.g. ``{1: "XM540-W270", 2: "XM430-W350"}``)
    clock : Clock shared with the host code (``sim.clock.SimClock`` in tests; RealClock by default)
    seed : seed of the position noise
    noise_ticks, backlash_ticks : standard deviation of the position noise and the play, in ticks
    faults : link faults applied to every reply
    """

    def __init__(self, servos, clock=None, *, seed: int = 0, noise_ticks: float = 0.3, backlash_ticks: float = 0.0,
                 faults: LinkFaults | None = None, positions=None):
        super().__init__("servo-bus", faults)
        self.clock = clock or RealClock()
        positions = positions or {}
        self.servos = {int(i): SimServo(int(i), m, self.clock, rng=pose_rng(seed, SETUP, "encoder", int(i)),
                                        noise_ticks=noise_ticks, backlash_ticks=backlash_ticks,
                                        position=positions.get(i, 2048.0), seed=seed)
                       for i, m in dict(servos).items()}
        self._parser = P.Parser()
        self._lock = threading.RLock()
        self.packets = 0  #: instruction packets handled

    def servo(self, dxl_id: int) -> SimServo:
        return self.servos[dxl_id]

    @contextlib.contextmanager
    def atomic(self):
        """Hold the bus lock: no packet is handled while the block runs (read or change several servos
        consistently from another thread, e.g. the rig wiring reading every joint at one instant)."""
        with self._lock:
            yield self

    def power_cycle(self) -> None:
        """Switch the bus power off and on: every servo's RAM back to defaults (EEPROM kept)."""
        with self._lock:
            for s in self.servos.values():
                s.reset(eeprom=False)
                s.online = True

    # -- packet handling ------------------------------------------------------------------------
    def on_bytes(self, data: bytes) -> None:
        with self._lock:
            for pkt in self._parser.feed(data):
                self.packets += 1
                self._handle(pkt)

    def _live(self, dxl_id: int) -> SimServo | None:
        s = self.servos.get(dxl_id)
        return s if s is not None and s.online else None

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

    def _reply(self, s: SimServo, error: int, params: bytes = b"", *, kind: str = "other") -> None:
        level = s.peek("status_return_level")
        if kind == "ping" or level >= 2 or (level == 1 and kind == "read"):
            self.send(P.status(s.dxl_id, s.error_byte(error), params))

    def _handle(self, pkt: P.Packet) -> None:
        bid = pkt.dxl_id
        if not pkt.crc_ok:
            s = self._live(bid)
            if s is not None:
                self._reply(s, P.ERR_CRC)
            return
        inst, p = pkt.inst, pkt.params
        u16 = lambda i: p[i] | (p[i + 1] << 8)  # noqa: E731
        if inst == P.INST_PING:
            targets = sorted(self.servos) if bid == P.BROADCAST_ID else [bid]
            for i in targets:
                s = self._live(i)
                if s is not None:
                    t = s.table
                    self._reply(s, 0, t.model_number.to_bytes(2, "little") + bytes([s.peek("firmware_version")]), kind="ping")
            return
        if inst in (P.INST_SYNC_READ, P.INST_SYNC_WRITE, P.INST_BULK_READ, P.INST_BULK_WRITE):
            self._group(inst, p, u16)
            return
        targets = [s for s in self.servos.values() if s.online] if bid == P.BROADCAST_ID else [self._live(bid)]
        for s in targets:
            if s is None:
                continue
            reply = bid != P.BROADCAST_ID
            if inst == P.INST_READ and len(p) == 4:
                err, data = s.read(u16(0), u16(2))
                if reply:
                    self._reply(s, err, data, kind="read")
            elif inst in (P.INST_WRITE, P.INST_REG_WRITE) and len(p) >= 3:
                if inst == P.INST_WRITE:
                    err = s.write(u16(0), p[2:])
                else:
                    s._registered, err = (u16(0), p[2:]), 0
                    s.poke("registered_instruction", 1)
                if reply:
                    self._reply(s, err)
            elif inst == P.INST_ACTION:
                if s._registered is not None:
                    s.write(*s._registered)
                    s._registered = None
                    s.poke("registered_instruction", 0)
                if reply:
                    self._reply(s, 0)
            elif inst == P.INST_REBOOT:
                if reply:
                    self._reply(s, 0)
                s.reboot()
            elif inst == P.INST_FACTORY_RESET and len(p) == 1:
                keep = {0xFF: (), 0x01: ("id",), 0x02: ("id", "baud_rate")}.get(p[0])
                if keep is None:
                    if reply:
                        self._reply(s, P.ERR_DATA_RANGE)
                    continue
                if reply:
                    self._reply(s, 0)
                if "id" not in keep:  # the e-manual: reset-all sets ID 1 (we keep our key by remapping)
                    old = s.dxl_id
                    s.reset(eeprom=True, keep=keep)
                    self.servos.pop(old, None)
                    self.servos[s.dxl_id] = s
                else:
                    s.reset(eeprom=True, keep=keep)
            elif inst == P.INST_CLEAR:
                if reply:
                    self._reply(s, 0)
            elif reply:
                self._reply(s, P.ERR_INSTRUCTION)

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


def main(argv=None) -> int:  # pragma: no cover - interactive tool
    import argparse

    ap = argparse.ArgumentParser(prog="python -m sim.servo_bus", description="Serve emulated Dynamixel servos on a pty.")
    ap.add_argument("--ids", default="1,2,3,4", help="comma-separated IDs")
    ap.add_argument("--model", default="XM430-W350")
    ap.add_argument("--seconds", type=float, default=3600.0, help="serve this long, then exit")
    args = ap.parse_args(argv)
    ids = [int(x) for x in args.ids.split(",") if x]
    ServoBus({i: args.model for i in ids}).serve_interactively(args.seconds)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
