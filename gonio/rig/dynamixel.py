"""Dynamixel servos (Protocol 2.0) through the real ``dynamixel-sdk``: a guarded bus and the rig's axes.

:class:`DynamixelBus` wraps one port: ``PortHandler`` (this module's, see below) / ``PacketHandler(2.0)`` / ``GroupSyncWrite`` /
``GroupSyncRead`` / ``GroupBulkRead``, with

* a lock around every transaction (the SDK's ``is_using`` flag is not a lock, FIELD-NOTES.md);
* bounded retries of timeouts and corrupted replies; after each failure it waits for a late reply
  (up to ``late_reply_window_s``) and clears the port, because the SDK takes a late reply as the
  answer to the next request when the IDs match (FIELD-NOTES.md);
* the packet timeout's latency term set per port (``latency_timer_ms``, the SDK's module-global
  ``LATENCY_TIMER`` is left alone), so a loaded CI machine can use a generous value;
* no busy-polling while a reply is awaited: the SDK calls ``readPort`` in a tight loop until its
  timeout; here ``readPort`` blocks in ``select`` (until the packet timeout) when nothing has
  arrived, so the waiting thread gives up the CPU and the GIL — on a loaded machine the device side (a
  USB adapter's driver, or the simulator's servo thread in the same process) then answers within the
  timeout instead of being starved by the loop that waits for it;
* typed errors: :class:`~gonio.errors.HardwareTimeout`, :class:`~gonio.errors.ChecksumError`,
  :class:`~gonio.errors.ServoAlarm` (Hardware Error Status bits decoded), :class:`~gonio.errors.HardwareError`.

:class:`DynamixelAxes` implements :class:`gonio.rig.interfaces.Axes` on such a bus: joint radians ↔
ticks (``ticks = zero_offset/360·4096 + direction · gear_ratio · θ · 4096/2π``), configuration written
before torque-on (operating mode, homing offset, position limits, profile velocity/acceleration from
the joint's speed limits), one ``GroupSyncWrite`` per move, settling polled with ``GroupSyncRead``
on the given :class:`~gonio.rig.interfaces.Clock`, the *measured* angles returned, and the final
approach to every target from one side (backlash). Alarms raise :class:`ServoAlarm` unless
``auto_recover`` allows a reboot; a servo found with torque off and no alarm (power cycle, brown-out)
gets its RAM settings written again and the move is re-issued, once per move.
"""

from __future__ import annotations

import math
import select
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Mapping, Sequence

import dynamixel_sdk as sdk

from gonio.errors import ChecksumError, ConfigError, HardwareError, HardwareTimeout, ServoAlarm
from gonio.rig.control_table import BAUD_RATES, ControlTable, load_control_table, table_for_model_number
from gonio.rig.kinematics import trapezoid_time

__all__ = ["DynamixelBus", "DynamixelAxes", "AxisConfig", "describe_hardware_error", "BAUD_RATES", "MAX_ID"]

#: Largest servo ID of Protocol 2.0 (253 is reserved, 254 is the broadcast ID).
MAX_ID = 252
_HW_BITS = {0x01: "input voltage", 0x04: "overheating", 0x08: "motor encoder", 0x10: "electrical shock",
            0x20: "overload"}
_STATUS_ERRORS = {1: "result fail", 2: "instruction error", 3: "CRC error", 4: "data range error",
                  5: "data length error", 6: "data limit error", 7: "access error"}
_RETRYABLE = (sdk.COMM_RX_TIMEOUT, sdk.COMM_RX_CORRUPT, sdk.COMM_RX_FAIL, sdk.COMM_TX_FAIL, sdk.COMM_PORT_BUSY)


def describe_hardware_error(bits: int) -> str:
    """Names of the Hardware Error Status(70) bits set in ``bits`` (e-manual, "Shutdown(63)")."""
    names = [name for bit, name in _HW_BITS.items() if bits & bit]
    return ", ".join(names) or f"unknown (0x{bits:02X})"


#: Bytes of a status packet around its parameters: header 4 + ID + LEN 2 + INST + ERR + CRC 2 (e-manual,
#: "Protocol 2.0 Status Packet").
_STATUS_OVERHEAD = 11
_INST_STATUS = 0x55


def _status_ok(rxpacket, dxl_id: int, n_params: int) -> bool:
    """A status packet (already unstuffed, CRC checked by the SDK) answers a request to ``dxl_id`` that
    expects ``n_params`` parameter bytes: right ID, instruction 0x55, length field and size consistent."""
    if rxpacket is None or len(rxpacket) != _STATUS_OVERHEAD + n_params:
        return False
    length = rxpacket[sdk.PKT_LENGTH_L] | (rxpacket[sdk.PKT_LENGTH_H] << 8)
    return rxpacket[sdk.PKT_ID] == dxl_id and rxpacket[sdk.PKT_INSTRUCTION] == _INST_STATUS and length == n_params + 4


def _crc_table() -> tuple[int, ...]:
    """Table of the Protocol 2.0 CRC-16 (poly 0x8005, init 0, not reflected; e-manual, "Protocol 2.0 CRC"):
    the same 256 values as the table the SDK's ``updateCRC`` spells out (and rebuilds on every call)."""
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


