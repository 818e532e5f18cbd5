"""The part of σ a pose's samples share (sigma_pose) is stored with them and read back; a record written before the
column existed reads as 0; NPZ exports carry it (docs/formats.md)."""

from __future__ import annotations

import base64
import json
import zlib

import numpy as np

from gonio.samples import SampleSet
from gonio.session.records import decode_record, encode_record


def _samples(n=4):
    rng = np.random.default_rng(1)
    w = np.tile([0.0, 0.0, 1.0], (n, 1))
    return SampleSet(w, w, rng.random((n, 3)), rng.random((n, 3)) + 1, pose=np.full(n, 3),
                     sigma_pose=rng.random((n, 3)))


def test_sigma_pose_is_stored_and_read_back():
    s = _samples()
    pose, back, meta = decode_record(encode_record(3, s, {"x": 1})[:-1])
    assert pose == 3 and np.array_equal(back.sigma_pose, s.sigma_pose) and np.array_equal(back.sigma, s.sigma)


def test_a_record_without_sigma_pose_reads_as_zero():
    line = encode_record(3, _samples(), {})[:-1]
    obj = json.loads(line[9:])
    del obj["cols"]["sigma_pose"]
    payload = json.dumps(obj, separators=(",", ":")).encode()
    _, back, _ = decode_record(b"%08x " % zlib.crc32(payload) + payload)
    assert back.sigma_pose.shape == (4, 3) and not back.sigma_pose.any()


def test_a_record_with_an_unknown_column_is_refused():
    line = encode_record(3, _samples(), {})[:-1]
    obj = json.loads(line[9:])
    obj["cols"]["extra"] = ["<f8", [4], base64.b64encode(np.zeros(4).tobytes()).decode()]
    payload = json.dumps(obj, separators=(",", ":")).encode()
    try:
        decode_record(b"%08x " % zlib.crc32(payload) + payload)
    except ValueError as exc:
        assert "exactly the columns" in str(exc)
    else:
        raise AssertionError("an unknown column was accepted")


def test_npz_exports_carry_sigma_pose(tmp_path):
    from gonio.io.npz import read_npz, write_npz

    s = _samples()
    got = read_npz(write_npz(tmp_path / "x.npz", s, {}))
    assert np.array_equal(got.samples.sigma_pose, s.sigma_pose)
    from gonio.io.npz import UNITS

    assert "sigma_pose" in UNITS
