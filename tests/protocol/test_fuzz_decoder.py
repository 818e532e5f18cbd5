"""Hypothesis fuzzing of the Python streaming decoder: random bytes, mutated valid frames, arbitrary
chunking. It never raises, never accepts a corrupted frame, and resynchronizes after garbage."""

from hypothesis import given
from hypothesis import strategies as st

from firmware_protocol import codec as c

frames = st.builds(c.Frame, st.integers(0, 255), st.integers(0, 255), st.binary(max_size=c.MAX_PAYLOAD))
SENTINEL = c.Frame(c.STATUS, 200, b"\x01\x00\x02")


def wire(f: c.Frame) -> bytes:
    return c.encode_frame(f.type, f.seq, f.payload)


def feed_chunked(data: bytes, cuts: list[int]) -> list:
    d, events, prev = c.Decoder(), [], 0
    for cut in sorted({min(x, len(data)) for x in cuts}) + [len(data)]:
        events += d.feed(data[prev:cut])
        prev = cut
    return events


def consistent(f: c.Frame) -> bool:
    """An accepted frame re-encodes to a segment the decoder accepts as the same frame."""
    return c.decode_segment(c.segment_of(c.cobs_encode(c.frame_body(f.type, f.seq, f.payload)))) == f


@given(st.binary(max_size=600), st.lists(st.integers(0, 600), max_size=20))
def test_random_bytes_never_raise_and_resync(data, cuts):
    events = feed_chunked(data + wire(SENTINEL), cuts)
    accepted = [e for e in events if isinstance(e, c.Frame)]
    assert all(isinstance(e, (c.Frame, c.Reject)) for e in events)
    assert all(consistent(f) for f in accepted)
    assert accepted and accepted[-1] == SENTINEL  # resynchronized on the frame after the garbage


@given(st.lists(frames, min_size=1, max_size=8), st.lists(st.integers(0, 800), max_size=30))
def test_valid_frames_any_chunking(fs, cuts):
    data = b"".join(wire(f) for f in fs)
    assert feed_chunked(data, cuts) == fs


@given(frames, st.data())
def test_mutated_frame_is_never_accepted(f, data):
    w = bytearray(wire(f))
    nbits = 8 * len(w)
    positions = data.draw(st.lists(st.integers(0, nbits - 1), min_size=1, max_size=5, unique=True))
    for k in positions:
        w[k // 8] ^= 1 << (k % 8)
    cuts = data.draw(st.lists(st.integers(0, len(w) + 20), max_size=6))
    events = feed_chunked(bytes(w) + wire(SENTINEL), cuts)
    assert [e for e in events if isinstance(e, c.Frame)] == [SENTINEL]


@given(frames, st.binary(min_size=1, max_size=40), st.integers(0, 200), st.data())
def test_garbage_insert_or_truncation_never_yields_a_different_frame(f, garbage, at, data):
    w = wire(f)
    at = at % (len(w) + 1)
    mode = data.draw(st.sampled_from(["insert", "truncate", "replace"]))
    if mode == "insert":
        bad = w[:at] + garbage + w[at:]
    elif mode == "truncate":
        bad = w[:at] + garbage
    else:
        bad = w[:at] + garbage + w[at + len(garbage):]
    events = c.Decoder().feed(bad + wire(SENTINEL))
    accepted = [e for e in events if isinstance(e, c.Frame)]
    assert accepted[-1] == SENTINEL
    # anything else accepted is the original frame, intact (e.g. garbage inserted before its delimiter)
    assert all(e == f for e in accepted[:-1]) and all(consistent(e) for e in accepted)


@given(st.binary(min_size=200, max_size=2000))
def test_decoder_memory_is_bounded(noise):
    d = c.Decoder()
    d.feed(noise.replace(b"\x00", b"\x01"))
    assert len(d._buf) <= c.MAX_ENCODED
    events = d.feed(b"\x00")
    assert len(events) == 1 and events[0].verdict == "overflow"
    assert d.feed(wire(SENTINEL)) == [SENTINEL]