class _CheckedPacketHandler(sdk.Protocol2PacketHandler):
    """The SDK's Protocol 2.0 handler, with every status packet checked before a value is taken from it.

    The SDK checks the CRC and the ID, but not that the packet carries the number of parameter bytes
    the request asked for: a short status packet with a valid CRC gives a value assembled from the CRC
    bytes, or an ``IndexError`` in the SDK. Here such a packet is ``COMM_RX_CORRUPT`` (retried by
    :meth:`DynamixelBus.transact`), so no value is ever built from a malformed reply.
    """

    def updateCRC(self, crc_accum, data_blk_ptr, data_blk_size):  # noqa: N802 - SDK name
        """The SDK's CRC-16 (same algorithm, same result) from a table built once instead of on every call
        (the SDK builds its 256-entry list each time: a third of the CPU of a short transaction)."""
        table = _CRC_TABLE
        for j in range(data_blk_size):
            crc_accum = ((crc_accum << 8) ^ table[((crc_accum >> 8) ^ data_blk_ptr[j]) & 0xFF]) & 0xFFFF
        return crc_accum

    def removeStuffing(self, packet):  # noqa: N802 - SDK name
        """The SDK's unstuffing, skipped when nothing is stuffed (the SDK's byte loop looks for ``FF FF FD FD``
        in the bytes from the length field to the first CRC byte, and without one it leaves the packet as it
        is); after it, the packet is cut to its unstuffed length: the SDK moves the bytes forward and updates
        the length field but leaves the list as long as it was, and the leftover bytes would fail the size
        check of :func:`_status_ok` (a reply whose parameters contain ``FF FF FD`` taken as corrupted)."""
        n = packet[sdk.PKT_LENGTH_L] | (packet[sdk.PKT_LENGTH_H] << 8)
        if b"\xff\xff\xfd\xfd" not in bytes(packet[sdk.PKT_INSTRUCTION - 2:sdk.PKT_INSTRUCTION + n - 1]):
            return packet
        packet = super().removeStuffing(packet)
        del packet[sdk.PKT_LENGTH_H + 1 + (packet[sdk.PKT_LENGTH_L] | (packet[sdk.PKT_LENGTH_H] << 8)):]
        return packet

    def readRx(self, port, dxl_id, length):  # noqa: N802 - SDK name; used by GroupSyncRead
        while True:
            rxpacket, result = self.rxPacket(port, False)
            if result != sdk.COMM_SUCCESS or rxpacket[sdk.PKT_ID] == dxl_id:
                break
        if result != sdk.COMM_SUCCESS:
            return [], result, 0
        if not _status_ok(rxpacket, dxl_id, length):
            return [], sdk.COMM_RX_CORRUPT, 0
        return list(rxpacket[sdk.PKT_PARAMETER0 + 1: sdk.PKT_PARAMETER0 + 1 + length]), result, rxpacket[sdk.PKT_ERROR]

    def readTxRx(self, port, dxl_id, address, length):  # noqa: N802 - SDK name
        data, result, error = super().readTxRx(port, dxl_id, address, length)
        if result == sdk.COMM_SUCCESS and len(data) != length:
            return [], sdk.COMM_RX_CORRUPT, 0
        return data, result, error

    def txRxPacket(self, port, txpacket):  # noqa: N802 - SDK name
        rxpacket, result, error = super().txRxPacket(port, txpacket)
        if result != sdk.COMM_SUCCESS or rxpacket is None:
            return rxpacket, result, error
        inst = txpacket[sdk.PKT_INSTRUCTION]
        expect = {sdk.INST_PING: 3}.get(inst, 0)
        if inst == sdk.INST_READ:
            expect = txpacket[sdk.PKT_PARAMETER0 + 2] | (txpacket[sdk.PKT_PARAMETER0 + 3] << 8)
        if not _status_ok(rxpacket, txpacket[sdk.PKT_ID], expect):
            return None, sdk.COMM_RX_CORRUPT, 0
        return rxpacket, result, error


class PortHandler(sdk.PortHandler):
    """``PortHandler`` whose packet timeout uses this port's latency timer instead of the module global,
    and whose ``readPort`` waits for bytes in ``select`` instead of returning at once (module docstring)."""

    def __init__(self, name: str, latency_timer_ms: float):
        super().__init__(name)
        self.latency_timer_ms = float(latency_timer_ms)

    def getCFlagBaud(self, baudrate):  # noqa: N802 - SDK name
        """The SDK's whitelist plus 4,500,000 (X series Baud Rate(8) = 7), set as a custom rate by pyserial."""
        return baudrate if baudrate in BAUD_RATES else -1

    def setPacketTimeout(self, packet_length):  # noqa: N802 - SDK name
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + self.latency_timer_ms * 2.0 + 2.0

    def readPort(self, length):  # noqa: N802 - SDK name
        """The bytes available (at most ``length``); when none are, first wait in the kernel for the next
        byte until the packet timeout. The SDK's receive loops call this back to back until the packet
        is complete or the timeout passes: with the SDK's non-blocking read that loop spins (one core at
        100 % per transaction, and, in one process with an emulator, the emulator starved of the
        interpreter lock); waiting in ``select`` gives the same bytes at the same deadlines."""
        data = self.ser.read(length)
        if data or length <= 0:
            return data
        left = (self.packet_timeout - self.getTimeSinceStart()) / 1000.0
        fileno = getattr(self.ser, "fileno", None)
        if left > 0 and fileno is not None:
            try:
                select.select([fileno()], [], [], left)
            except (OSError, ValueError):  # closed underneath, or no selectable descriptor: the SDK's loop decides
                return data
            data = self.ser.read(length)
        return data


