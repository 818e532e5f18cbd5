"""SPEC.md's worked examples and tables agree with the codec (the spec cannot drift from the code)."""

import re

from firmware_protocol import SPEC_PATH
from firmware_protocol import codec as c

SPEC = SPEC_PATH.read_text()
EXAMPLE = re.compile(r"^(?P<label>[A-Z_]+)[^\n]*?seq (?P<seq>\d+)\s+(?P<wire>00(?: [0-9A-F]{2})+ 00)"
                     r"(?:\s+body (?P<body>[0-9A-F ]+))?\s*$", re.M)


def test_every_worked_example_decodes_to_its_body_and_message():
    examples = list(EXAMPLE.finditer(SPEC))
    assert len(examples) >= 16
    names = set()
    for m in examples:
        wire = bytes.fromhex(m["wire"])
        frame = c.decode_frame(wire)
        msg = c.decode_message(frame)
        assert msg.name == m["label"] and frame.seq == int(m["seq"]), m.group(0)
        assert c.encode_frame(frame.type, frame.seq, frame.payload) == wire
        if m["body"]:
            assert c.cobs_decode(wire[1:-1 - c.CHECK_SIZE]) == bytes.fromhex(m["body"]), m.group(0)
        names.add(msg.name)
    assert names == set(c.BY_NAME)  # every message type has a worked example


def test_catalogue_table_matches_codec_sizes():
    rows = re.findall(r"^\| 0x([0-9A-F]{2}) \| (\w+)\s*\|.*\| (\d+) \|$", SPEC, re.M)
    table = {int(code, 16): (name, int(size)) for code, name, size in rows}
    assert table == {code: (m.name, m.size) for code, m in c.MESSAGES.items()}


def test_error_code_and_flag_tables_match_codec():
    errors = {int(code, 16): name for code, name in re.findall(r"^\| 0x([0-9A-F]{2}) \| ([A-Z_]+)\s+\|", SPEC, re.M)
              if int(code, 16) <= 0x08 and name in c.ERROR_NAMES.values()}
    assert errors == c.ERROR_NAMES
    bits = re.findall(r"^\| (\d) +\| ([A-Z_]+) +\|", SPEC, re.M)  # capability and status-flag rows
    assert len(bits) == 5 + 7
    for bit, name in bits:
        assert 1 << int(bit) in (getattr(c, f"FLAG_{name}", None), getattr(c, f"CAP_{name}", None)), name
    assert "0x1EDC6F41" in SPEC and "0x82F63B78" in SPEC and "0xE3069283" in SPEC and f"MAX_ENCODED = {c.MAX_ENCODED}" in SPEC
