"""Dynamixel Protocol 2.0 wire format, for the servo emulator (the host side uses dynamixel-sdk).

Packet: ``FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAMS... | CRC_L CRC_H`` where LEN counts INST,
PARAMS and CRC after byte stuffing. Status packets have INST = 0x55 and an ERROR byte before the
params. Source: ROBOTIS e-manual, "DYNAMIXEL Protocol 2.0" (Instruction/Status packet, CRC, byte
stuffing); FIELD-NOTES.md (CRC-16 poly 0x8005, init 0, not reflected; ping of ID 1 is
``FF FF FD 00 01 03 00 01 19 4E``).
"""

from __future__ import annotations

from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
INST_PING, INST_READ, INST_WRITE, INST_REG_WRITE, INST_ACTION = 0x01, 0x02, 0x03, 0x04, 0x05
INST_FACTORY_RESET, INST_REBOOT, INST_CLEAR, INST_STATUS = 0x06, 0x08, 0x10, 0x55
INST_SYNC_READ, INST_SYNC_WRITE, INST_BULK_READ, INST_BULK_WRITE = 0x82, 0x83, 0x92, 0x93
# Status error numbers (bits 0-6 of the ERROR byte); bit 7 is the hardware-error alert.
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE, ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = range(1, 8)
ERR_ALERT = 0x80


def _crc_table() -> list[int]:
    """The Protocol 2.0 CRC-16 table, written here from the e-manual and not imported from the host's
    driver (gonio.rig.dynamixel keeps its own for the SDK): the emulator checks the host's bytes with its
    own codec, so one wrong table cannot hide in both."""
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16/BUYPASS (poly 0x8005, init 0, no reflection, no final xor), as in Protocol 2.0."""
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Byte stuffing of instruction/error + params: after every ``FF FF FD`` insert an extra ``FD``."""
    return body.replace(b"\xff\xff\xfd", b"\xff\xff\xfd\xfd")


def unstuff(body: bytes) -> bytes:
    return body.replace(b"\xff\xff\xfd\xfd", b"\xff\xff\xfd")


def encode(dxl_id: int, inst: int, payload: bytes = b"") -> bytes:
    """A complete packet: header, ID, length, stuffed ``inst + payload``, CRC."""
    body = stuff(bytes([inst]) + payload)
    n = len(body) + 2
    head = HEADER + bytes([dxl_id, n & 0xFF, n >> 8]) + body
    crc = crc16(head)
    return head + bytes([crc & 0xFF, crc >> 8])


def status(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet (INST 0x55) with ``error`` and ``params``."""
    return encode(dxl_id, INST_STATUS, bytes([error & 0xFF]) + params)


@dataclass(frozen=True)
class Packet:
    """One parsed instruction packet (params unstuffed); ``crc_ok`` False if its CRC did not match."""

    dxl_id: int
    inst: int
    params: bytes
    crc_ok: bool = True


class Parser:
    """Incremental parser of a byte stream into :class:`Packet` objects; skips garbage before a header."""

    MAX_LEN = 1024

    def __init__(self):
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[Packet]:
        self._buf += data
        out = []
        while True:
            i = self._buf.find(HEADER)
            if i < 0:
                # keep a possible partial header at the end
                keep = next((k for k in (3, 2, 1) if self._buf.endswith(HEADER[:k])), 0)
                del self._buf[: len(self._buf) - keep]
                return out
            del self._buf[:i]
            if len(self._buf) < 7:
                return out
            n = self._buf[5] | (self._buf[6] << 8)
            if n < 3 or n > self.MAX_LEN:
                del self._buf[:1]
                continue
            if len(self._buf) < 7 + n:
                return out
            raw = bytes(self._buf[: 7 + n])
            del self._buf[: 7 + n]
            ok = crc16(raw[:-2]) == (raw[-2] | (raw[-1] << 8))
            body = unstuff(raw[7:-2])
            out.append(Packet(raw[4], body[0], body[1:], ok))