class DynamixelBus:
    """One Protocol 2.0 bus on a serial port, guarded and retried (see the module docstring).

    Parameters
    ----------
    port : serial device (``/dev/ttyUSB0``, or an emulator's ``/dev/pts/N``)
    baud : one of :data:`BAUD_RATES`
    latency_timer_ms : latency term of the SDK's reply timeout (USB adapters default to 16 ms; use
        more on loaded machines)
    retries : extra attempts after a timeout or corrupted reply
    late_reply_window_s : after a failure, how long to wait for a late reply before clearing the port
    """

    def __init__(self, port: str, baud: int = 1_000_000, *, latency_timer_ms: float = 16.0, retries: int = 3,
                 late_reply_window_s: float = 0.3):
        if baud not in BAUD_RATES:
            raise ConfigError.field("--baud", "baud", baud, f"not supported; use one of {', '.join(map(str, BAUD_RATES))}")
        self.port_name = port
        self.baud = baud
        self.retries = int(retries)
        self.late_reply_window_s = float(late_reply_window_s)
        self._port = PortHandler(port, latency_timer_ms)
        self._ph = _CheckedPacketHandler()
        self._lock = threading.RLock()
        self._sync_reads: dict[tuple, sdk.GroupSyncRead] = {}
        self._block_fields: dict[tuple, list] = {}  # (model, address, length) -> [(name, start, end, signed)]
        self.stats = {"transactions": 0, "retries": 0, "recoveries": 0}

    # -- lifecycle ------------------------------------------------------------------------------
    def open(self) -> "DynamixelBus":
        try:
            ok = self._port.setBaudRate(self.baud)
        except Exception as exc:  # serial.SerialException, OSError
            raise HardwareError(f"cannot open serial port {self.port_name}: {getattr(exc, 'strerror', None) or exc}",
                                device=self.port_name) from None
        if not ok:
            raise HardwareError(f"cannot open serial port {self.port_name} at {self.baud} baud", device=self.port_name)
        return self

    def close(self) -> None:
        with self._lock:
            if self._port.is_open:
                self._port.closePort()

    def __enter__(self):
        return self.open()

    def __exit__(self, *exc):
        self.close()

    # -- the guarded transaction ----------------------------------------------------------------
    def _recover(self) -> None:
        """Wait for a late reply (real time: it is the serial link), then drop whatever arrived."""
        self.stats["recoveries"] += 1
        deadline = time.monotonic() + self.late_reply_window_s
        while time.monotonic() < deadline:
            if self._port.getBytesAvailable():
                time.sleep(0.002 + 2 * self._port.latency_timer_ms / 1000.0)  # let the rest of it arrive
                break
            time.sleep(0.001)
        self._port.clearPort()
        self._port.is_using = False

    def _flush_stale(self) -> None:
        """Drop bytes that arrived between transactions (a reply later than the recovery window): the SDK
        would take them as the answer to the next request."""
        if self._port.getBytesAvailable():
            self.stats["stale_flushes"] = self.stats.get("stale_flushes", 0) + 1
            self._port.clearPort()

    def transact(self, what: str, dxl_id: int | None, fn: Callable[[], tuple], *, alarm_ok: bool = False):
        """Run ``fn`` (an SDK call returning ``(..., result, error)`` or ``(..., result)``) under the
        lock with retries; returns ``fn``'s output. Alarms raise :class:`ServoAlarm` unless ``alarm_ok``."""
        if dxl_id is not None and (isinstance(dxl_id, bool) or not isinstance(dxl_id, int) or not 0 <= dxl_id <= MAX_ID):
            raise ConfigError.field(None, "servo id", dxl_id, f"must be an integer in 0..{MAX_ID}")
        try:
            return self._transact(what, dxl_id, fn, alarm_ok)
        except OSError as exc:  # pyserial's SerialException too: the adapter was unplugged or lost power
            raise self._link_lost(what, dxl_id, exc) from None

    def _link_lost(self, what: str, dxl_id: int | None, exc: OSError) -> HardwareError:
        return HardwareError(f"{self._who(dxl_id)}: {what}: serial link lost ({exc}); the USB adapter unplugged "
                             "or the bus powered off?", device=self.port_name)

    def _transact(self, what: str, dxl_id: int | None, fn: Callable[[], tuple], alarm_ok: bool):
        last = sdk.COMM_RX_TIMEOUT
        for attempt in range(self.retries + 1):
            with self._lock:
                if not self._port.is_open:
                    raise HardwareError(f"{self.port_name}: port is not open", device=self.port_name)
                self._flush_stale()
                try:
                    out = fn()
                    result, error = self._result(out)
                except (IndexError, ValueError, TypeError, KeyError):  # the SDK choking on a malformed reply
                    out, result, error = None, sdk.COMM_RX_CORRUPT, 0
                self.stats["transactions"] += 1
                if result in _RETRYABLE:
                    last = result
                    self.stats["retries"] += attempt < self.retries
                    self._recover()
                    continue
            if result != sdk.COMM_SUCCESS:
                raise HardwareError(f"{self._who(dxl_id)}: {what}: {self._ph.getTxRxResult(result)}",
                                    device=self.port_name, code=result)
            if error & 0x7F == 3:  # the servo saw a corrupted instruction: retry
                last = sdk.COMM_RX_CORRUPT
                self.stats["retries"] += attempt < self.retries
                continue
            if error & 0x7F:
                raise HardwareError(f"{self._who(dxl_id)}: {what}: {_STATUS_ERRORS.get(error & 0x7F, error)}",
                                    device=self.port_name, code=error & 0x7F)
            if error & 0x80 and not alarm_ok:
                self.raise_alarm(dxl_id)
            return out
        cls = ChecksumError if last == sdk.COMM_RX_CORRUPT else HardwareTimeout
        why = "corrupted replies" if cls is ChecksumError else "no answer"
        wait = f" (reply timeout {2 * self._port.latency_timer_ms + 2:.0f} ms + transfer each: latency_timer_ms)" \
            if cls is HardwareTimeout else ""
        raise cls(f"{self._who(dxl_id)}: {what}: {why} after {self.retries + 1} attempts{wait}",
                  device=self.port_name, code=last)

    @staticmethod
    def _result(out) -> tuple[int, int]:
        if isinstance(out, int):
            return out, 0  # group txPacket / txRxPacket
        return out[-2], out[-1]  # (result, error) or (value, result, error)

    def _who(self, dxl_id) -> str:
        return f"{self.port_name}: servo {dxl_id}" if dxl_id is not None else self.port_name

    def raise_alarm(self, dxl_id: int, bits: int | None = None):
        if bits is None:
            bits, _, _ = self.transact("read Hardware Error Status", dxl_id,
                                       lambda: self._ph.read1ByteTxRx(self._port, dxl_id, 70), alarm_ok=True)
        raise ServoAlarm(f"{self._who(dxl_id)}: hardware error: {describe_hardware_error(bits)} "
                         f"(Hardware Error Status 0x{bits:02X}); torque is off until reboot (remove the cause, then "
                         f"`gonio servo reboot --id {dxl_id}`, or start the session: it reboots alarmed servos)",
                         device=f"dynamixel:{dxl_id}", code=bits)

    # -- instructions ---------------------------------------------------------------------------
    def ping(self, dxl_id: int) -> int:
        """Model number of servo ``dxl_id``; HardwareTimeout if it does not answer."""
        model, _, _ = self.transact("ping", dxl_id, lambda: self._ph.ping(self._port, dxl_id), alarm_ok=True)
        return model

    def scan(self, ids: Iterable[int] | None = None, *, attempts: int = 1,
             faults: dict[int, str] | None = None) -> dict[int, int]:
        """``{id: model number}`` of the servos that answer: broadcast ping (waits its full window,
        about a second) when ``ids`` is None, else pings per ID, each servo that did not answer pinged
        again up to ``attempts`` times in all (a noisy link loses a ping now and then). ``faults``, if
        given, receives for every servo still missing what its last ping met: ``"no answer"`` or
        ``"corrupted replies"``."""
        if ids is None:
            data, _, _ = self.transact("broadcast ping", None, lambda: self._broadcast(), alarm_ok=True)
            return {i: v[0] for i, v in sorted(data.items())}
        try:
            return self._scan_ids(ids, attempts, faults)
        except OSError as exc:  # as in transact: the link itself is gone
            raise self._link_lost("ping", None, exc) from None

    def _scan_ids(self, ids, attempts: int, faults) -> dict[int, int]:
        found: dict[int, int] = {}
        last: dict[int, str] = {}
        pending = list(ids)
        for _ in range(max(1, int(attempts))):
            for i in pending:
                with self._lock:
                    self._flush_stale()
                    try:
                        model, result, _ = self._ph.ping(self._port, i)
                    except (IndexError, ValueError, TypeError):
                        model, result = 0, sdk.COMM_RX_CORRUPT
                    self.stats["transactions"] += 1
                    if result == sdk.COMM_SUCCESS:
                        found[i] = model
                    else:
                        last[i] = "no answer" if result == sdk.COMM_RX_TIMEOUT else "corrupted replies"
                        if result != sdk.COMM_RX_TIMEOUT:
                            self._recover()
            pending = [i for i in pending if i not in found]
            if not pending:
                break
        if faults is not None:
            faults.update({i: last[i] for i in pending})
        return found

    def broadcast_ping(self, max_id: int = MAX_ID) -> tuple[dict[int, int], int]:
        """``({id: model number}, corrupted)`` of a broadcast ping, waiting as long as servos with IDs up to
        ``max_id`` need to answer: ``14 × max_id`` status bytes of transfer plus 3 ms per ID plus 16 ms (the SDK's
        own window, ``broadcastPing``, which always waits for all 252 IDs: ~0.8 s at 1 Mbps, ~4.5 s at 9600).
        ``corrupted`` counts the status packets that failed their CRC or were cut: replies that collided (two
        servos with one ID at this rate) or a noisy line. Protocol 2.0 e-manual, "Ping": every servo answers a
        broadcast ping in turn."""
        if not 0 <= max_id <= MAX_ID:
            raise ConfigError.field("--max-id", "max_id", max_id, f"servo IDs are 0..{MAX_ID}")
        try:
            with self._lock:
                self._flush_stale()
                return self._broadcast_window(max_id)
        except OSError as exc:
            raise self._link_lost("broadcast ping", None, exc) from None

    def _broadcast_window(self, max_id: int) -> tuple[dict[int, int], int]:
        port, ph = self._port, self._ph
        tx = [0] * 10
        tx[sdk.PKT_ID], tx[sdk.PKT_LENGTH_L], tx[sdk.PKT_LENGTH_H], tx[sdk.PKT_INSTRUCTION] = 0xFE, 3, 0, sdk.INST_PING
        if ph.txPacket(port, tx) != sdk.COMM_SUCCESS:
            port.is_using = False
            raise HardwareError(f"{self.port_name}: broadcast ping: cannot send", device=self.port_name)
        wait = 14 * (max_id + 1)
        port.setPacketTimeoutMillis(wait * port.tx_time_per_byte + 3.0 * (max_id + 1) + self._port.latency_timer_ms)
        rx = bytearray()
        while not port.isPacketTimeout():
            rx += bytes(port.readPort(wait - len(rx)))
        port.is_using = False
        self.stats["transactions"] += 1
        found: dict[int, int] = {}
        corrupted = 0
        k = rx.find(b"\xff\xff\xfd")
        while k >= 0:
            pkt = rx[k:k + 14]
            crc = ph.updateCRC(0, list(pkt[:12]), 12) if len(pkt) == 14 else -1
            if len(pkt) == 14 and crc == pkt[12] | (pkt[13] << 8) and pkt[7] == _INST_STATUS:
                found[pkt[4]] = pkt[9] | (pkt[10] << 8)
                k = rx.find(b"\xff\xff\xfd", k + 14)
            else:
                corrupted += 1
                k = rx.find(b"\xff\xff\xfd", k + 3)
        return dict(sorted(found.items())), corrupted

    def write_unacknowledged(self, dxl_id: int, table: ControlTable, name: str, value: int) -> None:
        """Write ``name`` without waiting for the status packet (``write*ByteTxOnly``): for the ID, whose change
        makes the status come back under the new ID, which the SDK's reply matching (by the request's ID) would
        wait for in vain. The caller reads the result back."""
        f = table[name]
        if not f.writable:
            raise ConfigError.field(table.model, name, value, "read-only field")
        fn = {1: self._ph.write1ByteTxOnly, 2: self._ph.write2ByteTxOnly, 4: self._ph.write4ByteTxOnly}[f.size]
        self.transact(f"write {name} = {value}", dxl_id, lambda: fn(self._port, dxl_id, f.address, f.to_unsigned(value)))

    def _broadcast(self):
        data, result = self._ph.broadcastPing(self._port)
        if result == sdk.COMM_RX_TIMEOUT:  # nobody there is an answer, not a failure
            return {}, sdk.COMM_SUCCESS, 0
        return data, result, 0

    def read(self, dxl_id: int, table: ControlTable, name: str, *, alarm_ok: bool = False) -> int:
        f = table[name]
        fn = {1: self._ph.read1ByteTxRx, 2: self._ph.read2ByteTxRx, 4: self._ph.read4ByteTxRx}[f.size]
        value, _, _ = self.transact(f"read {name}", dxl_id, lambda: fn(self._port, dxl_id, f.address), alarm_ok=alarm_ok)
        return f.from_unsigned(value)

    def write(self, dxl_id: int, table: ControlTable, name: str, value: int, *, alarm_ok: bool = False) -> None:
        f = table[name]
        if not f.writable:
            raise ConfigError.field(table.model, name, value, "read-only field")
        fn = {1: self._ph.write1ByteTxRx, 2: self._ph.write2ByteTxRx, 4: self._ph.write4ByteTxRx}[f.size]
        self.transact(f"write {name} = {value}", dxl_id, lambda: fn(self._port, dxl_id, f.address, f.to_unsigned(value)),
                      alarm_ok=alarm_ok)

    def sync_write(self, table: ControlTable, name: str, values: Mapping[int, int]) -> None:
        """One ``GroupSyncWrite`` of field ``name`` to several servos (no replies)."""
        f = table[name]
        group = sdk.GroupSyncWrite(self._port, self._ph, f.address, f.size)
        for i, v in values.items():
            group.addParam(i, list(f.to_unsigned(v).to_bytes(f.size, "little")))
        self.transact(f"sync write {name}", None, lambda: group.txPacket())

    def sync_read(self, table: ControlTable, first: str, last: str, ids: Sequence[int]) -> dict[int, dict[str, int]]:
        """One ``GroupSyncRead`` of the fields ``first`` … ``last`` (one contiguous block) of ``ids``."""
        address, length = table.span(first, last)
        key = (address, length, tuple(ids))
        group = self._sync_reads.get(key)
        if group is None:
            group = sdk.GroupSyncRead(self._port, self._ph, address, length)
            for i in ids:
                group.addParam(i)
            self._sync_reads[key] = group
        self.transact(f"sync read {first}..{last}", None, lambda: group.txRxPacket())
        fields = self._block_fields.get((table.model, address, length))
        if fields is None:
            fields = [(f.name, f.address - address, f.address - address + f.size, f.signed)
                      for f in table.fields.values() if address <= f.address and f.address + f.size <= address + length]
            self._block_fields[(table.model, address, length)] = fields
        out = {}
        for i in ids:  # the block's bytes as received (readRx checked the length), decoded field by field
            data = bytes(group.data_dict[i])
            out[i] = {name: int.from_bytes(data[a:b], "little", signed=signed) for name, a, b, signed in fields}
        return out

    def bulk_read(self, requests: Mapping[int, tuple[ControlTable, str]]) -> dict[int, int]:
        """One ``GroupBulkRead`` of one field per servo: ``{id: (table, field)}`` → ``{id: value}``."""
        group = sdk.GroupBulkRead(self._port, self._ph)
        for i, (table, name) in requests.items():
            group.addParam(i, table[name].address, table[name].size)
        self.transact("bulk read", None, lambda: group.txRxPacket())
        return {i: t[n].from_unsigned(group.getData(i, t[n].address, t[n].size)) for i, (t, n) in requests.items()}

    def reboot(self, dxl_id: int) -> None:
        self.transact("reboot", dxl_id, lambda: self._ph.reboot(self._port, dxl_id), alarm_ok=True)

    def factory_reset(self, dxl_id: int, option: int = 0x02) -> None:
        """Factory reset (0xFF all, 0x01 all but ID, 0x02 all but ID and baud rate)."""
        self.transact("factory reset", dxl_id, lambda: self._ph.factoryReset(self._port, dxl_id, option), alarm_ok=True)


