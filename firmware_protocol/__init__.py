"""The rig controller's wire protocol: ``SPEC.md`` (normative), ``vectors.json`` (test vectors),
:mod:`firmware_protocol.codec` (Python codec) and ``c/`` (C99 codec for the microcontroller).

This package depends on nothing in ``gonio``: it is what the firmware engineer gets.
"""

from pathlib import Path

from firmware_protocol.codec import (  # noqa: F401
    BY_NAME, MESSAGES, PROTOCOL_MAJOR, PROTOCOL_MINOR, Decoder, Frame, Message, ProtocolError, Reject,
    crc32c, decode_frame, decode_message, encode_frame, encode_message,
)

HERE = Path(__file__).resolve().parent
SPEC_PATH = HERE / "SPEC.md"
VECTORS_PATH = HERE / "vectors.json"
C_DIR = HERE / "c"
