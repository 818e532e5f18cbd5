"""SPEC.md §4–§5 as byte exchanges (vectors.json ``exchanges``): request bytes, the controller's inputs
(E-stop, interlock, heat-sink temperature) changed between them, and the reply each request must get — played
over a real pty against the Python emulator and the firmware's host build. They read like the spec: a retried
switch-on after an E-stop cut is answered ERROR ESTOP, a retried STATUS says what holds now, a retried TRIGGER
fires once, and over its temperature limit the controller cuts the light itself."""

import pytest

from firmware_protocol import codec as fp
from protocol.test_emulator_spec import Raw
from sim.clock import SimClock


def apply_input(emu, inp: dict) -> None:
    """Change one of the controller's inputs as an exchange step says."""
    for key, value in inp.items():
        if key == "estop":
            emu.set_estop(value)
        elif key == "interlock":
            emu.set_interlock(value)
        elif key == "heat_sink_c":
            emu.set_heat_sink(value)
        else:
            raise AssertionError(f"unknown input {key!r} in vectors.json")


def play(exchange: dict, ask, set_input) -> None:
    """Play one exchange: ``ask(bytes) -> [Message]`` sends a request, ``set_input(dict)`` changes an input."""
    steps = exchange["steps"]
    i = 0
    while i < len(steps):
        step = steps[i]
        if "input" in step:
            set_input(step["input"])
            i += 1
            continue
        replies = ask(bytes.fromhex(step["send"]))
        want = steps[i + 1]
        assert len(replies) == 1, (exchange["description"], step, replies)
        [got] = replies
        if "expect" in want:
            exp = fp.decode_message(fp.decode_frame(bytes.fromhex(want["expect"])))
            assert (got.name, got.seq, dict(got.values)) == (exp.name, exp.seq, dict(exp.values)), \
                (exchange["description"], step["request"])
        else:
            f = want["expect_fields"]
            assert (got.name, got.seq) == (f["name"], f["seq"]), (exchange["description"], step["request"], got)
            assert {k: got[k] for k in f["values"]} == f["values"], (exchange["description"], step["request"], got)
        i += 2


def test_vectors_hold_the_exchanges_of_the_spec(vectors):
    names = " ".join(e["description"] for e in vectors["exchanges"])
    assert "E-stop cut" in names and "TRIGGER" in names and "temperature limit" in names


@pytest.mark.parametrize("k", range(4))
def test_emulators_answer_every_exchange_as_the_spec_says(Emulator, vectors, k):
    exchange = vectors["exchanges"][k]
    with Emulator(SimClock()) as emu:
        r = Raw(emu.path)
        try:
            play(exchange, r.ask, lambda inp: apply_input(emu, inp))
        finally:
            r.port.close()