@dataclass(frozen=True)
class AxisConfig:
    """How one joint maps onto one servo. Angles in radians (joint side), speeds rad/s and rad/s².

    ``approach`` (rad, joint side): 0 disables backlash compensation; otherwise every move ends with a
    stretch of at least ``|approach|`` travelled in the direction of its sign.
    """

    name: str
    servo_id: int
    model: str = "XM430-W350"
    gear_ratio: float = 1.0
    zero_offset_deg: float = 180.0
    direction: int = 1
    lower: float = -math.pi * 0.9
    upper: float = math.pi * 0.9
    max_speed: float = 1.0
    max_accel: float = 2.0
    homing_offset_ticks: int = 0
    approach: float = 0.0

    def ticks_of(self, angle: float, ticks_per_rev: int) -> int:
        """Raw position (ticks) of joint ``angle`` (rad): ``zero_offset/360·tpr + direction·gear_ratio·θ·tpr/2π``."""
        return int(round(self.zero_offset_deg / 360.0 * ticks_per_rev
                         + self.direction * self.gear_ratio * angle * ticks_per_rev / (2.0 * math.pi)))

    def angle_of(self, ticks: float, ticks_per_rev: int) -> float:
        """Joint angle (rad) of raw position ``ticks``: the inverse of :meth:`ticks_of`."""
        return ((ticks - self.zero_offset_deg / 360.0 * ticks_per_rev) * 2.0 * math.pi / ticks_per_rev
                / (self.direction * self.gear_ratio))

    @classmethod
    def from_joint(cls, joint, *, approach: float = 0.0) -> "AxisConfig":
        """From a :class:`gonio.rig.kinematics.Joint`."""
        return cls(joint.name, joint.servo_id, joint.model, joint.gear_ratio, joint.zero_offset_deg, joint.direction,
                   joint.lower, joint.upper, joint.max_speed, joint.max_accel, 0, approach)


class DynamixelAxes:
    """The rig's joints on one Dynamixel bus (implements :class:`gonio.rig.interfaces.Axes`).

    Parameters
    ----------
    bus : an open :class:`DynamixelBus`
    axes : one :class:`AxisConfig` per joint
    clock : Clock for settling and timeouts (``SimClock`` shared with the emulator in tests)
    tolerance_ticks : settled when every servo is within this many ticks of its goal and not moving
    poll_s : polling period while settling
    max_blind_s : longest wait between polls during a long move (alarms are seen this late at worst). A
        poll that sees an alarm mid-move only ends the wait early (a servo's own shutdown stops it, and
        nothing is sent to the others), so the default lets a move of up to 2 s end with one poll at its
        predicted end besides the one at once (issue 17: 0.5 s made ~1.4 more round trips per pose of a dense
        plan, for an alarm reported up to 1.5 s sooner)
    auto_recover : reboots allowed per move to clear an alarm (0 = raise :class:`ServoAlarm`)
    clear_alarms : reboot servos that report a hardware error when configuring (else ServoAlarm)
    configure : write the configuration and enable torque now
    torque_off_on_close : by default the joints keep holding on :meth:`close` (arms do not drop)
    """

    def __init__(self, bus: DynamixelBus, axes: Sequence[AxisConfig], clock, *, tolerance_ticks: int = 3,
                 poll_s: float = 0.02, max_blind_s: float = 2.0, auto_recover: int = 0, configure: bool = True,
                 torque_off_on_close: bool = False, clear_alarms: bool = False):
        if len({a.name for a in axes}) != len(axes) or len({a.servo_id for a in axes}) != len(axes):
            raise ConfigError.field(None, "axes", [a.name for a in axes], "joint names and servo IDs must be unique")
        self.bus = bus
        self.axes = {a.name: a for a in axes}
        self.names = tuple(a.name for a in axes)
        self.clock = clock
        self.tolerance_ticks = int(tolerance_ticks)
        self.poll_s = float(poll_s)
        self.max_blind_s = float(max_blind_s)
        self.auto_recover = int(auto_recover)
        self.torque_off_on_close = torque_off_on_close
        #: Reboot servos found with a hardware error when configuring (a session started by a person);
        #: what was cleared is kept in :attr:`cleared_alarms` (``{joint: bits}``).
        self.clear_alarms = bool(clear_alarms)
        self.cleared_alarms: dict[str, int] = {}
        self._tables = {a.name: load_control_table(a.model) for a in axes}
        self._ids = [a.servo_id for a in axes]
        self._table = self._tables[axes[0].name]  # sync reads/writes need one layout (all X series share it)
        layout = lambda t: {n: (f.address, f.size, f.signed) for n, f in t.fields.items()}  # noqa: E731
        if any(layout(t) != layout(self._table) for t in self._tables.values()):
            raise ConfigError.field(None, "axes.model", sorted({a.model for a in axes}),
                                    "all servos on one bus must share a control-table layout")
        self._goals: dict[str, int] = {}
        self.last_move: dict[str, object] = {}
        #: the last state read: (Clock time, {joint: angle}); dropped whenever this object writes to a servo
        self._seen: tuple[float, dict[str, float]] | None = None
        if configure:
            self.configure()

    @classmethod
    def from_rig(cls, rig, bus: DynamixelBus, clock, *, approach: float = 0.0, **kw) -> "DynamixelAxes":
        """Axes for every joint of a :class:`gonio.rig.kinematics.Rig`."""
        return cls(bus, [AxisConfig.from_joint(j, approach=approach) for j in rig.joints], clock, **kw)

    # -- units ----------------------------------------------------------------------------------
    def to_ticks(self, name: str, angle: float) -> int:
        return self.axes[name].ticks_of(angle, self._tables[name].ticks_per_rev)

    def to_angle(self, name: str, ticks: float) -> float:
        return self.axes[name].angle_of(ticks, self._tables[name].ticks_per_rev)

    # -- configuration --------------------------------------------------------------------------
    def configure(self) -> None:
        """Check models; with torque off write mode, homing offset, limits; then RAM settings, torque on."""
        for name, a in self.axes.items():
            t = self._tables[name]
            model = self.bus.ping(a.servo_id)
            if model != t.model_number:
                known = table_for_model_number(model)
                raise ConfigError.field(None, f"{name}.model", a.model,
                                        f"servo {a.servo_id} reports model number {model} "
                                        f"({known.model if known else 'unknown'}), expected {t.model_number}")
            bits = self.bus.read(a.servo_id, t, "hardware_error_status", alarm_ok=True)
            if bits and not self.clear_alarms:
                self.bus.raise_alarm(a.servo_id, bits)
            if bits:  # a person started the session after removing the cause: reboot clears the alarm
                self.bus.reboot(a.servo_id)
                self.clock.sleep(0.1)
                self.cleared_alarms[name] = bits
            self.bus.write(a.servo_id, t, "torque_enable", 0)
            lo, hi = sorted((self.to_ticks(name, a.lower), self.to_ticks(name, a.upper)))
            mode = 3 if 0 <= lo and hi <= t.position_max else 4
            if self.bus.read(a.servo_id, t, "operating_mode") != mode:
                self.bus.write(a.servo_id, t, "operating_mode", mode)
            self.bus.write(a.servo_id, t, "homing_offset", a.homing_offset_ticks)
            if mode == 3:
                self.bus.write(a.servo_id, t, "max_position_limit", hi)
                self.bus.write(a.servo_id, t, "min_position_limit", lo)
            self._configure_ram(name)

    def _configure_ram(self, name: str) -> None:
        self._seen = None
        a, t = self.axes[name], self._tables[name]
        self.bus.write(a.servo_id, t, "profile_velocity", t.rad_s_to_velocity(a.max_speed * a.gear_ratio))
        self.bus.write(a.servo_id, t, "profile_acceleration", t.rad_s2_to_acceleration(a.max_accel * a.gear_ratio))
        self.bus.write(a.servo_id, t, "torque_enable", 1)

    def recover(self) -> dict[str, int]:
        """Reboot every servo with a hardware error, write its RAM settings again, re-enable torque.

        Returns ``{joint: cleared Hardware Error Status bits}``. Call it only when the cause is gone
        (an overload means something blocked the arm)."""
        cleared = {}
        self._seen = None
        for name, a in self.axes.items():
            bits = self.bus.read(a.servo_id, self._tables[name], "hardware_error_status", alarm_ok=True)
            if bits:
                self.bus.reboot(a.servo_id)
                self.clock.sleep(0.1)  # the servo restarts (e-manual: status first, then reboot)
                cleared[name] = bits
                self._configure_ram(name)
        return cleared

    # -- state ----------------------------------------------------------------------------------
    def _state(self) -> dict[int, dict[str, int]]:
        """Torque, hardware error, moving and present position of every servo: one sync read of the
        block Torque Enable … Present Position (one round trip on the bus, not one per field group).
        The positions are remembered with the Clock time of the read (:meth:`positions`)."""
        state = self.bus.sync_read(self._table, "torque_enable", "present_position", self._ids)
        self._seen = (self.clock.now(), {n: self.to_angle(n, state[a.servo_id]["present_position"])
                                         for n, a in self.axes.items()})
        return state

    def alarms(self) -> dict[str, int]:
        """``{joint: Hardware Error Status bits}`` of every servo reporting one. One sync read of the
        state block (:meth:`_state`): the positions come with it, so a :meth:`positions` at the same
        Clock time (the runner's safety check, then the pose's solution) costs no second round trip."""
        state = self._state()
        return {n: state[a.servo_id]["hardware_error_status"] for n, a in self.axes.items()
                if state[a.servo_id]["hardware_error_status"]}

    def positions(self) -> dict[str, float]:
        """Measured joint angles (radians) now: the last read's if it was taken at this same Clock time
        and this object has written nothing to a servo since (the same instant of the same state: with a
        real clock time always moves on, so this reads), else one sync read of Present Position."""
        seen = self._seen
        if seen is not None and seen[0] == self.clock.now():
            return dict(seen[1])
        data = self.bus.sync_read(self._table, "present_position", "present_position", self._ids)
        angles = {n: self.to_angle(n, data[a.servo_id]["present_position"]) for n, a in self.axes.items()}
        self._seen = (self.clock.now(), angles)
        return dict(angles)

    # -- motion ---------------------------------------------------------------------------------
    def _check_targets(self, targets: Mapping[str, float]) -> None:
        for name, value in targets.items():
            if name not in self.axes:
                raise ConfigError.field(None, "targets", name, f"unknown joint; joints: {', '.join(self.names)}")
            a = self.axes[name]
            if not (a.lower - 1e-9 <= value <= a.upper + 1e-9) or not math.isfinite(value):
                raise ConfigError.field(None, f"targets.{name}", math.degrees(value),
                                        f"outside the joint limits [{math.degrees(a.lower):g}, {math.degrees(a.upper):g}] deg")

    def move_to(self, targets: Mapping[str, float], *, timeout: float = 60.0) -> dict[str, float]:
        """Move the named joints together (others hold), wait until settled, return measured angles."""
        self._check_targets(targets)
        start = self.clock.now()
        # the positions only matter for a goal not yet known (the move's predicted time) and for the approach
        need = any(n not in self._goals for n in self.names) or any(self.axes[n].approach for n in targets)
        current = self.positions() if need else {}
        for name, angle in current.items():
            self._goals.setdefault(name, self.to_ticks(name, angle))
        stages = []
        pre = {}
        for name, goal in targets.items():
            a = self.axes[name]
            if a.approach:
                d, dist = math.copysign(1.0, a.approach), abs(a.approach)
                if (goal - current[name]) * d < dist - 1e-12:  # would not end with a long-enough stretch in d
                    via = min(max(goal - d * dist, a.lower), a.upper)
                    if (goal - via) * d > 0:
                        pre[name] = via
        if pre:
            stages.append({**targets, **pre})
        stages.append(dict(targets))
        for stage in stages:
            measured = self._move_stage(stage, start + timeout)
        self.last_move = {"stages": len(stages), "lab_time": self.clock.now() - start}
        return measured

    def _move_stage(self, targets: Mapping[str, float], deadline: float) -> dict[str, float]:
        goals = {self.axes[n].servo_id: self.to_ticks(n, v) for n, v in targets.items()}
        recoveries = 0
        reissued = False
        self._seen = None
        self.bus.sync_write(self._table, "goal_position", goals)
        predicted_end = self.clock.now() + self._predict(goals)
        # the first poll comes at once, before the Clock moves on: a sync write has no reply, and only a round
        # trip after it shows that the servos have taken the goal (with a simulated clock: the emulator starts
        # the profile at the Clock time it handles the packet)
        while True:
            state = self._state()
            alarms = {i: s["hardware_error_status"] for i, s in state.items() if s["hardware_error_status"]}
            if alarms:
                if recoveries >= self.auto_recover:
                    i, bits = next(iter(alarms.items()))
                    self.bus.raise_alarm(i, bits)
                recoveries += 1
                self.recover()
                self.bus.sync_write(self._table, "goal_position", goals)
                predicted_end = self.clock.now() + self._predict(goals)
                continue
            off = [n for n, a in self.axes.items() if not state[a.servo_id]["torque_enable"]]
            if off:
                if reissued:
                    raise HardwareError(f"{self.bus.port_name}: joints {', '.join(off)}: torque is off again "
                                        f"after re-enabling it (power supply?)", device=self.bus.port_name)
                reissued = True  # power cycle / brown-out: RAM lost, no alarm; restore and re-issue once
                for n in off:
                    self._configure_ram(n)
                self.bus.sync_write(self._table, "goal_position", goals)
                predicted_end = self.clock.now() + self._predict(goals)
                continue
            settled = all(not state[i]["moving"] and abs(state[i]["present_position"] - g) <= self.tolerance_ticks
                          for i, g in goals.items())
            if settled:
                return {n: self.to_angle(n, state[a.servo_id]["present_position"]) for n, a in self.axes.items()}
            now = self.clock.now()
            if now >= deadline:
                late = [n for n, a in self.axes.items() if a.servo_id in goals and
                        abs(state[a.servo_id]["present_position"] - goals[a.servo_id]) > self.tolerance_ticks]
                raise HardwareTimeout(f"{self.bus.port_name}: joints {', '.join(late) or 'still moving'} did not settle "
                                      f"within the move timeout", device=self.bus.port_name)
            wait = min(max(predicted_end - now, self.poll_s), self.max_blind_s, max(deadline - now, 0.0) + 1e-6)
            self.clock.sleep(wait)

    def _predict(self, goals: Mapping[int, int]) -> float:
        """Lab time the servos' trapezoidal profiles need for the move just commanded."""
        worst = 0.0
        by_id = {a.servo_id: n for n, a in self.axes.items()}
        for i, g in goals.items():
            name = by_id[i]
            a, t = self.axes[name], self._tables[name]
            v = t.velocity_to_rad_s(t.rad_s_to_velocity(a.max_speed * a.gear_ratio)) / t.rad_per_tick()
            acc = t.acceleration_to_rad_s2(t.rad_s2_to_acceleration(a.max_accel * a.gear_ratio)) / t.rad_per_tick()
            last = self._goals.get(name, g)
            worst = max(worst, float(trapezoid_time(g - last, v, acc)))
            self._goals[name] = g
        return worst

    def close(self) -> None:
        """Keep holding (default) or switch torque off, then release the bus."""
        try:
            if self.torque_off_on_close:
                for n, a in self.axes.items():
                    self.bus.write(a.servo_id, self._tables[n], "torque_enable", 0, alarm_ok=True)
        finally:
            self.bus.close()
